"""A source whose rest pose is not what it says (limbstream.heading.contradiction): its segments'
axes are off by a constant turn each, as a BVH file whose zero pose has every bone along +X gives
them read as its labelled rest pose (limbstream.heading.simulate.zero_pose_along_x). Its joints
contradict their constraints at any heading: the correction finds so, says which joints, stops
(its corrections drop to none) instead of turning the pelvis round; correct data never trips it;
``eval`` says so."""
from __future__ import annotations

import json

import numpy as np
import pytest

from limbstream import cli, quat
from limbstream.body import LAYOUTS
from limbstream.heading import HeadingCorrection
from limbstream.heading.joints import Layout, joint_errors_deg
from limbstream.heading.simulate import DriftModel, zero_pose_along_x
from limbstream.sources import load
from limbstream.sources.generator import generate
from limbstream.sources.loop import looped

FS = 50.0
SECONDS = 90.0
BIAS_DPS = 0.02
"""The sensors' vertical gyro bias, uniform +-, deg/s: about VQF 6D's median drift (1.7 deg/min)."""


def drifting(q: np.ndarray, seed: int) -> np.ndarray:
    """(n, S, 4) calibrated orientations of ``q`` whose headings drift from 0 at t = 0."""
    t = np.arange(len(q)) / FS
    return DriftModel(bias_dps=BIAS_DPS, walk=0.0, tilt_deg=0.3, seed=seed).draw(t, q.shape[1]).apply(q)


def online(est: HeadingCorrection, q: np.ndarray) -> np.ndarray:
    """(n, B, S) the corrections the estimator gives tick by tick for ``q`` (n, B, S, 4)."""
    return np.stack([est.update(q[k]) for k in range(len(q))])


def take_all(est: HeadingCorrection, q: np.ndarray) -> None:
    """Give the estimator every tick of ``q`` (n, B, S, 4) at once, each subject's in time order."""
    est.take(np.tile(np.arange(q.shape[1]), len(q)), q.reshape(-1, *q.shape[2:]))


def hip_errors(q_est: np.ndarray, truth: np.ndarray, layout: Layout) -> np.ndarray:
    """(n,) the mean joint angle error of the hips, deg."""
    hips = [j for j, name in enumerate(layout.joints) if name.startswith("hip")]
    return joint_errors_deg(q_est, truth, layout)[:, hips].mean(axis=1)


@pytest.fixture(scope="module")
def two_subjects():
    """One estimator, two subjects of the same generated motion through drifting sensors: row 0
    labelled as it is, row 1 read as a zero pose with every bone along +X labelled as the same
    rest pose. Returns (truth (n, 2, S, 4), readings, corrections (n, 2, S), estimator, layout)."""
    motion = generate(SECONDS, FS, seed=4)
    truth = np.stack([motion.q, zero_pose_along_x(motion.q, motion.segments, motion.rest_pose)], axis=1)
    q = np.stack([drifting(truth[:, b], seed=7) for b in range(2)], axis=1)
    layout = Layout.of(motion.segments, motion.rest_pose)
    est = HeadingCorrection(layout, 2, FS)
    return truth, q, online(est, q), est, layout


def test_the_mislabel_is_a_constant_turn_that_puts_every_bone_along_x():
    motion = generate(2.0, FS, seed=1)
    for rest_pose in ("standing", "tpose"):
        wrong = zero_pose_along_x(motion.q, motion.segments, rest_pose)
        turn = quat.multiply(quat.conjugate(motion.q), wrong)  # q^-1 q': the segment's own constant turn
        assert np.allclose(np.abs(np.sum(turn[0] * turn, axis=-1)), 1.0)
        rest = {s.name: s.directions[rest_pose] for layout in LAYOUTS.values() for s in layout.segments}
        bones = np.array([rest[name] for name in motion.segments], np.float64)
        assert np.allclose(quat.rotate(wrong, np.array([1.0, 0.0, 0.0])), quat.rotate(motion.q, bones), atol=1e-9)


def test_a_mislabelled_rest_pose_stops_the_correction_and_says_which_joints(two_subjects):
    truth, q, c, est, layout = two_subjects
    assert est.contradicted.tolist() == [False, True]
    assert 30.0 <= est.stopped_s[1] <= 60.0, est.stopped_s
    joints = est.contradicted_joints(1)
    assert {"hip_l", "hip_r"} <= set(joints) and min(joints.values()) > 0.5, joints
    assert est.contradicted_joints(0) == {}
    after = round((est.stopped_s[1] + 1.0) * FS)
    assert np.abs(c[after:, 1]).max() == 0.0  # no correction from then on
    assert est.status()["confidence"][1].max() < 0.01  # and none claimed


