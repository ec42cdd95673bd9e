"""`limbstream export`: BVH / CSV / npz of a recording's exact frames or of a motion file, read
back with limbstream's own loaders (the BVH loader maps the exported joints to segments)."""
from __future__ import annotations

import csv

import numpy as np
import pytest
from support.export import T0_US, cli

from limbstream import quat, wire
from limbstream.skeleton import Skeleton
from limbstream.sources import load, load_npz
from limbstream.sources.bvh import load_bvh, parse_bvh
from limbstream.services.outputs.export import BVH_JOINTS, ROTATION_CHANNELS, csv_header, skeleton_of
from limbstream.services.outputs.recording import RecordingWriter

@pytest.fixture(scope="module")
def clip(cmu_npz):
    """The first CMU clip: (m, 10, 4) orientations in SEGMENTS order."""
    motion = load_npz(cmu_npz)[0]
    return np.stack([motion.segment(s) for s in wire.SEGMENTS], axis=1)


def write_recording(path, q: np.ndarray, skeleton: Skeleton, drop: set[int]) -> None:
    """Exact frames of s01 (minus the indexes in ``drop``), live frames and another subject's
    frames mixed in, as an aggregator and the recorder would leave them."""
    writer = RecordingWriter(path)
    joints = skeleton.positions(q)
    for k in range(len(q)):
        t = T0_US + 20_000 * k
        if k not in drop:
            frame = wire.PoseFrame(k, t, wire.KIND_EXACT, 0, q[k].astype(np.float32), joints[k])
            writer.add("pose", wire.pose_key("s01"), wire.encode_pose(frame), t * 1000 + 400_000_000)
        if k % 5 == 0:
            live = wire.PoseFrame(k, t, wire.KIND_LIVE, 0, np.tile(np.float32([0, 1, 0, 0]), (10, 1)), joints[0])
            writer.add("pose", wire.pose_key("s01"), wire.encode_pose(live), t * 1000)
            other = wire.PoseFrame(k, t, wire.KIND_EXACT, 0, q[0].astype(np.float32), joints[0])
            writer.add("pose", wire.pose_key("s02"), wire.encode_pose(other), t * 1000)
    writer.add("pose", wire.pose_key("s01"), b"broken", T0_US * 1000)
    writer.close()


