"""`limbstream export -o X.mot / X.sto`: OpenSim's motion file and OpenSense's orientation file,
read back by OpenSim's own readers (the ``opensim`` package: Storage for .mot, the quaternion
table OpenSense's IMU inverse kinematics reads for .sto)."""
from __future__ import annotations

import numpy as np
import pytest
from support import require_data
from support.export import T0_US, cli, quaternion_table, storage_columns

from limbstream import joints, quat, wire
from limbstream.services.outputs.export import export, from_motion, read_take
from limbstream.services.outputs.opensim import IMU_NAMES
from limbstream.services.outputs.recording import RecordingWriter
from limbstream.skeleton import Skeleton
from limbstream.sources import load, load_npz, names


def test_a_motion_file_exports_joint_angles_and_orientations_opensim_reads(tmp_path, cmu_npz):
    motion = load_npz(cmu_npz)[0]
    truth, flags = joints.true_angles(motion)
    result = cli(str(cmu_npz), "--subject", "s01", "-o", str(tmp_path / "walk.mot"))
    assert result.returncode == 0, result.stderr
    assert "calibration: the source's own segment orientations" in result.stderr
    storage, columns = storage_columns(tmp_path / "walk.mot")
    assert list(columns) == ["time", *joints.ANGLES] and storage.isInDegrees()
    assert storage.getSize() == len(motion.t) and columns["time"] == pytest.approx(motion.t, abs=1e-6)
    for name in joints.ANGLES:
        assert columns[name] == pytest.approx(truth[:, joints.ANGLES.index(name)], abs=1e-4), name
    assert np.ptp(columns["knee_angle_r"]) > 30

    export(read_take(cmu_npz, "s01"), "sto", tmp_path / "walk.sto")
    table, q = quaternion_table(tmp_path / "walk.sto")
    assert table.getColumnLabels() == tuple(IMU_NAMES[s] for s in wire.SEGMENTS)
    assert float(table.getTableMetaDataAsString("DataRate")) == pytest.approx(50.0)
    segments = np.stack([motion.segment(s) for s in wire.SEGMENTS], axis=1)
    want = joints.anatomical(segments, motion.rest_pose)
    assert quat.angle_deg(q, want).max() < 2e-3  # OpenSim prints its quaternions with 6 digits


def test_a_recording_with_a_missing_segment_leaves_those_frames_out(tmp_path, cmu_npz):
    """Frames 200-249 lack the left shank (identity, flag MISSING, as an aggregator fills them):
    OpenSim's Storage takes no NaN, so those frames are left out, and the note says so."""
    motion = load_npz(cmu_npz)[0]
    q = np.stack([motion.segment(s) for s in wire.SEGMENTS], axis=1)[:400].astype(np.float32)
    gone = np.zeros(len(q), bool)
    gone[200:250] = True
    q[gone, wire.SEGMENTS.index("l_shank")] = [1, 0, 0, 0]
    body = Skeleton(rest_pose="tpose")
    writer = RecordingWriter(tmp_path / "take.mcap")
    for k in range(len(q)):
        flags = wire.rest_pose_flag("tpose") | (wire.FRAME_MISSING if gone[k] else 0)
        frame = wire.PoseFrame(k, T0_US + 20_000 * k, wire.KIND_EXACT, flags, q[k], body.positions(q[k]))
        writer.add("pose", wire.pose_key("s01"), wire.encode_pose(frame), (T0_US + 20_000 * k) * 1000)
    writer.close()
    result = cli(str(tmp_path / "take.mcap"), "-o", str(tmp_path / "take.mot"))
    assert result.returncode == 0, result.stderr
    assert "50 frames lack a segment's data" in result.stderr, result.stderr
    _, columns = storage_columns(tmp_path / "take.mot")
    keep = np.flatnonzero(~gone)
    assert columns["time"] == pytest.approx(keep * 0.02, abs=1e-6)
    truth, _ = joints.joint_angles(q.astype(np.float64), rest_pose="tpose")
    assert columns["knee_angle_l"] == pytest.approx(truth[keep, joints.ANGLES.index("knee_angle_l")], abs=1e-3)


