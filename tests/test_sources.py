"""Motion loaders against the shared data and against broken files."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from limbstream import quat
from limbstream.body import layout
from limbstream.sources import SEGMENTS, MotionFileError, bvh, imu_files, load, load_npz, names

CLIPS = ("01_01", "02_01", "05_06", "131_01", "131_02", "131_03")
BVH_TOL_DEG = 1e-3  # the npz is float32: rounding alone leaves ~1e-5 deg


# --------------------------------------------------------------------------- BVH


@pytest.fixture(scope="module")
def npz_clips(cmu_npz):
    return {m.name: m for m in load_npz(cmu_npz)}


@pytest.mark.parametrize("clip", CLIPS)
def test_bvh_reproduces_npz(clip, cmu_bvh_dir, npz_clips):
    motion = bvh.load_bvh(cmu_bvh_dir / f"{clip}.bvh")
    ref = npz_clips[clip]
    assert motion.segments == SEGMENTS == ref.segments
    assert motion.q.shape == ref.q.shape, f"{clip}: {motion.q.shape} vs {ref.q.shape}"
    np.testing.assert_allclose(motion.t, ref.t, atol=1e-9)
    dev = quat.angle_deg(motion.q, ref.q)
    worst = dev.max(axis=0)
    assert worst.max() < BVH_TOL_DEG, (
        f"{clip}: max deviation per segment {dict(zip(SEGMENTS, worst))}"
    )


def test_bvh_tpose_heuristic(cmu_bvh_dir, npz_clips):
    flags = {c: bvh.is_synthetic_tpose(bvh.parse_bvh(cmu_bvh_dir / f"{c}.bvh")) for c in CLIPS}
    assert flags == {c: c == "01_01" for c in CLIPS}, flags
    kept = bvh.load_bvh(cmu_bvh_dir / "01_01.bvh", drop_first=False)
    assert len(kept.t) == len(npz_clips["01_01"].t) + 1
    dev = quat.angle_deg(kept.q[:50], npz_clips["01_01"].q[:50]).max()
    assert dev > 10.0, (
        f"keeping the T-pose frame should shift the clip, max deviation {dev:.3g} deg"
    )


def test_bvh_segment_maps_pick_scheme(cmu_bvh_dir):
    assert (
        bvh.pick_segment_map(bvh.parse_bvh(cmu_bvh_dir / "02_01.bvh").joints)["l_upperarm"]
        == "LeftArm"
    )
    asf = bvh.pick_segment_map(bvh.parse_bvh(cmu_bvh_dir / "131_01.bvh").joints)
    assert asf["l_upperarm"] == "LeftShoulder" and asf["neck"] == "lowerneck"


def test_bvh_native_rate_and_custom_map(cmu_bvh_dir):
    path = cmu_bvh_dir / "02_01.bvh"
    clip = bvh.parse_bvh(path)
    native = bvh.load_bvh(path, fs=None, segment_map={"head": "Head", "hip": "Hips"})
    assert native.segments == ("head", "hip") and native.q.shape == (clip.n_frames, 2, 4)
    assert abs(native.fs - 1.0 / clip.frame_time) < 1e-6
    # frames of the native stream at the 50 Hz instants equal the resampled ones where they coincide
    at50 = bvh.load_bvh(path, segment_map={"head": "Head", "hip": "Hips"})
    # 120 and 50 Hz share every 0.1 s (frame 12 k, sample 5 k) up to the file's rounded frame time
    dev = quat.angle_deg(at50.q[::5][:20], native.q[::12][:20]).max()
    assert dev < 0.05, f"max deviation at shared instants {dev:.3g} deg"


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


TWO_JOINT_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation
  JOINT Arm
  {
    OFFSET 1 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 1 0 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.5
0 0 0 10 20 30 40 50 60
0 0 0 -30 80 5 0 0 0
1 2 3 0 0 0 90 -45 120
"""


