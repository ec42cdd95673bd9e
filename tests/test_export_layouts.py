"""`limbstream export` of a ``full`` subject: a recording of its frames (15 segments, 20 joints)
exports to BVH in the layout's hierarchy (checked with the tests' own BVH reader), to CSV with the
layout's columns and to npz that reads back as a ``full`` motion, which exports again; the
recording's skeletons draw the layout's bones."""
from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.bvh import read_bvh_positions
from support.export import T0_US, cli

from limbstream import quat, wire
from limbstream.body import FULL, PAPER10, Body
from limbstream.services.outputs.bvh_writer import BVH_JOINTS, ROTATION_CHANNELS, bvh_joints
from limbstream.services.outputs.export import csv_header, skeleton_of
from limbstream.services.outputs.recording import RecordingWriter
from limbstream.sources import load

FULL_HIERARCHY = [
    ("Hips", None), ("LowerBack", "Hips"), ("Spine", "LowerBack"), ("Neck", "Spine"), ("LeftArm", "Spine"), ("LeftForeArm", "LeftArm"),
    ("LeftHand", "LeftForeArm"), ("RightArm", "Spine"), ("RightForeArm", "RightArm"), ("RightHand", "RightForeArm"),
    ("LeftUpLeg", "Hips"), ("LeftLeg", "LeftUpLeg"), ("LeftFoot", "LeftLeg"), ("RightUpLeg", "Hips"),
    ("RightLeg", "RightUpLeg"), ("RightFoot", "RightLeg")]
"""full's BVH hierarchy, in the file's order: pelvis -> its bent bone, the lumbar spine (LowerBack,
at the pelvis) -> spine -> neck (the head, its End Site the top of the head); the arms off the
chest (Spine), the hands; the legs off the pelvis, the feet, their End Sites the toes."""
AT = {"Hips": "pelvis", "LowerBack": "pelvis", "Spine": "spine", "Neck": "neck_base", "LeftArm": "l_shoulder", "LeftForeArm": "l_elbow",
      "LeftHand": "l_wrist", "RightArm": "r_shoulder", "RightForeArm": "r_elbow", "RightHand": "r_wrist",
      "LeftUpLeg": "l_hip", "LeftLeg": "l_knee", "LeftFoot": "l_ankle", "RightUpLeg": "r_hip", "RightLeg": "r_knee",
      "RightFoot": "r_ankle"}
BODY = Body.from_height(FULL, 1.80)


def full_motion(n: int) -> np.ndarray:
    """(n, 15, 4) smooth orientations of every ``full`` segment: each swings about its own axis."""
    t = np.arange(n)[:, None] * 0.02
    k = np.arange(len(FULL.segments))[None, :]
    axes = Rotation.random(len(FULL.segments), random_state=3).apply([1.0, 0.0, 0.0])
    angle = 0.6 * np.sin(2 * np.pi * (0.3 + 0.05 * k) * t + k)
    return quat.continuous(quat.from_rotation(Rotation.from_rotvec((angle[..., None] * axes).reshape(-1, 3)))
                           .reshape(n, -1, 4), axis=0)


def write_full_recording(path, q: np.ndarray) -> None:
    """Exact frames of the full subject s01 and a paper10 subject s02's, as the recorder leaves them."""
    writer = RecordingWriter(path)
    frames = wire.PoseFrames(np.arange(len(q)), T0_US + 20_000 * np.arange(len(q)), wire.KIND_EXACT,
                             np.zeros(len(q), np.int64), q, BODY.positions(q), FULL)
    for k, payload in enumerate(frames.encode()):
        writer.add("pose", wire.pose_key("s01"), payload, (T0_US + 20_000 * k) * 1000)
        writer.add_skeleton("s01", frames[k], (T0_US + 20_000 * k) * 1000)  # as the recorder does
    other = wire.PoseFrame(0, T0_US, wire.KIND_EXACT, 0, np.tile(np.float32([1, 0, 0, 0]), (10, 1)))
    writer.add("pose", wire.pose_key("s02"), wire.encode_pose(other), T0_US * 1000)
    writer.close()


def test_the_body_of_a_full_frame_is_its_layouts():
    q = full_motion(3)
    frame = wire.PoseFrames(np.arange(3), np.arange(3), wire.KIND_EXACT, np.zeros(3, np.int64), q,
                            BODY.positions(q), FULL)[2]
    body = skeleton_of(frame)
    assert body.body.layout == FULL and body.rest_pose == "standing"
    assert body.body.lengths == pytest.approx(BODY.lengths, abs=1e-5)
    assert np.allclose(body.positions(q), BODY.positions(q), atol=1e-5)


