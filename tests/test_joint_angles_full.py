"""Joint angles of the ``full`` layout (limbstream.joints with a layout): the joint tables per
layout and the rule a layout file's joints follow, zero at rest in both rest poses, the sign of
every new angle in a constructed pose, every angle back from poses built joint by joint, and the
``.mot`` columns and error figures of a full-layout motion."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from limbstream import calibration, quat, wire
from limbstream.body import FULL, PAPER10, layout
from limbstream.joints import GIMBAL, TO_OPENSIM, angle_names, joint_angles, pooled_errors, true_angles
from limbstream.sources import Motion

SEG = FULL.segment_index
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
X, Y, Z = np.eye(3)  # limbstream's axes: X the subject's left, Y up, Z forward
NEW = ("ankle_angle_r", "subtalar_angle_r", "ankle_angle_l", "subtalar_angle_l", "lumbar_extension", "lumbar_bending",
       "lumbar_rotation", "wrist_flex_r", "wrist_dev_r", "wrist_flex_l", "wrist_dev_l")
EXAMPLES = "examples/layouts"


def turn(axis, deg) -> np.ndarray:
    return calibration.axis_angle(np.asarray(axis, np.float64), np.radians(deg))


def rest(n: int = 1) -> np.ndarray:
    return np.tile(IDENTITY, (n, len(FULL.segments), 1))


def full_angles(q, **kwargs) -> tuple[dict[str, np.ndarray], np.ndarray]:
    got, flags = joint_angles(q, layout="full", **kwargs)
    return {name: got[..., k] for k, name in enumerate(wire.joint_angles("full"))}, flags


def test_joint_tables_per_layout():
    assert wire.joint_table("paper10") is wire.JOINT_TABLE and wire.joint_angles("paper10") == wire.JOINT_ANGLES
    assert angle_names("paper10") == wire.JOINT_ANGLES
    assert wire.joint_table("full") is wire.FULL_JOINT_TABLE
    # the rule a layout file follows gives each built-in layout its own table back
    assert wire.joint_table(PAPER10) == wire.JOINT_TABLE and wire.joint_table(FULL) == wire.FULL_JOINT_TABLE
    names = wire.joint_angles("full")
    assert len(names) == len(set(names)) == 30 and set(NEW) <= set(names)
    assert set(wire.JOINT_ANGLES) <= set(names)
    joints = {j.name: (j.parent, j.child) for j in wire.FULL_JOINT_TABLE}
    assert joints["lumbar"] == ("hip", "chest") and joints["neck"] == ("chest", "head")
    assert joints["shoulder_r"] == ("chest", "r_upperarm") and joints["wrist_l"] == ("l_lowerarm", "l_hand")
    assert joints["ankle_r"] == ("r_shank", "r_foot")
    with pytest.raises(ValueError, match="layout must be one of"):
        wire.joint_table("paper11")


def test_a_layout_files_joints_follow_from_its_segments():
    """suit17 hangs the upper arms off clavicles: the shoulders are still measured from the chest
    (an ancestor); back16 has no segment named chest: no lumbar angles or neck, the shoulders from
    the pelvis (as paper10's), its ankles and wrists as full's."""
    suit = wire.joint_table(f"{EXAMPLES}/suit17.toml")
    assert suit == wire.FULL_JOINT_TABLE
    back = {j.name: j.parent for j in wire.joint_table(layout(f"{EXAMPLES}/back16.json"))}
    assert set(back) == {"hip_r", "knee_r", "ankle_r", "hip_l", "knee_l", "ankle_l", "shoulder_r", "elbow_r",
                         "wrist_r", "shoulder_l", "elbow_l", "wrist_l"}
    assert back["shoulder_r"] == "hip"
    # a parent that is not an ancestor of the child does not make a joint
    among = wire.joints_among(["hip", "chest", "r_upperarm"], {"hip": None, "chest": "hip", "r_upperarm": "hip"})
    assert [(j.name, j.parent) for j in among] == [("lumbar", "hip"), ("shoulder_r", "hip")]  # the arm hangs off the pelvis
    got, _ = joint_angles(np.tile(IDENTITY, (1, 17, 1)), layout=f"{EXAMPLES}/suit17.toml")
    assert got.shape == (1, 30) and np.abs(got).max() == 0.0


@pytest.mark.parametrize("rest_pose", wire.REST_POSES)
def test_the_rest_pose_gives_zero_everywhere(rest_pose):
    """Standing: every segment at identity, the feet flat on the floor. T-pose data: the arms and
    hands out along +-X at identity; lowered to the sides they are the standing rest pose."""
    q = rest(2)
    if rest_pose == "tpose":
        for s, sign in (("l", -1.0), ("r", 1.0)):
            q[:, [SEG[f"{s}_upperarm"], SEG[f"{s}_lowerarm"], SEG[f"{s}_hand"]]] = turn(Z, sign * 90)
    for dtype in (np.float64, np.float32):
        got, flags = joint_angles(q.astype(dtype), rest_pose=rest_pose, layout="full")
        assert got.shape == (2, 30) and np.abs(got).max() < 1e-4 and not flags.any()
    if rest_pose == "tpose":  # identity in a T-pose: the arms out, the hands in line with them
        a, _ = full_angles(rest(1), rest_pose="tpose")
        assert a["arm_add_r"][0] == pytest.approx(-90.0) and a["wrist_flex_r"][0] == pytest.approx(0.0, abs=1e-9)


def descendants(segment: str) -> list[str]:
    """``segment`` and every segment of the full layout that hangs off it."""
    out = [segment]
    for s in FULL.segments:  # parents first
        if s.parent in out:
            out.append(s.name)
    return out


def test_each_new_angle_has_the_models_sign():
    """Constructed poses, one movement each (limbstream's axes: X left, Y up, Z forward; the palms
    face the thighs at rest, thumbs forward)."""
    poses = {  # segment: its turn from rest; the angle expected
        "ankle_angle_r": ("r_foot", turn(-X, 20), 20.0),       # the toes up: dorsiflexion
        "ankle_angle_l": ("l_foot", turn(X, 30), -30.0),       # the toes down: plantarflexion
        "subtalar_angle_r": ("r_foot", turn(Z, 15), 15.0),     # the right sole turned to the left (medial): inversion
        "subtalar_angle_l": ("l_foot", turn(-Z, 15), 15.0),    # the left sole turned to the right (medial): inversion
        "lumbar_extension": ("chest", turn(X, 30), -30.0),     # the trunk forward: flexion, negative extension
        "lumbar_bending": ("chest", turn(Z, 10), 10.0),        # the trunk bent to the right (its top to -X)
        "lumbar_rotation": ("chest", turn(Y, 25), 25.0),       # the chest turned to the left (as neck_rotation)
        "wrist_flex_r": ("r_hand", turn(Z, 40), 40.0),         # the right fingers towards the palm (medial): flexion
        "wrist_flex_l": ("l_hand", turn(-Z, 40), 40.0),        # the left fingers towards the palm (medial): flexion
        "wrist_dev_r": ("r_hand", turn(X, 12), 12.0),          # the fingers back, to the little finger: ulnar deviation
        "wrist_dev_l": ("l_hand", turn(-X, 8), -8.0),          # the fingers forward, to the thumb: radial deviation
    }
    for name, (segment, q_turn, expect) in poses.items():
        q = rest(1)
        q[0, [SEG[s] for s in descendants(segment)]] = q_turn  # the segment and what hangs off it
        got, flags = full_angles(q)
        assert got[name][0] == pytest.approx(expect, abs=1e-9), name
        others = [k for k, v in got.items() if k != name and abs(v[0]) > 1e-9]
        assert others == [], (name, others)
        assert not flags.any()


def test_the_generators_full_body_gives_its_own_ankle_and_wrist_angles_back():
    """The generator builds each foot from its shank turned by its own ankle flexion and subtalar
    inversion, each hand from its forearm by wrist flexion and deviation, the palm against the thigh
    at rest as the convention's (``generator_limbs``): the same angles come back exactly, through
    every activity; its
    trunk (pelvis -> chest, another Euler order) bends the same way: flexion reads as negative
    lumbar extension, within a degree."""
    from limbstream.sources import generator

    source = generator.GeneratorSource(seed=3, fs=50.0, layout="full")
    t = np.arange(0.0, source.period_s, 0.02)
    got, flags = full_angles(source.orientations(t))
    truth = source.joint_angles(t)
    for mine, theirs in (("ankle_angle_l", "ankle_flex_l"), ("ankle_angle_r", "ankle_flex_r"),
                         ("subtalar_angle_l", "subtalar_l"), ("subtalar_angle_r", "subtalar_r"),
                         ("wrist_flex_l", "wrist_flex_l"), ("wrist_flex_r", "wrist_flex_r"),
                         ("wrist_dev_l", "wrist_dev_l"), ("wrist_dev_r", "wrist_dev_r")):
        assert np.abs(got[mine] - truth[theirs]).max() < 1e-6, mine
        assert np.ptp(truth[theirs]) > 15
    assert np.abs(got["lumbar_extension"] + truth["trunk_flex"]).max() < 1.0 and np.ptp(truth["trunk_flex"]) > 10
    assert np.abs(got["lumbar_rotation"] - truth["trunk_rot"]).max() < 1.0 and np.ptp(truth["trunk_rot"]) > 10
    assert not (flags & ~np.uint8(GIMBAL)).any()


def test_joints_measured_from_the_chest():
    """The shoulders and the neck follow the chest: a trunk bent forward with the arms and head
    along reads lumbar flexion only; the head bent back against an upright chest reads neck
    extension; the arm raised forward against a chest bent forward reads the difference."""
    q = rest(1)
    bent = turn(X, 30)
    for segment in ("chest", "head", "l_upperarm", "l_lowerarm", "l_hand", "r_upperarm", "r_lowerarm", "r_hand"):
        q[0, SEG[segment]] = bent
    got, _ = full_angles(q)
    assert got["lumbar_extension"][0] == pytest.approx(-30.0)
    assert max(abs(v[0]) for k, v in got.items() if k != "lumbar_extension") < 1e-9
    q[0, SEG["r_upperarm"]] = q[0, SEG["r_lowerarm"]] = q[0, SEG["r_hand"]] = turn(X, -50)  # the arm forward, 50 deg
    q[0, SEG["head"]] = turn(-X, 15)  # the head back, 45 deg against the chest
    got, _ = full_angles(q)
    assert got["arm_flex_r"][0] == pytest.approx(80.0) and got["neck_extension"][0] == pytest.approx(45.0)


def test_constructed_poses_give_back_every_angle():
    """Each joint's child is its parent turned by F Rz(a) Rx(b) Ry(c) F^-1 in OpenSim's axes (F
    the joint's model frame; scipy builds the rotation); the angles read back with the model's
    signs, whatever the pelvis's orientation."""
    rng = np.random.default_rng(5)
    n = 300
    names = wire.joint_angles("full")
    truth = {name: rng.uniform(-60.0, 60.0, n) for name in names}
    q = rest(n)
    q[:, SEG["hip"]] = quat.from_rotation(Rotation.random(n, random_state=rng))
    to_limbstream = quat.conjugate(TO_OPENSIM)
    for joint in wire.FULL_JOINT_TABLE:  # parents before their children
        zxy = np.stack([truth[a] * s if a else np.zeros(n) for a, s in zip(joint.angles, joint.signs)], axis=1)
        local = quat.from_rotation(Rotation.from_euler("ZXY", zxy, degrees=True))
        frame = np.array(joint.frame)
        local = quat.multiply(quat.multiply(frame, local), quat.conjugate(frame))
        local = quat.multiply(quat.multiply(to_limbstream, local), TO_OPENSIM)
        q[:, SEG[joint.child]] = quat.multiply(q[:, SEG[joint.parent]], local)
    got, flags = full_angles(q)
    assert not flags.any()
    for name in names:
        err = np.abs(got[name] - truth[name]).max()
        assert err < 1e-6, (name, err)


def test_a_missing_hand_leaves_the_wrist_without_numbers():
    q = rest(1)
    present = np.ones(len(FULL.segments), bool)
    present[SEG["l_hand"]] = False
    got, flags = full_angles(q, present=present)
    assert np.isnan(got["wrist_flex_l"]).all() and np.isnan(got["wrist_dev_l"]).all()
    assert np.isfinite(got["wrist_flex_r"]).all() and np.isfinite(got["elbow_flex_l"]).all()


def full_motion(n: int = 200, seed: int = 0) -> Motion:
    """A full-layout motion built from orientations: every new joint moving about its own axes."""
    t = np.arange(n) / 50.0
    rng = np.random.default_rng(seed)
    q = rest(n)
    q[:, SEG["hip"]] = quat.from_rotation(Rotation.random(n, random_state=rng))
    wave = 20.0 * np.sin(2 * np.pi * 0.5 * t)
    for segment, axis in (("chest", X), ("head", -X), ("r_thigh", -X), ("l_thigh", X), ("r_shank", X), ("l_shank", X),
                          ("r_foot", -X), ("l_foot", Z), ("r_upperarm", -X), ("l_upperarm", Z), ("r_lowerarm", -X),
                          ("l_lowerarm", -X), ("r_hand", Z), ("l_hand", X)):
        parent = FULL.segment(segment).parent
        q[:, SEG[segment]] = quat.multiply(q[:, SEG[parent]],
                                           calibration.axis_angle(np.tile(axis, (n, 1)), np.radians(wave)))
    return Motion(t, q, FULL.segment_names, name="full", rest_pose="standing")


def test_true_angles_and_error_figures_of_a_full_layout_motion():
    motion = full_motion()
    assert motion.layout is FULL
    got, flags = true_angles(motion)
    names = wire.joint_angles("full")
    assert got.shape == (len(motion.t), len(names)) and not flags.any()
    assert np.ptp(got[:, names.index("ankle_angle_r")]) > 30 and np.ptp(got[:, names.index("wrist_flex_r")]) > 30
    # an estimate off by 2 degrees of wrist flexion on the right hand only
    estimate = motion.q.copy()
    estimate[:, SEG["r_hand"]] = quat.multiply(estimate[:, SEG["r_hand"]], turn(Z, 2.0))
    figures = pooled_errors([(estimate, motion.q, "standing", "full")], "paper10")
    assert figures["wrist_flex_r"]["mean"] == pytest.approx(2.0, abs=1e-6)
    assert figures["wrist_flex_l"]["mean"] == pytest.approx(0.0, abs=1e-9)
    assert figures["ankle_angle_l"]["n"] == len(motion.t)
    assert list(figures)[:len(wire.JOINT_ANGLES)] == list(wire.JOINT_ANGLES)  # paper10's first, then full's others
    assert set(figures) == set(names)


def test_eval_scores_the_new_joints_of_a_full_layout_motion(tmp_path, capsys):
    """``eval --joint-angles`` on a full-layout motion file (built from orientations): the joint
    angle table lists the full layout's angles, the per-joint-kind table has ankles, wrists and
    the lumbar spine, and the dump holds the body in the full layout's segment order."""
    from limbstream import cli

    motion = full_motion(n=500)
    np.savez(tmp_path / "full.npz", clip_full=motion.q, fs=np.float64(50.0), segment_names=np.array(motion.segments),
             rest_pose=np.array("standing"))
    (tmp_path / "dump").mkdir()
    assert cli.main(["eval", str(tmp_path / "full.npz"), "--algorithms", "fastsw", "--thresholds", "1e-3",
                     "--joint-angles", "--dump", str(tmp_path / "dump")]) == 0
    text = capsys.readouterr().out
    kinds = [line.split()[3] for line in text.split("joint error per joint")[1].split("joint positions")[0].splitlines()
             if line.startswith("fastsw ")]
    assert kinds == ["knees", "elbows", "ankles", "wrists", "hips", "shoulders", "lumbar", "neck"], text
    lines = {ln.split()[3]: ln.split()[4:] for ln in text.split("joint angles of the reconstruction")[1].splitlines()
             if ln.startswith("fastsw ")}
    assert list(lines) == list(wire.joint_angles("full")), text
    for name in NEW:  # mean, p99, bias, frames, gimbal
        assert 0.0 <= float(lines[name][0]) < 1.0 and int(lines[name][3]) == len(motion.t), (name, lines[name])
    dump = np.load(tmp_path / "dump" / "full.npz")
    assert tuple(dump["segment_names"]) == FULL.segment_names and dump["estimated"].shape == (500, 15, 4)
    assert "lumbar" in set(dump["joints"]) and "wrist_r" in set(dump["joints"])


def test_heading_correction_holds_the_new_joints_of_a_full_body():
    """A full-layout motion through sensors whose headings drift: held by the joints (the ankles,
    wrists and lumbar spine among them: their twist and range), the ankles' and the lumbar
    spine's joint error falls and no kind's grows."""
    from limbstream import evaluation

    streams = evaluation.streams_of([full_motion(n=3000, seed=1)], calibration.SensorModel(90, 180, 0.1, seed=2))
    off, on = (evaluation.evaluate(streams, ["fastsw"], [9e-4], 25, heading=h)[0] for h in (False, True))
    assert set(on["joint_kinds"]) == {"knee", "elbow", "ankle", "wrist", "hip", "shoulder", "lumbar", "neck"}
    mean = {k: (off["joint_kinds"][k]["mean"], on["joint_kinds"][k]["mean"]) for k in on["joint_kinds"]}
    assert all(held <= free + 0.05 for free, held in mean.values()), mean
    assert mean["ankle"][1] < mean["ankle"][0] - 0.1 and mean["lumbar"][1] < mean["lumbar"][0], mean


def test_mot_of_a_full_layout_motion_has_the_models_columns(tmp_path):
    """The ``.mot`` of a full-layout motion: time and the full layout's angles under the model's
    coordinate names, the values the joint angles'; without hands, no wrist columns."""
    from support.export import storage_columns

    from limbstream.services.outputs.opensim import mot_of

    motion = full_motion(n=100)
    (tmp_path / "full.mot").write_text(mot_of("full", motion.t, motion.q, "calibration: segments", "full"))
    storage, columns = storage_columns(tmp_path / "full.mot")
    assert list(columns) == ["time", *wire.joint_angles("full")]
    assert storage.getSize() == 100 and storage.getColumnLabels().getSize() == 31
    truth, _ = true_angles(motion)
    for k, name in enumerate(wire.joint_angles("full")):
        assert columns[name] == pytest.approx(truth[:, k], abs=1e-4), name
    assert columns["time"] == pytest.approx(motion.t - motion.t[0], abs=1e-6)
    present = np.ones(len(FULL.segments), bool)
    present[[SEG["l_hand"], SEG["r_hand"]]] = False
    (tmp_path / "no_hands.mot").write_text(mot_of("no hands", motion.t, motion.q, "c", FULL, present=present))
    _, columns = storage_columns(tmp_path / "no_hands.mot")
    assert list(columns) == ["time", *(a for a in wire.joint_angles("full") if not a.startswith("wrist"))]
    with pytest.raises(ValueError, match="no joint has both"):  # the pelvis alone
        mot_of("one", motion.t, motion.q, "c", "full", present=np.eye(len(FULL.segments), dtype=bool)[SEG["hip"]])


def test_a_full_layout_joint_angle_message_carries_its_layout():
    """A full subject's message: version 2, layout code 1, its 30 angles (174 bytes), back with
    the angles' names; a layout file's (code 255) needs the subject's layout to be read; a batch
    decodes to one layout (another layout's payload is refused)."""
    n = len(wire.joint_angles("full"))
    got, flags = joint_angles(full_motion(n=4).q, layout="full")
    frames = wire.AngleFrames(np.arange(4), np.arange(4) * 20_000, np.full(4, wire.KIND_LIVE),
                              np.full(4, wire.BASIS["segments"]), np.full(4, np.nan), got, flags, FULL)
    payloads = frames.encode()
    assert [len(p) for p in payloads] == [24 + 5 * n] * 4 == [174] * 4
    assert payloads[0][0] == wire.ANGLES_VERSION == 2 and payloads[0][3] == n and payloads[0][20] == 1
    back = wire.decode_angles(payloads[2])
    assert back.layout is FULL and back.names == wire.joint_angles("full")
    assert np.allclose(back.angles, got[2], atol=1e-4) and np.array_equal(back.flags, flags[2])
    js = back.to_json("s01")
    assert js["layout"] == "full" and list(js["angles"]) == list(wire.joint_angles("full"))
    paper10 = wire.AngleFrames(np.arange(1), np.zeros(1), np.full(1, 1), np.full(1, wire.BASIS["segments"]),
                               np.full(1, np.nan), np.zeros((1, 19)), np.zeros((1, 19), np.uint8)).encode()
    together, reasons = wire.decode_angles_many(payloads[:2] + paper10 + payloads[2:])
    assert reasons == ["", "", "layout", "", ""] and len(together) == 4 and together.layout is FULL
    with pytest.raises(ValueError, match="angles for a layout of 30"):
        wire.AngleFrames(np.arange(1), np.zeros(1), np.full(1, 1), np.full(1, 3), np.full(1, np.nan),
                         np.zeros((1, 19)), np.zeros((1, 19), np.uint8), FULL).encode()
    suit = layout(f"{EXAMPLES}/suit17.toml")
    (own,) = wire.AngleFrames(np.arange(1), np.zeros(1), np.full(1, 1), np.full(1, 3), np.full(1, np.nan),
                              np.zeros((1, 30)), np.zeros((1, 30), np.uint8), suit).encode()
    assert own[20] == wire.OTHER_LAYOUT
    with pytest.raises(wire.WireError) as err:
        wire.decode_angles(own)
    assert err.value.reason == "layout"
    assert wire.decode_angles(own, suit).layout is suit
    for short in (b"\x02" * 19, b"short"):  # shorter than the fields every version begins with
        with pytest.raises(wire.WireError) as err:
            wire.decode_angles(short)
        assert err.value.reason == "size"
    from typing import get_args

    from limbstream.services.dashboard.models import AngleName
    assert set(get_args(AngleName)) == set(wire.joint_angles("full"))  # the REST angle filter knows full's angles


def test_the_aggregators_joint_stage_publishes_each_subjects_layout():
    """The joint stage told each subject's layout (``layout_of``): a ``paper10`` subject's message
    and a ``full`` subject's from one tick's frames (a group per layout), each the joint angles of
    its own frame in its own layout."""
    from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
    from limbstream.services.aggregator.angles import JointStage
    from limbstream.services.aggregator.frames import FrameBatch, FrameGroup

    agg = Aggregator(None, AggregatorSettings())
    for subject in ("s01", "s02"):
        for segment in wire.SEGMENTS:
            agg.on_alive(wire.alive_key(subject, segment), True)
            status = wire.DeviceStatus(wire.device_id(subject, segment), wire.DeviceConfig(), 1, 0, 0,
                                       orientations="segments")
            agg.on_config(wire.config_key(subject, segment), wire.encode_status(status))
    full_index = list(agg.fusion.subjects).index("s02")
    stage = JointStage(agg.fusion, clock=lambda: 0.0, layout_of=lambda i: FULL if i == full_index else None)
    motion = full_motion(n=3)
    paper10_q = motion.q[:, [SEG["head" if s == "neck" else s] for s in wire.SEGMENTS]]
    paper = wire.PoseFrames(np.arange(3), np.arange(3) * 20_000, wire.KIND_LIVE, np.zeros(3, np.uint8), paper10_q,
                            np.zeros((3, 15, 3)), PAPER10)
    full = wire.PoseFrames(np.arange(3, 6), np.arange(3, 6) * 20_000, wire.KIND_LIVE, np.zeros(3, np.uint8), motion.q,
                           np.zeros((3, 20, 3)), FULL)
    live = [FrameGroup(np.full(3, 1 - full_index), paper, np.zeros((3, 10), bool)),
            FrameGroup(np.full(3, full_index), full, np.zeros((3, 15), bool))]
    batch = FrameBatch(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 10, 4)), np.zeros((0, 10), bool), [], live)
    out = list(stage(batch))
    assert len(out) == 6
    for (key, kind, payload), row in zip(sorted(out, key=lambda m: wire.decode_angles(m[2]).seq), range(6)):
        assert kind == wire.ANGLES
        message = wire.decode_angles(payload)
        subject = wire.parse_subject_key(key)[0]
        if row < 3:
            assert subject == ("s01" if full_index == 1 else "s02") and message.layout is None
            want, _ = joint_angles(paper10_q[row].astype(np.float32))
        else:
            assert message.layout is FULL and len(message.angles) == 30
            want, _ = joint_angles(motion.q[row - 3].astype(np.float32), layout="full")
        assert np.allclose(message.angles, want, atol=1e-3), (row, message.angles - want)
