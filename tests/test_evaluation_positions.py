"""``limbstream eval``'s joint positions (limbstream.evaluation.positions): a BVH file's own joints
against paper10's forward kinematics on the file's bones, the error a known turn of one segment
gives, and the dump's positions, compared with the file itself."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from support.bvh import read_bvh_positions, write_bvh

from limbstream import calibration, cli, evaluation, quat
from limbstream.body import PAPER10
from limbstream.evaluation.body import Body
from limbstream.evaluation.positions import errors_cm, positions_of, source_of
from limbstream.sources import load, load_npz
from limbstream.sources.bvh import parse_bvh

LOWER = ("l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle")
"""Joints the file's skeleton places through the segments' own joints alone in 01_01 and 131_xx
(their hip joints' extra rotations are zero): paper10 puts them where the file does."""
BONES = (("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"), ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"),
         ("neck_base", "head"))
"""Bones of single segments above the pelvis: their vectors match the file's, wherever the trunk's
bend (no chest sensor in paper10) puts their start."""
J = PAPER10.joint_index


def _body(motion, estimated=None, source=True) -> Body:
    """An evaluation body of ``motion`` at its own samples, its truth the motion's orientations."""
    t = np.asarray(motion.t, np.float64)
    truth = np.asarray(motion.q, np.float64)
    fields = source_of(motion) if source else {"source": None, "source_offset_s": 0.0}
    return Body(motion.name, t, truth.copy() if estimated is None else estimated, truth, motion.rest_pose, {}, False,
                t + fields["source_offset_s"], fields["source"])


@pytest.mark.parametrize("clip", ["01_01", "131_01"])
def test_the_estimate_on_the_files_bones_puts_the_joints_where_the_file_does(cmu_bvh_dir, clip):
    """At the file's own frames, the estimate being the truth: the file's positions are an
    independent reader's (to 1e-9 m), and paper10's forward kinematics on the file's bones puts
    the legs' joints where the file does and gives every limb bone and the neck the file's
    vector, to well under 1 mm."""
    path = cmu_bvh_dir / f"{clip}.bvh"
    [motion] = load(path, fs=None)
    source = motion.positions
    assert source is not None and source.unit_m == pytest.approx(0.0254 / 0.45)  # CMU's unit
    file = read_bvh_positions(path)
    first = round(source.start_s / source.clip.frame_time)  # 01_01's synthetic T-pose frame is dropped
    own = np.stack([file[name][first:] for name in source.joints()], axis=1)
    own = (own - own[:, :1]) * source.unit_m  # the pelvis at the origin, metres
    places = positions_of(_body(motion))
    assert places.from_file and places.joints == source.joints()
    np.testing.assert_allclose(places.truth, own, atol=1e-9)
    lower = [J[j] for j in LOWER]
    assert np.abs(places.estimated[:, lower] - places.truth[:, lower]).max() < 1e-4
    for a, b in BONES:
        est = places.estimated[:, J[b]] - places.estimated[:, J[a]]
        assert np.abs(est - (own[:, J[b]] - own[:, J[a]])).max() < 1e-4, (a, b)
    trunk = errors_cm(places)[:, J["l_shoulder"]]
    assert trunk.mean() > 1.0  # the spine bends in the file, not in paper10: said, not hidden


def test_at_the_evals_rate_the_legs_are_exact_and_the_error_is_zero_on_the_same_body(cmu_bvh_dir, cmu_npz):
    """The eval's 50 Hz frames, threshold 0 (the reconstruction is the truth): the legs' joints
    of a BVH clip within 1 mm of the file's (interpolated between its 120 Hz frames); for npz
    clips (orientations only) the truth is the true orientations' joints on the same body: 0."""
    [bvh] = evaluation.evaluate(load(cmu_bvh_dir / "01_01.bvh"), ["fastsw"], [0.0])
    for name in ("hip", "knee", "ankle"):
        assert bvh["positions"][name]["p99"] < 0.1, (name, bvh["positions"])
    assert bvh["positions"]["wrist"]["mean"] > 1.0
    [npz] = evaluation.evaluate(load_npz(cmu_npz), ["fastsw"], [0.0])
    assert npz["pos_cm"] < 1e-4 and set(npz["positions"]) == {"hip", "knee", "ankle", "shoulder", "elbow", "wrist",
                                                            "neck_base", "head"}


@pytest.mark.parametrize("segment, moved, bone", [("l_thigh", ("l_knee", "l_ankle"), "l_thigh"),
                                                  ("r_upperarm", ("r_elbow", "r_wrist"), "r_upperarm"),
                                                  ("l_shank", ("l_ankle",), "l_shank")])
@pytest.mark.parametrize("from_file", [True, False])
def test_a_segment_turned_moves_the_joints_below_it_by_the_chord(cmu_bvh_dir, segment, moved, bone, from_file):
    """One segment's estimate turned by 20 deg about an axis across its bone: every joint it
    carries moves by the chord 2 L sin(10 deg) (L: the bone's length on the body used), no other
    joint moves."""
    [motion] = load(cmu_bvh_dir / "131_01.bvh", fs=None)
    half = math.radians(10.0)
    turn = np.array([math.cos(half), 0.0, 0.0, math.sin(half)])  # 20 deg about Z: across every bone here (Z = 0)
    k = motion.segments.index(segment)
    estimated = np.asarray(motion.q, np.float64).copy()
    estimated[:, k] = quat.multiply(estimated[:, k], turn)
    truth = positions_of(_body(motion, source=from_file))
    places = positions_of(_body(motion, estimated, source=from_file))
    length = places.dimensions.lengths[bone]
    chord = 200.0 * length * math.sin(math.radians(10.0))
    shift = np.linalg.norm(places.estimated - truth.estimated, axis=-1) * 100.0  # cm, per frame and joint
    for name, j in J.items():
        expected = chord if name in moved else 0.0
        np.testing.assert_allclose(shift[:, j], expected, atol=1e-6, err_msg=name)
    if not from_file:  # the truth is the same body's: the error is the shift
        np.testing.assert_allclose(errors_cm(places), shift, atol=1e-9)
    for name in LOWER if from_file else ():  # where paper10 puts the file's joints, against the file itself
        np.testing.assert_allclose(errors_cm(places)[:, J[name]], chord if name in moved else 0.0, atol=0.01)


def test_the_dump_holds_the_positions_and_the_file_s_own_joints(cmu_bvh_dir, tmp_path, capsys):
    """``--dump``: per frame its time in the file, the estimated and true positions and the
    file's joint of each; the true positions are the file's (linear between its frames), and the
    row's ``pos`` recomputes from the dump."""
    path = cmu_bvh_dir / "01_01.bvh"
    out = tmp_path / "rows.json"
    code = cli.main(["eval", str(path), "--algorithms", "fastsw", "--thresholds", "9e-4", "--dump", str(tmp_path),
                     "--json", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "the file's own joints" in text and "ankles" in text and "0.0564444 m per unit" in text, text
    [row] = json.loads(out.read_text())
    d = np.load(tmp_path / "01_01.npz")
    m = len(d["t"])
    assert d["source_t"].shape == (m,) and d["positions"].shape == d["true_positions"].shape == (m, 15, 3)
    assert d["position_joints"].shape == (15,) and list(d["position_joints"])[:6] == [
        "Hips", "Neck", "Neck1", "LeftUpLeg", "LeftLeg", "LeftFoot"]
    assert bool(d["positions_from_file"]) and float(d["source_unit_m"]) == pytest.approx(0.0254 / 0.45)
    frame_time = parse_bvh(path).frame_time  # 0.0083333 s
    np.testing.assert_allclose(d["source_t"], d["t"] + frame_time, atol=1e-12)  # frame 0 (a synthetic T-pose) dropped
    file = read_bvh_positions(path)
    frame = d["source_t"] / frame_time
    k = np.floor(frame).astype(int)
    u = (frame - k)[:, None, None]
    own = np.stack([file[str(n)] for n in d["position_joints"]], axis=1)
    own = (own - own[:, :1]) * float(d["source_unit_m"])
    np.testing.assert_allclose(d["true_positions"], own[k] * (1 - u) + own[k + 1] * u, atol=1e-9)  # between frames
    err = np.linalg.norm(d["positions"] - d["true_positions"], axis=-1)[:, 1:] * 100.0  # the pelvis: not scored
    assert err.mean() == pytest.approx(row["pos_cm"], rel=1e-9)


def test_with_a_sensor_model_the_frames_keep_their_file_times(cmu_bvh_dir):
    """After the calibration script the sensor model's and raw sensors' bodies are the motion's:
    each frame's file time is its time in the motion (plus the dropped frame)."""
    [motion] = load(cmu_bvh_dir / "131_03.bvh")
    modelled = evaluation.streams_of([motion], calibration.SensorModel(90, 180, seed=1))
    assert {s.source_offset_s for s in modelled} == {0.0} and modelled[0].t[modelled[0].motion_from] == 0.0
    from limbstream import imu
    from limbstream.evaluation.raw_streams import emulated_streams

    raw = emulated_streams([motion], calibration.SensorModel(90, 180, seed=1), imu.model("icm42688p"))
    s = raw[0]
    assert s.source is motion.positions
    assert s.t[s.motion_from] + s.source_offset_s == pytest.approx(0.0, abs=0.021)  # the first device instant
    [row] = evaluation.evaluate(raw, ["fastsw"], [9e-4], 25)
    assert 0.0 < row["pos_cm"] < 20.0 and row["positions"]["knee"]["n"] > 0


def test_other_exporters_files_give_the_same_joints_and_a_skeleton_paper10_cannot_take_has_none(
        cmu_bvh_dir, tmp_path, capsys):
    """Position channels on every joint and a floor root above the pelvis (other exporters'
    files) give the same joints, root relative; a skeleton on which a paper10 bone has no length
    (the hip joint at the pelvis) loads without positions of its own, and eval says so."""
    clip = parse_bvh(cmu_bvh_dir / "131_03.bvh")
    [plain] = load(cmu_bvh_dir / "131_03.bvh")
    six = tmp_path / "six.bvh"
    six.write_text(write_bvh(clip, six=True, floor_root="Root"))
    [other] = load(six)
    assert other.positions is not None and other.positions.joints() == plain.positions.joints()
    t = np.asarray(plain.t)
    np.testing.assert_allclose(other.positions.at(t), plain.positions.at(t), atol=1e-5)  # 6 decimals in the file
    offsets = clip.offsets.copy()
    offsets[clip.joints.index("LeftHip")] = 0.0
    flat = tmp_path / "flat_hip.bvh"
    flat.write_text(write_bvh(clip, offsets=offsets))
    [motion] = load(flat)
    assert motion.positions is None
    assert cli.main(["eval", str(flat), "--algorithms", "fastsw", "--thresholds", "9e-4"]) == 0
    text = capsys.readouterr().out
    assert "every motion: no positions of its own" in text and "paper10's default" in text, text