def test_bvh_channel_order_and_forward_kinematics(tmp_path):
    path = _write(tmp_path / "two.bvh", TWO_JOINT_BVH)
    motion = bvh.load_bvh(path, fs=None, segment_map={"hip": "Hips", "arm": "Arm"})
    values = np.loadtxt(TWO_JOINT_BVH.splitlines()[-3:])

    def intrinsic(axes: str, angles: np.ndarray) -> Rotation:
        # R = R_first R_second R_third, each elementary rotation built on its own
        out = Rotation.identity()
        for axis, angle in zip(axes, angles):
            out = out * Rotation.from_rotvec(np.radians(angle) * np.eye(3)["XYZ".index(axis)])
        return out

    for f, row in enumerate(values):
        hips = intrinsic("XYZ", row[3:6])
        arm = hips * intrinsic("ZXY", row[6:9])
        for k, ref in enumerate((hips, arm)):
            dev = quat.angle_deg(motion.q[f, k], quat.from_rotation(ref))
            assert dev < 1e-9, f"frame {f} joint {k}: {dev} deg"
    np.testing.assert_allclose(motion.t, [0.0, 0.5, 1.0])
    # resampling at 4 Hz: the midpoint between frames is their SLERP
    fast = bvh.load_bvh(path, fs=4.0, segment_map={"hip": "Hips"})
    assert len(fast.t) == 5
    mid = quat.slerp(motion.q[0, 0], motion.q[1, 0], 0.5)
    assert quat.angle_deg(fast.q[1, 0], mid) < 1e-9


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda s: s.replace("HIERARCHY", "HIERARCHX"), r"line 1: not a BVH file"),
        (lambda s: s.replace("MOTION", "MOTIONS"), r"no MOTION section"),
        (
            lambda s: s.replace("0 0 0 -30 80 5 0 0 0", "0 0 0 -30 eighty 5 0 0 0"),
            r"line 20: 'eighty' is not a number",
        ),
        (
            lambda s: s.replace("1 2 3 0 0 0 90 -45 120", "1 2 3 0 0 0 90 -45"),
            r"line 21: frame has 8 values, expected 9",
        ),
        (
            lambda s: s.replace("Frames: 3", "Frames: 4"),
            r"MOTION holds 3 frames, header says Frames: 4",
        ),
        (
            lambda s: s.replace("Zrotation Xrotation Yrotation", "Zrotation Xrotation Wrotation"),
            r"line 9: unknown channel 'Wrotation'",
        ),
        (
            lambda s: s.replace("OFFSET 1 0 0\n    CH", "OFFSET 1 zero 0\n    CH"),
            r"line 8: OFFSET: 'zero' is not a number",
        ),
        (lambda s: s.replace("Frame Time: 0.5", "Frame Time: -1"), r"Frame Time > 0"),
        (lambda s: s.replace("  }\n}\nMOTION", "  }\nMOTION"), r"unclosed braces"),
    ],
)
def test_bvh_broken_files(tmp_path, edit, message):
    path = _write(tmp_path / "broken.bvh", edit(TWO_JOINT_BVH))
    with pytest.raises(MotionFileError, match=re.escape(str(path)) + ".*" + message):
        bvh.load_bvh(path, fs=None, segment_map={"hip": "Hips"})


def test_bvh_unknown_skeleton_needs_a_map(tmp_path):
    path = _write(tmp_path / "two.bvh", TWO_JOINT_BVH)
    with pytest.raises(MotionFileError, match=r"match no naming scheme .*joints: Hips, Arm; map them with --names"):
        bvh.load_bvh(path)
    with pytest.raises(MotionFileError, match="no joint named 'Knee'"):
        bvh.load_bvh(path, segment_map={"l_shank": "Knee"})


# --------------------------------------------------------------------------- x-IMU3


def test_xio_raw_streams(xio_dir):
    streams = imu_files.xio_streams(xio_dir)
    names = {s.name for s in streams}
    assert names == {"l_thigh", "r_thigh", "l_shank", "r_shank", "l_foot", "r_foot", "hip"}, names
    for s in streams:
        dt = np.diff(s.t)
        assert np.all(dt > 0), s.path
        assert 0.0195 < np.median(dt) < 0.0205, f"{s.path}: median step {np.median(dt)}"
        assert dt.max() > 1.5 * np.median(dt), f"{s.path}: the recording has gaps, none found"
        assert np.abs(np.linalg.norm(s.q, axis=1) - 1).max() < 1e-12
        assert np.all(np.sum(s.q[1:] * s.q[:-1], axis=1) > 0), f"{s.path}: sign flips"
        assert s.dropped == 0