def test_its_hip_error_no_longer_grows(two_subjects):
    """Turned round by the joints until it stops, then left as its sensors drift."""
    truth, q, c, est, layout = two_subjects
    err = hip_errors(HeadingCorrection.apply(q[:, 1], c[:, 1]), truth[:, 1], layout)
    first, last = err[:round(60 * FS)].mean(), err[-round(30 * FS):].mean()
    assert last < 5.0 and last < first + 1.0, (first, last)


def test_the_correct_subject_beside_it_is_still_corrected(two_subjects):
    truth, q, c, est, layout = two_subjects
    assert est.contradictions.shares()[0].max() < 0.1, est.contradictions.shares()[0]
    assert np.abs(c[-1, 0]).max() > np.radians(0.1)  # corrected
    err = hip_errors(HeadingCorrection.apply(q[:, 0], c[:, 0]), truth[:, 0], layout)
    assert err[-round(30 * FS):].mean() < 2.0, err[-round(30 * FS):].mean()


def test_a_mislabelled_full_body_trips_too():
    """The full layout (feet, hands, chest, head): its ankles, lumbar spine and hips say it."""
    motion = generate(60.0, FS, seed=5, layout="full")
    truth = np.stack([motion.q, zero_pose_along_x(motion.q, motion.segments, motion.rest_pose)], axis=1)
    q = np.stack([drifting(truth[:, b], seed=8) for b in range(2)], axis=1)
    est = HeadingCorrection(Layout.of(motion.segments, motion.rest_pose), 2, FS)
    take_all(est, q)
    assert est.contradicted.tolist() == [False, True], est.contradictions.shares()
    assert est.contradictions.shares()[0].max() < 0.1
    assert {"hip_l", "hip_r"} <= set(est.contradicted_joints(1)), est.contradicted_joints(1)


def test_correct_cmu_clips_never_trip_it(cmu_npz):
    """Every CMU clip (labelled T-pose), looped for 60 s through drifting sensors, one subject
    each in one estimator: no joint comes near the bound (subject 131's clips, whose arms hang at
    rest though the file says T-pose, bend their elbows 60 deg off the plane across the forearm:
    under the bound, 75 deg)."""
    clips = load(cmu_npz)
    truth = np.stack([looped([clip], 60.0).q for clip in clips], axis=1)
    q = np.stack([drifting(truth[:, b], seed=20 + b) for b in range(len(clips))], axis=1)
    est = HeadingCorrection(Layout.of(clips[0].segments, clips[0].rest_pose), len(clips), FS)
    take_all(est, q)
    shares = est.contradictions.shares()
    assert not est.contradicted.any() and shares.max() < 0.25, dict(zip([c.name for c in clips], shares.round(2)))


def test_eval_says_the_correction_stopped(tmp_path, capsys):
    """A mislabelled file (the repo's npz format, labelled ``standing``) through ``eval`` with a
    drifting sensor model: the heading correction stops and eval names the motion and joints."""
    motion = generate(75.0, FS, seed=6)
    path = tmp_path / "mislabelled.npz"
    np.savez(path, clip_walk=zero_pose_along_x(motion.q, motion.segments, motion.rest_pose),
             segment_names=np.array(motion.segments), fs=FS, rest_pose=np.array(motion.rest_pose))
    out = tmp_path / "rows.json"
    code = cli.main(["eval", str(path), "--algorithms", "fastsw", "--thresholds", "9e-4", "--max-len", "25",
                     "--mounting-deg", "90", "--heading-deg", "180", "--yaw-drift-dps", "0.02",
                     "--heading-correction", "joints", "--json", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    line = next((x for x in text.splitlines() if x.startswith("heading correction stopped for walk at")), None)
    assert line is not None and "hip_l" in line and "hip_r" in line, text
    [row] = json.loads(out.read_text())
    [stopped] = row["heading_stopped"]
    assert stopped["motion"] == "walk" and 30 <= stopped["at_s"] <= 60 and "hip_l" in stopped["joints"]