def test_a_full_recording_exports_its_layouts_bvh_hierarchy(tmp_path):
    q = full_motion(200)
    rec = tmp_path / "take.mcap"
    write_full_recording(rec, q)
    out = tmp_path / "s01.bvh"
    result = cli(str(rec), "--subject", "s01", "--format", "bvh", "-o", str(out))
    assert result.returncode == 0, result.stderr
    assert [(j.name, j.parent) for j in bvh_joints(FULL)] == FULL_HIERARCHY
    assert [(j.name, j.parent) for j in bvh_joints(PAPER10)] == [(j.name, j.parent) for j in BVH_JOINTS]

    text = out.read_text()
    names = [line.split()[1] for line in text.splitlines() if line.strip().split()[:1] in (["ROOT"], ["JOINT"])]
    assert names == [name for name, _ in FULL_HIERARCHY]
    channels = [line.split()[1:] for line in text.splitlines() if line.strip().startswith("CHANNELS")]
    assert channels[0] == ["6", "Xposition", "Yposition", "Zposition", *ROTATION_CHANNELS]
    assert all(c == ["3", *ROTATION_CHANNELS] for c in channels[1:]) and len(channels) == 16
    rest = BODY.positions(np.tile([1.0, 0, 0, 0], (15, 1))).astype(np.float64)
    at = dict(zip(FULL.joints, rest))
    offsets = [np.array(line.split()[1:], float) for line in text.splitlines() if line.strip().startswith("OFFSET")]
    # joints' OFFSETs and the End Sites (head top, hands' fingertips, feet's toes), in the file's order
    parent_at = {name: AT[parent] if parent else AT[name] for name, parent in FULL_HIERARCHY}
    ends = {"Neck": "head_top", "LeftHand": "l_fingertip", "RightHand": "r_fingertip", "LeftFoot": "l_toe",
            "RightFoot": "r_toe"}
    expected = []
    for name, _ in FULL_HIERARCHY:
        expected.append(at[AT[name]] - at[parent_at[name]])
        if name in ends:
            expected.append(at[ends[name]] - at[AT[name]])
    assert len(offsets) == len(expected) == 21
    assert np.allclose(offsets, expected, atol=2e-6)
    lines = [line.split() for line in text.split("MOTION")[0].splitlines()]
    end_of = {lines[i - 6][1]: np.array(line[1:], float) for i, line in enumerate(lines)
              if line[:1] == ["OFFSET"] and lines[i - 2] == ["End", "Site"]}  # the leaves' End Sites
    assert set(end_of) == set(ends)
    foot = BODY.lengths["l_foot"]  # forward (+Z) and down by the ankle's height to the toe (docs/body.md)
    assert end_of["LeftFoot"] == pytest.approx([0.0, -0.257 * foot, 0.967 * foot], abs=1e-3)
    assert end_of["LeftFoot"] == pytest.approx(np.array(FULL.segment("l_foot").directions["standing"]) * foot, abs=2e-6)
    assert end_of["Neck"] == pytest.approx([0.0, BODY.lengths["head"], 0.0], abs=2e-6)
    assert end_of["RightHand"] == pytest.approx([0.0, -BODY.lengths["r_hand"], 0.0], abs=2e-6)

    positions = read_bvh_positions(out)  # an independent reader: every joint where the frames have it
    floor = -rest[:, 1].min()  # the root lifted so the toes touch the floor at rest
    joints = BODY.positions(q).astype(np.float64)
    for name, joint in AT.items():
        err = np.abs(positions[name] - (joints[:, FULL.joint_index[joint]] + [0.0, floor, 0.0])).max()
        assert err < 1e-4, (name, err)