def test_xio_folder_is_slerp_on_common_grid(xio_dir):
    streams = imu_files.xio_streams(xio_dir)
    motion = imu_files.align(streams)
    start = max(s.t[0] for s in streams)
    assert motion.t[0] == 0.0 and motion.t[-1] <= min(s.t[-1] for s in streams) - start + 1e-9
    medians = [1.0 / np.median(np.diff(s.t)) for s in streams]
    assert abs(motion.fs - np.median(medians)) < 1e-6, (motion.fs, medians)
    for k, s in enumerate(streams):
        ref = Slerp(s.t, quat.to_rotation(s.q))(motion.t + start)
        dev = quat.angle_deg(motion.q[:, k], quat.from_rotation(ref)).max()
        assert dev < 1e-4, f"{s.name}: max deviation from scipy Slerp {dev:.3g} deg"


XIO_OK = "Timestamp (us),W,X,Y,Z\n1000,1,0,0,0\n21000,0.9,0.1,0,0\n41000,0.8,0.2,0,0\n"


@pytest.mark.parametrize(
    "text, message",
    [
        ("Time,W,X,Y,Z\n1000,1,0,0,0\n", r"line 1: header"),
        (XIO_OK.replace("0.9,0.1", "0.9,abc"), r"line 3: 'abc' is not a number"),
        (XIO_OK.replace("0.9,0.1,0,0", "0.9,0.1,0"), r"line 3: 4 fields, expected 5"),
        (XIO_OK.replace("0.8,0.2,0,0", "0,0,0,0"), r"line 4: zero-norm quaternion"),
        (XIO_OK.replace("0.8,0.2", "nan,0.2"), r"line 4: non-finite"),
        ("", r"empty file"),
        ("Timestamp (us),W,X,Y,Z\n1000,1,0,0,0\n", r"1 samples, need at least 2"),
    ],
)
def test_xio_broken_files(tmp_path, text, message):
    path = _write(tmp_path / "Left_Upper.csv", text)
    with pytest.raises(MotionFileError, match=re.escape(str(path)) + ".*" + message):
        imu_files.read_xio_csv(path)


def test_xio_non_increasing_timestamps_are_dropped_and_counted(tmp_path):
    text = XIO_OK + "41000,0.7,0.3,0,0\n30000,0.7,0.3,0,0\n61000,0.7,0.3,0,0\n"
    path = _write(tmp_path / "pelvis.csv", text)
    with pytest.warns(UserWarning, match=re.escape(str(path)) + r": dropped 2 rows"):
        stream = imu_files.read_xio_csv(path)
    assert stream.dropped == 2 and stream.name == "hip"
    np.testing.assert_allclose(stream.t, [0.001, 0.021, 0.041, 0.061])


# --------------------------------------------------------------------------- Xsens


def _xsens_acc(path: Path) -> np.ndarray:
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("//")]
    header = lines[0].split("\t")
    cols = [header.index(c) for c in ("Acc_X", "Acc_Y", "Acc_Z")]
    return np.array([[float(ln.split("\t")[c]) for c in cols] for ln in lines[1:]])


def test_xsens_files_rate_counter_and_gravity(xsens_dir):
    files = sorted(xsens_dir.glob("*.txt"))
    assert len(files) == 8
    for path in files:
        s = imu_files.read_xsens_txt(path)
        np.testing.assert_allclose(np.diff(s.t), 0.01, atol=1e-9, err_msg=str(path))
        assert np.abs(np.linalg.norm(s.q, axis=1) - 1).max() < 1e-12
        assert np.all(np.sum(s.q[1:] * s.q[:-1], axis=1) > 0), f"{path}: sign flips"
        # sensor -> global: the specific force of a sensor at rest maps onto global up (+Z)
        up = np.median(quat.rotate(s.q, _xsens_acc(path)), axis=0)
        assert np.allclose(up, [0, 0, 9.81], atol=0.15), f"{path}: median rotated acceleration {up}"


def test_xsens_folder(xsens_dir):
    (motion,) = load(xsens_dir, {"00B421E6": "hip", "00B421ED": "l_shank"})
    assert motion.segments == ("hip", "l_shank"), motion.segments  # a mapping leaves the others out
    assert abs(motion.fs - 100.0) < 1e-6
    first = imu_files.read_xsens_txt(xsens_dir / "00B421E6.txt")
    n = min(len(first.t), len(motion.t))
    # shared counter: the same samples, made segment orientations (turned Y up, calibrated at the start)
    body = quat.multiply(quat.Z_UP_TO_Y_UP, first.q[:n])
    relative = quat.multiply(quat.conjugate(body[:n]), motion.q[:n, 0])  # the constant right factor S0^-1
    assert quat.angle_deg(relative, np.broadcast_to(relative[0], relative.shape)).max() < 1e-4
    assert quat.angle_deg(motion.q[:50, 0], np.broadcast_to([1.0, 0, 0, 0], (50, 4))).max() < 2.0