def test_the_xsens_walk_exports_calibrated_functionally(tmp_path):
    """``limbstream export ../shared/data/xsens_opensense --names opensense -o walk.mot``: the
    loader calibrates the sensors from the still first second, the export finds the knees' facing
    (and only turns the segments about the vertical by it), and knee flexion peaks at 60-70 deg."""
    folder = require_data("xsens_opensense")
    result = cli(str(folder), "--names", "opensense", "-o", str(tmp_path / "walk.mot"))
    assert result.returncode == 0, result.stderr
    assert "calibration: rest pose from the first 1 s standing still, functional facing" in result.stderr
    storage, columns = storage_columns(tmp_path / "walk.mot")
    assert list(columns)[1:] == [a for a in joints.ANGLES if a.startswith(("hip", "knee"))]
    assert columns["time"][0] == 0.0
    for side in "lr":
        assert 60.0 <= columns[f"knee_angle_{side}"].max() <= 72.0, side
        assert np.ptp(columns[f"hip_flexion_{side}"]) > 30.0

    (motion,) = load(folder, names.NAMED["opensense"])
    assert motion.orientations == "rest"
    take = from_motion([motion], None, folder, None)
    assert take.anatomical and "functional facing" in take.basis, take.basis
    t = (take.t_us - take.t_us[0]) / 1e6
    for segment in ("hip", "l_thigh", "r_shank"):  # the facing is a turn about the vertical: angles from rest kept
        loaded = quat.interpolate(motion.t, motion.segment(segment), t)
        exported = take.q[:, wire.SEGMENTS.index(segment)]
        assert np.abs(np.abs(exported[:, 0]) - np.abs(loaded[:, 0])).max() < 1e-6, segment
        assert np.abs(exported[:, 2]) == pytest.approx(np.abs(loaded[:, 2]), abs=1e-6), segment  # about Y too
    export(take, "sto", tmp_path / "walk.sto")
    table, q = quaternion_table(tmp_path / "walk.sto")
    assert table.getColumnLabels() == ("tibia_l_imu", "tibia_r_imu", "femur_l_imu", "femur_r_imu", "pelvis_imu")
    assert quat.angle_deg(q[:50], np.array([1.0, 0, 0, 0])).max() < 5.0  # standing still: the rest pose


def test_sensors_without_a_moving_hinge_get_no_angles_and_are_told_why(tmp_path):
    folder = require_data("xsens_opensense")  # only the pelvis and a thigh mapped: no knee to find the facing from
    result = cli(str(folder), "--names", "00B42279=hip,00B4227C=r_thigh", "-o", str(tmp_path / "walk.mot"))
    assert result.returncode == 2 and "no joint angles" in result.stderr and "no knee or elbow" in result.stderr
    assert not (tmp_path / "walk.mot").exists()


def test_a_recording_that_does_not_start_still_gets_no_angles_and_is_told_why(tmp_path):
    """Its loader leaves it uncalibrated (the sensors' raw orientations): no .mot, the reason said."""
    for name, phase in (("Left_Upper", 0.0), ("Left_Lower", 1.0)):
        rows = "".join(f"{1000 + 20000 * k},{np.cos(0.05 * k + phase)},{np.sin(0.05 * k + phase)},0,0\n"
                       for k in range(100))
        (tmp_path / f"{name}.csv").write_text("Timestamp (us),W,X,Y,Z\n" + rows)
    result = cli(str(tmp_path), "-o", str(tmp_path / "turning.mot"))
    assert result.returncode == 2 and "no joint angles" in result.stderr and "no rest calibration" in result.stderr, \
        result.stderr
    assert not (tmp_path / "turning.mot").exists()
