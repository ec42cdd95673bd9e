"""Heading held by the body (limbstream.heading): the hinge, the range of motion, stillness, the
filters, and the estimator on generated motion whose headings drift, including its edge cases (a
joint that never moves, a joint held at its limit, a device that restarts, a lower body alone);
and the smooth loop of clips it is measured on (limbstream.sources.loop)."""
from __future__ import annotations

import numpy as np
import pytest

from limbstream import quat
from limbstream.calibration import yaw
from limbstream.heading import HeadingCorrection, Settings, hinge, rom
from limbstream.heading.filter import JointFilters, wrap
from limbstream.heading.joints import Layout, joint_errors_deg, relative, vertical_in
from limbstream.heading.simulate import DriftModel
from limbstream.sources import load
from limbstream.sources.generator import DEFAULT_SCHEDULE, generate
from limbstream.sources.loop import looped
from limbstream.wire import SEGMENTS

FS = 50.0
LAYOUT = Layout.of(SEGMENTS, "standing")
SEG = {name: i for i, name in enumerate(SEGMENTS)}
JOINT = {name: j for j, name in enumerate(LAYOUT.joints)}


def drifting(q: np.ndarray, bias_dps: float, seed: int) -> np.ndarray:
    """(n, S, 4) calibrated orientations of true ones ``q`` whose headings drift from 0 at t = 0."""
    t = np.arange(len(q)) / FS
    return DriftModel(bias_dps=bias_dps, walk=0.0, tilt_deg=0.3, seed=seed).draw(t, q.shape[1]).apply(q)


def mean_error(q_est: np.ndarray, q_true: np.ndarray, layout: Layout = LAYOUT) -> dict[str, float]:
    """Joint class -> mean joint angle error (deg)."""
    err = joint_errors_deg(q_est, q_true, layout)
    return {name: float(err[:, mask].mean()) for name, mask in layout.classes().items()}


# -- pieces ---------------------------------------------------------------------------------------


def test_hinge_measure_finds_a_turned_child_and_weighs_a_bent_knee_more():
    motion = generate(20.0, FS, seed=2, activities=[("walking", 20.0)])
    q = motion.q.copy()
    k = JOINT["knee_r"]
    q[:, SEG["r_shank"]] = quat.multiply(yaw(np.radians(25.0)), q[:, SEG["r_shank"]])
    r, g = relative(q, LAYOUT)[:, [k]], vertical_in(q[:, LAYOUT.parent[[k]]])
    spread = np.radians([[10.0, 3.0]]) ** 2
    measured, info = hinge.measure(r, g, np.array([[1.0, 0.0, 0.0]]), LAYOUT.bone_axes()[[k]], spread)
    mean = np.degrees(np.angle(np.sum(info * np.exp(1j * measured))))
    assert abs(mean + 25.0) < 0.1, mean
    flexion = np.degrees(2 * np.arccos(np.clip(np.abs(relative(motion.q, LAYOUT)[:, k, 0]), 0, 1)))
    bent, straight = info[flexion > 40].mean(), info[flexion < 5].mean()
    assert bent > 3 * straight, (bent, straight)


def test_hinge_axes_learn_the_axis_and_the_heading_left_in_the_data():
    motion = generate(30.0, FS, seed=4, activities=[("running", 30.0)])
    k = [JOINT["knee_l"], JOINT["elbow_r"]]
    r, g = relative(motion.q, LAYOUT)[:, k], vertical_in(motion.q[:, LAYOUT.parent[k]])
    left = quat.multiply(np.concatenate([np.cos(np.radians(3.0) / 2) * np.ones(g.shape[:-1] + (1,)),
                                         np.sin(np.radians(3.0) / 2) * g], -1), r)  # 3 deg left about g
    axes = hinge.HingeAxes((2,), 1e9, 1.0, 0.8)
    axes.add(left, g, np.ones(r.shape[:2], bool), 1 / FS)
    tilt = np.degrees(np.arccos(np.abs(axes.axis @ np.array([1.0, 0.0, 0.0]))))
    assert np.all(tilt < 0.5), tilt
    assert np.allclose(np.degrees(axes.error), -3.0, atol=0.3), np.degrees(axes.error)
    assert np.all(axes.ready > 0.99)