def test_an_imu_recording_without_body_segments_is_an_error_naming_its_sensors_and_the_flag(xsens_dir):
    with pytest.raises(MotionFileError) as err:
        load(xsens_dir)
    assert "no sensor maps to a body segment (sensors found: 00B421E6, 00B421ED," in str(err.value)
    assert "--names NAME|FILE|SENSOR=SEGMENT" in str(err.value) and "opensense" in str(err.value)


@pytest.mark.parametrize("text, expected", [
    ("opensense", names.NAMED["opensense"]),
    ("A1=hip, B2 = l_thigh", {"A1": "hip", "B2": "l_thigh"}),
])
def test_names_parse_named_mappings_and_lists(text, expected):
    assert names.parse(text) == expected


def test_names_parse_a_file(tmp_path):
    path = _write(tmp_path / "map.txt", "# my suit\nA1=hip\nB2=r_foot, C3=neck  # the head band\n")
    assert names.parse(str(path)) == {"A1": "hip", "B2": "r_foot", "C3": "neck"}


@pytest.mark.parametrize("text, message", [
    ("nosuchmapping", "neither a named mapping (opensense), a file, nor a SENSOR=SEGMENT list"),
    ("A1=hip,B2", "'B2' is not SENSOR=SEGMENT"),
    ("A1=hip,A1=neck", "sensor 'A1' is mapped twice"),
])
def test_names_parse_refuses_bad_mappings(text, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        names.parse(text)


def test_names_segments_are_checked_against_the_layout_in_effect():
    """Parsing checks the syntax; the segments are the layout's (a layout file's own too), or a
    built-in layout's where none is given, each refused in one line with the layout's segments."""
    back16 = layout("examples/layouts/back16.json")
    mapping = names.parse("A1=lower_back,B2=hip")
    names.check_segments(mapping, back16)
    with pytest.raises(ValueError, match=r"^--names: 'lower_back' is not a segment of a built-in layout .*: "
                                         r"l_shank, r_shank, .*r_foot$"):
        names.check_segments(mapping, None)
    with pytest.raises(ValueError, match=r"^--names: 'neck' is not a segment of layout back16; its segments: "
                                         r"hip, lower_back, upper_back, head, .*r_foot$"):
        names.check_segments({"A1": "neck"}, back16)
    names.check_segments({"A1": "neck", "B2": "r_foot"}, None)


def test_names_match_file_names_ending_in_the_sensor():
    stems = ["MT_012005D6_009-001_00B4227C", "Left_Upper", "00B42268"]
    assert names.name_sensors(stems, {"00b4227c": "r_thigh"}) == ["r_thigh", None, None]
    assert names.name_sensors(stems, None) == ["MT_012005D6_009-001_00B4227C", "l_thigh", "00B42268"]


def test_names_only_for_imu_recordings(cmu_npz):
    with pytest.raises(MotionFileError, match="--names maps the sensors of IMU recordings"):
        load(cmu_npz, {"A": "hip"})


def test_an_imu_recording_becomes_segment_orientations_from_its_still_start(xio_dir):
    """Loaded, the x-IMU3 recording (which starts standing still) is on the skeleton's Y-up world
    and calibrated: every segment at rest at the start, and the legs hang below the hips."""
    (motion,) = load(xio_dir)
    assert motion.rest_pose == "standing" and motion.orientations == "rest"
    start = motion.q[: round(motion.fs)]
    assert quat.angle_deg(start, np.broadcast_to([1.0, 0, 0, 0], start.shape)).max() < 2.0
    down = quat.rotate(motion.q[:, motion.segments.index("l_thigh")], [0.0, -1.0, 0.0])
    assert np.mean(down[:, 1] < 0) > 0.95, "the thigh's bone points down in most samples"


def test_a_recording_that_does_not_start_still_is_left_uncalibrated_with_a_warning(tmp_path):
    rows = "\n".join(f"{1000 + 20000 * k},{np.cos(0.05 * k)},{np.sin(0.05 * k)},0,0" for k in range(100))
    _write(tmp_path / "Left_Upper.csv", "Timestamp (us),W,X,Y,Z\n" + rows + "\n")
    with pytest.warns(UserWarning, match="not calibrated, the sensors do not start in a still rest pose"):
        (motion,) = load(tmp_path)
    assert motion.orientations == "sensors"
    raw = quat.multiply(quat.Z_UP_TO_Y_UP, imu_files.read_xio_csv(tmp_path / "Left_Upper.csv").q)
    assert quat.angle_deg(motion.q[:, 0], raw[: len(motion.t)]).max() < 1e-4


XSENS_HEAD = (
    "// Update Rate: 50.0Hz\nPacketCounter\tAcc_X\t"
    + "\t".join(f"Mat[{r}][{c}]" for c in (1, 2, 3) for r in (1, 2, 3))
    + "\n"
)


def _xsens_row(counter: int, matrix: np.ndarray) -> str:
    return (
        f"{counter:05d}\t0.0\t"
        + "\t".join(f"{matrix[r, c]:.6f}" for c in range(3) for r in range(3))
        + "\n"
    )


def test_xsens_counter_wrap_duplicates_and_matrix_layout(tmp_path):
    rot = Rotation.from_euler("xyz", [10, 20, 30], degrees=True)
    mat = rot.as_matrix()
    rows = [_xsens_row(c, mat) for c in (65533, 65534, 65535, 65535, 0, 2)]
    path = _write(tmp_path / "wrap.txt", XSENS_HEAD + "".join(rows))
    with pytest.warns(UserWarning, match="dropped 1 rows"):
        s = imu_files.read_xsens_txt(path)
    np.testing.assert_allclose(s.t, np.array([65533, 65534, 65535, 65536, 65538]) / 50.0)
    assert quat.angle_deg(s.q, quat.from_rotation(rot)).max() < 1e-4  # Mat[r][c] is row r, column c


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda s: s.replace("Mat[2][3]", "Mat[2][4]"),
            r"line 2: missing column\(s\) Mat\[2\]\[3\]",
        ),
        (
            lambda s: s.replace("00003\t0.0\t1.000000", "00003\t0.0\t2.000000"),
            r"line 5: not a rotation matrix",
        ),
        (
            lambda s: s.replace("00002\t0.0\t1.000000", "00002\t0.0\tone"),
            r"line 4: 'one' is not a number",
        ),
        (lambda s: "// nothing\n", r"no column header"),
    ],
)
def test_xsens_broken_files(tmp_path, edit, message):
    rows = "".join(_xsens_row(c, np.eye(3)) for c in range(1, 5))
    path = _write(tmp_path / "broken.txt", edit(XSENS_HEAD + rows))
    with pytest.raises(MotionFileError, match=re.escape(str(path)) + ".*" + message):
        imu_files.read_xsens_txt(path)