def test_recording_exports_to_bvh_csv_npz_and_reads_back(tmp_path, clip):
    q = quat.continuous(clip[:600].astype(np.float32).astype(np.float64), axis=0)
    rec = tmp_path / "take.mcap"
    write_recording(rec, q, Skeleton(), drop={100, 101, 350})

    result = cli(str(rec), "--subject", "s01", "--format", "bvh", "-o", str(tmp_path / "s01.bvh"))
    assert result.returncode == 0, result.stderr
    assert "600 frames at 50 Hz" in result.stdout, result.stdout
    assert "3 of 600 frames were not recorded" in result.stderr and "1 undecodable" in result.stderr, result.stderr

    clip_bvh = parse_bvh(tmp_path / "s01.bvh")
    assert clip_bvh.joints == tuple(j.name for j in BVH_JOINTS) and clip_bvh.frame_time == pytest.approx(0.02)
    assert clip_bvh.channels[0] == ("Xposition", "Yposition", "Zposition", *ROTATION_CHANNELS)
    assert all(c == ROTATION_CHANNELS for c in clip_bvh.channels[1:])
    offsets = dict(zip(clip_bvh.joints, clip_bvh.offsets))
    assert offsets["LeftLeg"] == pytest.approx([0, -0.45, 0], abs=1e-5)  # metres, from the frames' joints
    back = load_bvh(tmp_path / "s01.bvh", fs=None, drop_first=False)
    expected = q.copy()
    expected[[100, 101]] = q[99]  # a missing frame repeats the one before
    expected[350] = q[349]
    assert back.segments == wire.SEGMENTS and len(back.t) == 600
    err = quat.angle_deg(back.q, expected)
    print(f"\nBVH round trip: max {err.max():.2e} deg")
    assert err.max() < 0.01

    assert cli(str(rec), "--subject", "s01", "-o", str(tmp_path / "s01.csv")).returncode == 0
    with open(tmp_path / "s01.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == csv_header() and len(rows) == 1 + 597  # recorded frames only
    table = np.array(rows[1:], float)
    keep = np.setdiff1d(np.arange(600), [100, 101, 350])
    assert np.array_equal(table[:, 1], T0_US + 20_000 * keep) and np.array_equal(table[:, 2], keep)
    assert table[101, 0] == pytest.approx(0.02 * 103)  # the gap shows as a step in t
    cols = {name: i for i, name in enumerate(rows[0])}
    got_q = table[:, [cols[f"{s}_{c}"] for s in wire.SEGMENTS for c in ("qw", "qx", "qy", "qz")]].reshape(-1, 10, 4)
    assert quat.angle_deg(got_q, q[keep]).max() < 0.01
    ankle = table[:, [cols["l_ankle_x"], cols["l_ankle_y"], cols["l_ankle_z"]]]
    assert np.allclose(ankle, Skeleton().positions(q[keep])[:, wire.JOINTS.index("l_ankle")], atol=1e-4)

    assert cli(str(rec), "--subject", "s01", "-o", str(tmp_path / "s01.npz")).returncode == 0
    (motion,) = load(tmp_path / "s01.npz")
    assert motion.name == "s01" and motion.fs == pytest.approx(50) and quat.angle_deg(motion.q, expected).max() < 1e-4
    data = np.load(tmp_path / "s01.npz")
    assert list(np.flatnonzero(data["filled"])) == [100, 101, 350]
    assert all(data["flags"][[100, 101, 350]] & wire.FRAME_GAP)


def test_motion_files_export_to_bvh_and_back(tmp_path, clip, cmu_npz, cmu_bvh_dir):
    out = tmp_path / "clip.bvh"
    result = cli(str(cmu_npz), "--subject", "s01", "-o", str(out))
    assert result.returncode == 0, result.stderr
    err = quat.angle_deg(load(out)[0].q, clip)
    assert err.max() < 0.01, err.max()

    source = sorted(cmu_bvh_dir.glob("*.bvh"))[0]
    original = load_bvh(source, fs=None)  # its own 120 Hz, which the export keeps
    result = cli(str(source), "-o", str(out))
    assert result.returncode == 0 and "at 120 Hz" in result.stdout and "tpose rest pose" in result.stdout, result
    err = quat.angle_deg(load_bvh(out, fs=None, drop_first=False).q, original.q)
    print(f"\n{source.name}: {len(original.t)} frames, max {err.max():.2e} deg")
    assert err.max() < 0.01


def test_rest_pose_and_body_come_from_the_frames():
    q = np.tile([1.0, 0, 0, 0], (10, 1))
    q[wire.SEGMENTS.index("l_upperarm")] = [np.cos(0.3), 0, 0, np.sin(0.3)]
    for body in (Skeleton(), Skeleton(thigh=0.5, upperarm=0.33, rest_pose="tpose")):
        flags = wire.rest_pose_flag(body.rest_pose)  # the rest pose travels in the frame's flags
        frame = wire.PoseFrame(0, 0, wire.KIND_EXACT, flags, q.astype(np.float32), body.positions(q))
        got = skeleton_of(frame)
        assert got.rest_pose == body.rest_pose and got.thigh == pytest.approx(body.thigh, abs=1e-5)
        assert got.upperarm == pytest.approx(body.upperarm, abs=1e-5)


def test_bad_export_input_is_a_one_line_error(tmp_path, cmu_npz):
    rec = tmp_path / "take.mcap"
    write_recording(rec, np.tile([1.0, 0, 0, 0], (5, 10, 1)), Skeleton(), drop=set())
    cases = [
        (cli(str(rec), "--subject", "s07", "-o", str(tmp_path / "a.bvh")), ("--subject s07", "s01")),
        (cli(str(rec), "-o", str(tmp_path / "a.bvh")), ("--subject", "s01, s02")),
        (cli(str(rec), "--subject", "s01", "-o", str(tmp_path / "missing" / "a.bvh")), ("-o", "a.bvh", "cannot write")),
        (cli(str(rec), "--subject", "s01", "-o", str(tmp_path / "a.txt")), ("--format",)),
        (cli(str(cmu_npz), "--subject", "nope", "-o", str(tmp_path / "a.csv")), ("--subject nope", "01_01")),
        (cli(str(tmp_path / "none.bvh"), "-o", str(tmp_path / "a.csv")), ("none.bvh", "no such file")),
    ]
    for result, words in cases:
        err = result.stderr.strip()
        assert result.returncode == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, (result, words)
        assert all(w in err for w in words), (err, words)


def test_an_xsens_recording_exports_once_its_sensors_are_mapped(tmp_path, xsens_dir):
    """Without a mapping the Xsens folder (sensors named by serial number) is an error naming its
    sensors and --names; with ``--names opensense`` its walk exports as a person: each knee (the
    angle from thigh to shank) peaks at 55-75 degrees in every stride's swing."""
    from scipy.signal import find_peaks
    out = tmp_path / "walk.npz"
    refused = cli(str(xsens_dir), "-o", str(out))
    err = refused.stderr.strip()
    assert refused.returncode == 2 and len(err.splitlines()) == 1 and not out.exists(), refused
    assert "no sensor maps to a body segment (sensors found: 00B421E6, 00B421ED" in err and "--names" in err, err
    done = cli(str(xsens_dir), "--names", "opensense", "-o", str(out))
    assert done.returncode == 0, done.stderr
    assert "at 100 Hz" in done.stdout, done.stdout  # the sensors' own rate
    assert "calibration: rest pose from the first 1 s standing still, functional facing" in done.stderr, done.stderr
    data = np.load(out)
    q = data["clip_xsens_opensense"].astype(np.float64)
    fs = float(data["fs"])
    for side in "lr":
        knee = quat.angle_deg(q[:, wire.SEGMENTS.index(f"{side}_thigh")], q[:, wire.SEGMENTS.index(f"{side}_shank")])
        peaks, _ = find_peaks(knee, height=30.0, distance=round(0.8 * fs))  # one swing per stride
        assert len(peaks) >= 8 and knee[: round(fs)].max() < 10.0, (side, knee[peaks])  # it starts standing
        assert 55.0 <= np.median(knee[peaks]) <= 75.0 and knee.max() <= 75.0, (side, knee[peaks].round(1))
    at50 = cli(str(xsens_dir), "--names", "opensense", "--rate", "50", "-o", str(tmp_path / "walk50.npz"))
    assert at50.returncode == 0 and "at 50 Hz" in at50.stdout, at50
    q50 = np.load(tmp_path / "walk50.npz")["clip_xsens_opensense"]
    assert fs == 100.0 and len(q50) == (len(q) + 1) // 2
    assert quat.angle_deg(q50.astype(np.float64), q[::2]).max() < 1e-3  # every other frame of the 100 Hz one


def test_a_raw_recording_exports_fused_as_devices_fuse_it(tmp_path):
    """The qmt full-body .mat (angular rate and specific force) is fused as ``fuse``, ``eval`` and
    ``up --imu raw`` devices fuse it, calibrated from its still start and exported at its 100 Hz:
    the subject stands still for its first seconds, then moves its knees."""
    from support import require_data

    from limbstream import joints
    path = require_data("qmt_full_body/full_body_example_data.mat")
    result = cli(str(path), "-o", str(tmp_path / "qmt.npz"))
    assert result.returncode == 0, result.stderr
    assert "10000 frames at 100 Hz" in result.stdout and "standing rest pose" in result.stdout, result.stdout
    assert "calibration: rest pose from the first 1 s standing still" in result.stderr, result.stderr
    (motion,) = load(tmp_path / "qmt.npz")
    angles, _ = joints.joint_angles(motion.q, None, "standing")
    knee = angles[:, [joints.ANGLES.index("knee_angle_l"), joints.ANGLES.index("knee_angle_r")]]
    assert np.abs(knee[: 300]).max() < 5.0 and np.ptp(knee[400:], axis=0).min() > 45.0, np.ptp(knee, axis=0)