def test_a_full_recording_exports_csv_and_npz_in_its_layout(tmp_path):
    q = full_motion(50)
    rec = tmp_path / "take.mcap"
    write_full_recording(rec, q)
    assert cli(str(rec), "--subject", "s01", "-o", str(tmp_path / "s01.csv")).returncode == 0
    with open(tmp_path / "s01.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == csv_header(FULL) and len(rows[0]) == 4 + 15 * 4 + 20 * 3
    assert {"l_foot_qw", "head_qz", "chest_qx", "r_hand_qy", "l_toe_z", "head_top_y", "r_fingertip_x"} <= set(rows[0])
    cols = {name: i for i, name in enumerate(rows[0])}
    table = np.array(rows[1:], float)
    got_q = table[:, [cols[f"{s}_{c}"] for s in FULL.segment_names for c in ("qw", "qx", "qy", "qz")]].reshape(-1, 15, 4)
    assert len(table) == 50 and quat.angle_deg(got_q, q).max() < 0.01
    toe = table[:, [cols["r_toe_x"], cols["r_toe_y"], cols["r_toe_z"]]]
    assert np.allclose(toe, BODY.positions(q)[:, FULL.joint_index["r_toe"]], atol=1e-4)

    assert cli(str(rec), "--subject", "s01", "-o", str(tmp_path / "s01.npz")).returncode == 0
    data = np.load(tmp_path / "s01.npz")
    assert str(data["layout"]) == "full" and list(data["segment_names"]) == list(FULL.segment_names)
    assert list(data["joint_names"]) == list(FULL.joints) and data["joints"].shape == (50, 20, 3)
    (motion,) = load(tmp_path / "s01.npz")
    assert motion.layout == FULL and quat.angle_deg(motion.q, q).max() < 1e-4
    # the npz, a motion file of the full layout, exports to BVH in the same hierarchy
    result = cli(str(tmp_path / "s01.npz"), "-o", str(tmp_path / "again.bvh"))
    assert result.returncode == 0, result.stderr
    again = read_bvh_positions(tmp_path / "again.bvh")
    assert list(again) == [name for name, _ in FULL_HIERARCHY]
    rest = Body.default(FULL).positions(np.tile([1.0, 0, 0, 0], (15, 1)))  # a motion file without a body: the default's
    ankle = Body.default(FULL).positions(q)[:, FULL.joint_index["l_ankle"]] + [0.0, -rest[:, 1].min(), 0.0]
    assert np.abs(again["LeftFoot"] - ankle).max() < 1e-4


def test_a_full_recordings_skeletons_draw_its_bones(tmp_path):
    """The recorder's skeletons of full frames (foxglove.SceneUpdate, decoded from the schema the
    file carries): a line per bone of the 19, the toes on the grid."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from mcap.reader import make_reader

    q = full_motion(5)
    rec = tmp_path / "take.mcap"
    write_full_recording(rec, q)
    with open(rec, "rb") as f:
        messages = list(make_reader(f).iter_messages(topics=["/s01/skeleton"]))
    assert len(messages) == 5
    schema = messages[0][0]
    pool = descriptor_pool.DescriptorPool()
    for file in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(file)
    update = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name)).FromString(messages[-1][2].data)
    (entity,) = update.entities
    line = entity.lines[0]
    pairs = [(FULL.joints[a], FULL.joints[b]) for a, b in zip(line.indices[::2], line.indices[1::2])]
    assert pairs == [(b.origin, b.joint) for b in FULL.bones] and len(pairs) == 19
    points = np.array([[p.x, p.y, p.z] for p in line.points])
    assert np.allclose(points, BODY.positions(q[-1]), atol=1e-6)
    rest = BODY.positions(np.tile([1.0, 0, 0, 0], (15, 1)))
    assert line.pose.position.z == pytest.approx(rest[FULL.joint_index["l_hip"], 1] - rest[:, 1].min(), abs=1e-5)


def test_a_recordings_skeletons_stand_at_each_frames_root(tmp_path):
    """The recorder's skeletons of frames carrying a root: each at its frame's root, Z up (as
    ``limbstream foxglove`` places them), walking with it."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from mcap.reader import make_reader

    q = full_motion(4)
    root = np.stack([0.1 * np.arange(4), np.full(4, 0.95), -0.2 * np.arange(4)], axis=1)
    frames = wire.PoseFrames(np.arange(4), T0_US + 20_000 * np.arange(4), wire.KIND_EXACT, np.zeros(4, np.int64), q,
                             BODY.positions(q), FULL, root, np.full(4, 0b0101))
    rec = tmp_path / "take.mcap"
    writer = RecordingWriter(rec)
    for k in range(4):
        writer.add_skeleton("s01", frames[k], (T0_US + 20_000 * k) * 1000)
    writer.close()
    with open(rec, "rb") as f:
        messages = list(make_reader(f).iter_messages(topics=["/s01/skeleton"]))
    pool = descriptor_pool.DescriptorPool()
    for file in descriptor_pb2.FileDescriptorSet.FromString(messages[0][0].data).file:
        pool.Add(file)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(messages[0][0].name))
    updates = [cls.FromString(m[2].data) for m in messages]
    placed = [(u.entities[0].lines[0].pose.position.x, u.entities[0].lines[0].pose.position.y,
               u.entities[0].lines[0].pose.position.z) for u in updates]
    assert np.allclose(placed, root[:, [2, 0, 1]], atol=1e-6), placed


def test_opensim_files_of_a_full_take(tmp_path):
    """.mot holds a full take's own joint angles (the full layout's, the model's names: its ankles,
    wrists and lumbar spine too); .sto's OpenSense columns are paper10's: a full take is refused
    with the reason, never written with its segments taken for paper10's."""
    from support.export import storage_columns

    from limbstream.joints import joint_angles

    rec = tmp_path / "take.mcap"
    motion = full_motion(20)
    write_full_recording(rec, motion)
    result = cli(str(rec), "--subject", "s01", "-o", str(tmp_path / "s01.mot"))
    assert result.returncode == 0, result.stderr
    _, columns = storage_columns(tmp_path / "s01.mot")
    names = wire.joint_angles("full")
    assert list(columns)[1:] == list(names)
    truth, _ = joint_angles(motion.astype(np.float32), layout="full")  # the frames' orientations, as recorded
    assert len(columns["time"]) == len(motion)
    for name in ("ankle_angle_r", "wrist_flex_l", "lumbar_extension", "arm_flex_r"):
        assert np.allclose(columns[name], truth[:, names.index(name)], atol=1e-3), name
    result = cli(str(rec), "--subject", "s01", "-o", str(tmp_path / "s01.sto"))
    assert result.returncode != 0 and not (tmp_path / "s01.sto").exists(), result
    last = result.stderr.strip().splitlines()[-1]
    assert "s01: no anatomical frames of the full layout" in last and "Traceback" not in result.stderr, result.stderr