def test_range_counts_ask_for_a_turn_only_when_many_samples_are_out():
    box = rom.limits(["hip_r"])
    motion = generate(20.0, FS, seed=5, activities=[("walking", 20.0)])
    j = JOINT["hip_r"]
    r, g = relative(motion.q, LAYOUT)[:, j], vertical_in(motion.q[:, LAYOUT.parent[j]])
    for turn_deg, asked_for in ((0.0, False), (75.0, True)):
        counts = rom.RangeCounts((), 10.0, 0.2)
        turned = quat.multiply(np.concatenate([np.full(g.shape[:-1] + (1,), np.cos(np.radians(turn_deg) / 2)),
                                               np.sin(np.radians(turn_deg) / 2) * g], -1), r)
        for k in range(0, len(r), 10):
            counts.add(rom.out_of_range(turned[k][None], g[k][None], box)[0], np.array(True), 0.2)
        offset, asked = counts.asked()
        assert bool(asked) == asked_for, (turn_deg, counts.out / counts.seen)
        if asked:  # back into the range, not necessarily all the way
            assert -75.0 <= np.degrees(offset) <= -5.0, np.degrees(offset)


def test_angles_are_scipys_intrinsic_xzy():
    from scipy.spatial.transform import Rotation
    r = Rotation.random(200, random_state=3)
    got = rom.angles(quat.from_rotation(r))
    assert np.abs(wrap(got - r.as_euler("XZY"))).max() < 1e-9


def test_filters_learn_offset_rate_and_mean_from_wrapped_angles():
    f = JointFilters((2,), np.radians([1.0, 0.1, 30.0]), np.radians([0.0, 0.0, 0.0]))
    rate = np.radians([0.2, -0.3])  # rad/s of the offset
    mean = np.radians([20.0, -170.0])
    rng = np.random.default_rng(1)
    for k in range(1, 601):
        f.predict(0.2)
        t = 0.2 * k
        f.update(np.array([1.0, 0.0, -1.0]), wrap(rate * t - mean + np.radians(5.0) * rng.normal(size=2)),
                 np.full(2, 1 / np.radians(5.0) ** 2))
        if k % 50 == 0:  # now and then an absolute measurement of the offset
            f.update(np.array([1.0, 0.0, 0.0]), wrap(rate * t), np.full(2, 1 / np.radians(1.0) ** 2))
    assert np.allclose(np.degrees(wrap(f.x[:, 0] - rate * 120.0)), 0.0, atol=1.0), np.degrees(f.x[:, 0])
    assert np.allclose(f.x[:, 1], rate, atol=np.radians(0.01)), np.degrees(f.x[:, 1])
    assert np.allclose(np.degrees(wrap(f.x[:, 2] - mean)), 0.0, atol=1.5), np.degrees(f.x[:, 2])


def test_drift_model_is_a_bounded_wandering_bias_integrated():
    t = np.arange(0, 600.0, 1 / FS)
    model = DriftModel(bias_dps=0.1, walk=2e-4, tilt_deg=0.5, seed=9)
    d = model.draw(t, 10)
    assert np.all(np.abs(np.degrees(d.bias[0])) <= 0.1)
    assert np.allclose(np.diff(d.heading, axis=0), 0.5 * (d.bias[1:] + d.bias[:-1]) / FS)
    wander = np.degrees(d.bias[-1] - d.bias[0])
    assert 0.0 < np.abs(wander).max() < 0.05, wander
    tilt = quat.angle_deg(d.tilt, np.array([1.0, 0.0, 0.0, 0.0]))
    assert 0.4 < np.sqrt(np.mean(tilt ** 2)) / np.sqrt(2) < 0.6
    bad = model.bad_day().draw(t, 10)
    assert np.allclose(bad.bias[0], 2 * d.bias[0])
    assert np.array_equal(model.draw(t, 10).heading, d.heading)


# -- the loop ---------------------------------------------------------------------------------------


def test_loop_joins_clips_without_a_jump_and_keeps_a_hinge_a_hinge(cmu_npz):
    clips = {m.name: m for m in load(cmu_npz)}
    walk = clips["02_01"]  # 2.8 s: a seam every 1.8 s
    m = looped([walk], 30.0)
    assert m.q.shape == (1500, 10, 4)
    step = quat.angle_deg(m.q[1:], m.q[:-1])
    own = quat.angle_deg(walk.q[1:], walk.q[:-1])
    assert step.max() <= own.max() + 0.5, (step.max(), own.max())
    rate_change = np.abs(np.diff(step, axis=0))
    assert rate_change.max() <= np.abs(np.diff(own, axis=0)).max() + 0.5
    jumps = looped([clips["01_01"]], 60.0)  # knees are exact hinges in this clip
    layout = Layout.of(jumps.segments, jumps.rest_pose)
    r = relative(jumps.q, layout)[:, JOINT["knee_l"]]
    v = r[:, 1:] * np.sign(r[:, :1])
    axis = np.linalg.eigh(v.T @ v)[1][:, 2]
    off = np.degrees(np.arcsin(np.linalg.norm(np.cross(v, axis), axis=1) / np.maximum(np.linalg.norm(v, axis=1), 1e-9)))
    assert off[np.linalg.norm(v, axis=1) > 0.05].max() < 0.1