def test_xsens_reflection_is_rejected(tmp_path):
    rows = "".join(_xsens_row(c, np.diag([1.0, 1.0, -1.0])) for c in range(1, 4))
    path = _write(tmp_path / "mirror.txt", XSENS_HEAD + rows)
    with pytest.raises(MotionFileError, match=r"line 3: not a rotation matrix .*det -1"):
        imu_files.read_xsens_txt(path)


# --------------------------------------------------------------------------- load()


def test_load_dispatch(tmp_path, cmu_bvh_dir, xio_dir, xsens_dir, cmu_npz):
    assert [m.name for m in load(cmu_bvh_dir)] == list(CLIPS)
    assert load(cmu_bvh_dir / "02_01.bvh")[0].q.shape == (143, 10, 4)
    (single,) = load(xio_dir / "Left_Foot.csv")
    raw = imu_files.read_xio_csv(xio_dir / "Left_Foot.csv")
    assert single.segments == ("l_foot",) and np.array_equal(single.t, raw.t - raw.t[0])  # its own samples
    (one,) = load(xsens_dir / "00B421E6.txt", {"00B421E6": "l_foot"})
    assert one.q.shape[1] == 1 and abs(one.fs - 100.0) < 1e-6
    assert len(load(cmu_npz)) == len(CLIPS)
    assert {m.orientations for m in load(cmu_npz) + load(cmu_bvh_dir)} == {"segments"}
    with pytest.raises(MotionFileError, match="no such file"):
        load(tmp_path / "missing.bvh")
    with pytest.raises(MotionFileError, match="unknown motion file type"):
        load(_write(tmp_path / "motion.c3d", "x"))
    with pytest.raises(MotionFileError, match="folder holds no"):
        load(tmp_path)