def test_loop_refuses_mismatched_or_short_clips():
    a = generate(5.0, FS, seed=1)
    with pytest.raises(ValueError, match="shorter than twice"):
        looped([generate(1.0, FS, seed=1)], 10.0)
    with pytest.raises(ValueError, match="differs"):
        looped([a, generate(5.0, 100.0, seed=1)], 10.0)


# -- the estimator ----------------------------------------------------------------------------------


def online(est: HeadingCorrection, q: np.ndarray, present: np.ndarray | None = None,
           restarts: dict[int, tuple[int, int]] | None = None) -> np.ndarray:
    """(n, B, S) the corrections the live estimator applies at each tick of ``q`` (n, B, S, 4)."""
    out = np.empty(q.shape[:-1])
    for k in range(len(q)):
        if restarts and k in restarts:
            est.restart(*restarts[k])
        out[k] = est.update(q[k], None if present is None else present[k])
    return out


def test_online_ticks_give_what_the_batch_gives_and_subjects_stay_apart():
    truth = generate(30.0, FS, seed=6).q
    q = np.stack([drifting(truth, 0.1, 1), drifting(truth, 0.2, 2)], axis=1)
    est = HeadingCorrection(LAYOUT, 2, FS)
    applied = HeadingCorrection.apply(q, online(est, q))
    for b in range(2):
        alone = HeadingCorrection.batch(q[:, b], LAYOUT, FS, row=b)
        assert quat.angle_deg(applied[:, b], alone).max() < 1e-6


def test_subjects_step_on_different_ticks_and_may_come_apart():
    """The subjects' steps are spread over the ticks of a block; a subject whose ticks come on
    their own, in bursts, at other times than the others' (the aggregator's subjects), and a
    subject added later get what one fed in step with the others gets."""
    truth = generate(6.0, FS, seed=7).q
    q = np.stack([drifting(truth, 0.1 * (b + 1), b) for b in range(12)], axis=1)
    est = HeadingCorrection(LAYOUT, 12, FS)
    stepping = []
    for k in range(len(q)):
        before = est.pending.copy()
        est.update(q[k])
        stepping.append(int(np.sum(est.pending < before + 1)))
    assert max(stepping) <= -(-12 // est.block) and sum(stepping) >= 12 * (len(q) // est.block), stepping
    apart = HeadingCorrection(LAYOUT, 2, FS)
    rows = apart.add_subjects(10)
    assert rows.tolist() == list(range(2, 12))
    burst = np.random.default_rng(0).integers(0, 4, len(q))  # subject 5's ticks held back, then taken at once
    waiting: list[int] = []
    others = np.array([b for b in range(12) if b != 5])
    for k in range(len(q)):
        waiting.append(k)
        if burst[k] == 0 or k == len(q) - 1:  # with the others' tick: subject 5 several times in one call
            apart.take(np.concatenate([others[::-1], np.full(len(waiting), 5)]),
                       np.concatenate([q[k, others[::-1]], q[waiting, 5]]))
            waiting = []
        else:
            apart.take(others[::-1], q[k, others[::-1]])
    for name in ("offset_deg", "rate_dpm", "confidence"):
        assert np.abs(apart.status()[name] - est.status()[name]).max() < 1e-9, name
    assert np.abs(apart.filters.x - est.filters.x).max() < 1e-12 and np.array_equal(apart.pending, est.pending)


def test_a_subject_joins_after_a_burst():
    """A burst of one subject's ticks widens the room kept per subject between steps; a subject
    added after that gets the same room and is corrected as one that was there from the start."""
    truth = generate(4.0, FS, seed=3).q
    q = np.stack([drifting(truth, 0.1, 0), drifting(truth, 0.2, 1)], axis=1)
    late = HeadingCorrection(LAYOUT, 1, FS)
    late.take(np.zeros(3 * late.block, np.int64), q[:3 * late.block, 0])  # 3 blocks at once
    assert late.add_subjects(1).tolist() == [1]
    both = HeadingCorrection(LAYOUT, 2, FS)
    both.take(np.zeros(3 * both.block, np.int64), q[:3 * both.block, 0])
    for k in range(3 * late.block, len(q)):
        late.take(np.array([0, 1]), q[k])
        both.take(np.array([0, 1]), q[k])
    assert late.pending.tolist() == both.pending.tolist()
    assert np.abs(late.filters.x - both.filters.x).max() < 1e-12
    assert np.abs(late.status()["offset_deg"] - both.status()["offset_deg"]).max() < 1e-9


SESSION_S = 150.0
RESTART_S, HOLD_S = 60.0, (45.0, 135.0)


@pytest.fixture(scope="module")
def session():
    """Five subjects of generated motion in one estimator, 150 s: (truth, readings, corrections,
    status at the end). 0: headings drifting; 1: standing still, drifting; 2: stiff knees, no
    drift; 3: drifting, its right shank restarting at 60 s with its heading half a turn off;
    4: no drift, the head turned to 85 deg from 45 to 135 s."""
    n = round(SESSION_S * FS)
    # the default schedule without its still moments: a still, standing body is a known pose, which
    # would tell the stiff knees' headings (subject 2) apart from their bending
    moving = [item for item in DEFAULT_SCHEDULE if item[0] != "still"]
    truth = np.stack([generate(SESSION_S, FS, seed=s, activities=moving).q for s in range(5)], axis=1)
    truth[:, 1] = truth[0, 1]
    truth[:, 2, SEG["l_shank"]], truth[:, 2, SEG["r_shank"]] = truth[:, 2, SEG["l_thigh"]], truth[:, 2, SEG["r_thigh"]]
    held = slice(round(HOLD_S[0] * FS), round(HOLD_S[1] * FS))
    turned = quat.multiply(truth[held, 4, SEG["hip"]], np.array([np.cos(np.radians(42.5)), 0.0, np.sin(np.radians(42.5)), 0.0]))
    truth[held, 4, SEG["neck"]] = turned
    q = truth.copy()
    for b, bias in ((0, 0.1), (1, 0.1), (3, 0.1)):
        q[:, b] = drifting(truth[:, b], bias, seed=10 + b)
    k = round(RESTART_S * FS)
    q[k:, 3, SEG["r_shank"]] = quat.multiply(yaw(np.radians(170.0)), q[k:, 3, SEG["r_shank"]])
    est = HeadingCorrection(LAYOUT, 5, FS)
    c = online(est, q, restarts={k: (3, SEG["r_shank"])})
    assert c.shape == (n, 5, len(SEGMENTS))
    return truth, q, c, est.status(), est


def test_drifting_headings_are_held_by_the_joints(session):
    truth, q, c, _, _ = session
    last = slice(-round(30 * FS), None)
    before = mean_error(q[last, 0], truth[last, 0])
    after = mean_error(HeadingCorrection.apply(q[last, 0], c[last, 0]), truth[last, 0])
    assert before["hinge"] > 4.0 and before["3-DoF"] > 4.0, before
    assert after["hinge"] < 1.5 and after["3-DoF"] < 0.6 * before["3-DoF"], (before, after)


def test_a_still_subject_keeps_its_joints_and_its_confidence(session):
    truth, q, c, status, _ = session
    err = mean_error(HeadingCorrection.apply(q[:, 1], c[:, 1]), truth[:, 1])
    assert max(err.values()) < 1.0, err  # the drift of 15 deg/min is held, not let through
    assert status["confidence"][1].min() > 0.5, status["confidence"][1]


def test_a_knee_that_never_bends_gets_no_correction_and_loses_confidence(session):
    truth, q, c, status, est = session
    knees = [JOINT["knee_l"], JOINT["knee_r"]]
    knee_offsets = np.degrees(wrap(c[:, 2, [SEG["l_shank"], SEG["r_shank"]]] - c[:, 2, [SEG["l_thigh"], SEG["r_thigh"]]]))
    assert np.abs(knee_offsets).max() < 0.5 and np.abs(np.degrees(est.joint_offsets()[2, knees])).max() < 0.5
    assert np.all(status["confidence"][2, [SEG["l_shank"], SEG["r_shank"]]] < 0.5), status["confidence"][2]
    err = mean_error(HeadingCorrection.apply(q[:, 2], c[:, 2]), truth[:, 2])  # nothing drifts: nothing to undo
    assert max(err.values()) < 1.0, err


def test_a_joint_held_at_its_limit_gets_no_correction(session):
    _, _, c, _, _ = session
    neck = np.degrees(c[:, 4, SEG["neck"]] - c[:, 4, SEG["hip"]])
    assert np.abs(neck).max() < 2.0, np.abs(neck).max()


def test_a_restarted_device_is_relearnt_not_corrected_stale(session):
    truth, q, c, _, _ = session
    k = round(RESTART_S * FS)
    knee = slice(JOINT["knee_r"], JOINT["knee_r"] + 1)
    corrected = HeadingCorrection.apply(q[:, 3], c[:, 3])
    offset = np.degrees(wrap(c[:, 3, SEG["r_shank"]] - c[:, 3, SEG["r_thigh"]]))
    assert abs(offset[k - 1]) > 0.5 and abs(offset[k]) < 1e-9  # the old correction is dropped at once
    err = joint_errors_deg(corrected, truth[:, 3], LAYOUT)[:, knee][:, 0]
    assert err[k + 1] > 100.0  # half a turn off now, and known to be
    assert err[k + round(30 * FS):].mean() < 2.0, err[k + round(30 * FS):].mean()


def test_a_lower_body_alone_is_corrected():
    names = ("hip", "l_thigh", "r_thigh", "l_shank", "r_shank")
    truth = generate(120.0, FS, seed=8).q[:, [SEG[s] for s in names]]
    layout = Layout.of(names, "standing")
    assert layout.joints == ("hip_r", "knee_r", "hip_l", "knee_l")
    q = drifting(truth, 0.15, seed=3)
    corrected = HeadingCorrection.batch(q, layout, FS)
    last = slice(-round(30 * FS), None)
    before, after = mean_error(q[last], truth[last], layout), mean_error(corrected[last], truth[last], layout)
    assert after["hinge"] < 1.5 and after["3-DoF"] < 2.5 and before["3-DoF"] > 4.0, (before, after)


def test_absent_devices_get_no_correction_and_the_rest_average_zero():
    truth = generate(10.0, FS, seed=9).q[:, None]
    present = np.ones(truth.shape[:3], bool)
    present[:, 0, [SEG["neck"], SEG["l_upperarm"]]] = False
    est = HeadingCorrection(LAYOUT, 1, FS)
    c = online(est, drifting(truth[:, 0], 0.2, 4)[:, None], present)
    assert np.all(c[:, 0, SEG["neck"]] == 0) and np.all(c[:, 0, SEG["l_upperarm"]] == 0)
    groups = [[SEG[s] for s in SEGMENTS if s not in ("neck", "l_upperarm", "l_lowerarm")], [SEG["l_lowerarm"]]]
    for group in groups:
        assert np.abs(c[:, 0, group].sum(axis=1)).max() < 1e-9


def test_status_reports_each_devices_offset_rate_and_confidence():
    truth = generate(120.0, FS, seed=10, activities=[("walking", 120.0)]).q
    q = truth.copy()
    rate_dps = 0.1
    q[:, SEG["r_shank"]] = quat.multiply(yaw(np.radians(rate_dps) * np.arange(len(q)) / FS), q[:, SEG["r_shank"]])
    est = HeadingCorrection(LAYOUT, 1, FS)
    online(est, q[:, None])
    status = est.status()
    assert set(status) == {"offset_deg", "rate_dpm", "confidence"}
    assert all(v.shape == (1, len(SEGMENTS)) for v in status.values())
    shank = SEG["r_shank"]
    expected_rate = -rate_dps * 60 * (1 - 1 / len(SEGMENTS))  # undone relative to the others' mean
    assert abs(status["rate_dpm"][0, shank] - expected_rate) < 0.15 * abs(expected_rate), status["rate_dpm"]
    assert abs(status["offset_deg"][0, shank] + rate_dps * 120 * 0.9) < 1.5, status["offset_deg"]
    assert status["confidence"][0, shank] > 0.5


def test_settings_and_shapes_are_checked():
    est = HeadingCorrection(LAYOUT, 2, FS, Settings())
    with pytest.raises(ValueError, match="q"):
        est.update(np.zeros((3, len(SEGMENTS), 4)))
    with pytest.raises(ValueError, match="update_s"):
        HeadingCorrection(LAYOUT, 1, FS, Settings(update_s=0.0))
