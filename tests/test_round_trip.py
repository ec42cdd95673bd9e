"""Every format ``limbstream export`` writes, read back: a recording's exact frames and the CMU clips
(a T-pose one and one whose hierarchy stands with the arms hanging) keep their orientations
(<= 0.1 deg) and joint angles (<= 0.5 deg) through BVH and npz (read back by limbstream's own
loaders, then exported again), CSV (its columns), OpenSense's .sto and OpenSim's .mot (read by
OpenSim's readers)."""
from __future__ import annotations

import csv

import numpy as np
import pytest
from support.export import T0_US, cli, quaternion_table, storage_columns

from limbstream import joints, quat, wire
from limbstream.services.outputs.export import export, read_take, take_angles
from limbstream.services.outputs.recording import RecordingWriter
from limbstream.skeleton import Skeleton
from limbstream.sources.generator import GeneratorSource

Q_TOL_DEG = 0.1
ANGLE_TOL_DEG = 0.5
SOURCES = ("recording", "02_01", "131_01")
"""A recording of the generator's standing subject, a CMU T-pose walk, a CMU clip standing at rest."""


def write_recording(path, seconds: float = 4.0) -> None:
    """Exact pose frames of s01 at 50 Hz, as an aggregator of the generator's devices records them."""
    motion = GeneratorSource(seed=3).motion(seconds)
    skeleton = Skeleton()
    q = motion.q.astype(np.float32)
    positions = skeleton.positions(q)
    writer = RecordingWriter(path)
    for k in range(len(q)):
        t = T0_US + 20_000 * k
        frame = wire.PoseFrame(k, t, wire.KIND_EXACT, 0, q[k], positions[k])
        writer.add("pose", wire.pose_key("s01"), wire.encode_pose(frame), t * 1000)
    writer.close()


@pytest.fixture(params=SOURCES)
def source(request, tmp_path, cmu_bvh_dir):
    if request.param == "recording":
        path = tmp_path / "session.mcap"
        write_recording(path)
        return path
    return cmu_bvh_dir / f"{request.param}.bvh"


def angles_of(take) -> np.ndarray:
    return take_angles(take)[0]


def assert_same(what: str, q: np.ndarray | None, angles: np.ndarray | None, ref) -> None:
    """Orientations (F, 10, 4) and joint angles (F, A) against the reference take's."""
    if q is not None:
        err = quat.angle_deg(q, ref.q)
        print(f"{what}: orientations max {err.max():.2e} deg")
        assert err.max() <= Q_TOL_DEG, what
    if angles is not None:
        ref_angles = angles_of(ref)
        err = np.abs(angles - ref_angles)
        print(f"{what}: joint angles max {np.nanmax(err):.2e} deg")
        assert np.array_equal(np.isnan(angles), np.isnan(ref_angles)) and np.nanmax(err) <= ANGLE_TOL_DEG, what


@pytest.mark.parametrize("fmt", ("bvh", "npz"))
def test_limbstream_reads_back_what_it_writes(fmt, source, tmp_path):
    ref = read_take(source, None)
    out = tmp_path / f"out.{fmt}"
    export(ref, fmt, out)
    back = read_take(out, None)
    assert len(back) == len(ref) and back.period_us == ref.period_us
    assert back.skeleton.rest_pose == ref.skeleton.rest_pose
    assert_same(f"{source.name} -> {fmt}", back.q, angles_of(back), ref)
    for again in ("mot", "sto"):  # exported again: the same files as from the source
        export(back, again, tmp_path / f"again.{again}")
        export(ref, again, tmp_path / f"ref.{again}")
    _, mine = storage_columns(tmp_path / "again.mot")
    _, theirs = storage_columns(tmp_path / "ref.mot")
    assert mine.keys() == theirs.keys()
    assert max(np.max(np.abs(mine[c] - theirs[c])) for c in mine) <= ANGLE_TOL_DEG
    assert quat.angle_deg(quaternion_table(tmp_path / "again.sto")[1],
                          quaternion_table(tmp_path / "ref.sto")[1]).max() <= Q_TOL_DEG


def test_csv_holds_the_orientations(source, tmp_path):
    ref = read_take(source, None)
    export(ref, "csv", tmp_path / "out.csv")
    with open(tmp_path / "out.csv") as f:
        rows = list(csv.reader(f))
    table = np.array(rows[1:], float)
    cols = {name: i for i, name in enumerate(rows[0])}
    q = table[:, [cols[f"{s}_{c}"] for s in wire.SEGMENTS for c in ("qw", "qx", "qy", "qz")]].reshape(-1, 10, 4)
    assert_same(f"{source.name} -> csv", q, joints.joint_angles(q, None, ref.skeleton.rest_pose)[0], ref)


def test_opensim_files_hold_the_angles_and_frames(source, tmp_path):
    ref = read_take(source, None)
    export(ref, "mot", tmp_path / "out.mot")
    export(ref, "sto", tmp_path / "out.sto")
    _, columns = storage_columns(tmp_path / "out.mot")
    angles = np.stack([columns[name] for name in joints.ANGLES], axis=1)
    assert_same(f"{source.name} -> mot", None, angles, ref)
    frames = quaternion_table(tmp_path / "out.sto")[1]
    err = quat.angle_deg(frames, joints.anatomical(ref.q, ref.skeleton.rest_pose))
    print(f"{source.name} -> sto: anatomical frames max {err.max():.2e} deg")
    assert err.max() <= Q_TOL_DEG


def test_a_recording_exported_as_bvh_gives_the_recordings_joint_angles(tmp_path):
    """The command line: the angles of ``export s01.bvh -o rt.mot`` are those of the recording's own
    .mot (a standing subject's BVH read as a T-pose turned the arms over the head)."""
    rec = tmp_path / "session.mcap"
    write_recording(rec)
    for args in ((str(rec), "--subject", "s01", "-o", str(tmp_path / "s01.bvh")),
                 (str(rec), "--subject", "s01", "-o", str(tmp_path / "s01.mot")),
                 (str(tmp_path / "s01.bvh"), "-o", str(tmp_path / "rt.mot"))):
        result = cli(*args)
        assert result.returncode == 0, result.stderr
        assert "standing rest pose" in result.stdout, result.stdout
    _, direct = storage_columns(tmp_path / "s01.mot")
    _, through_bvh = storage_columns(tmp_path / "rt.mot")
    worst = {c: float(np.max(np.abs(direct[c] - through_bvh[c]))) for c in direct}
    print(f"recording -> bvh -> mot vs recording -> mot: {max(worst.values()):.2e} deg")
    assert max(worst.values()) <= ANGLE_TOL_DEG, worst


def test_rate_resamples_a_recording(tmp_path):
    """``--rate``: every other frame at half the rate; SLERP halfway between frames at twice it."""
    rec = tmp_path / "session.mcap"
    write_recording(rec)
    ref = read_take(rec, None)
    half, double = read_take(rec, None, rate=25.0), read_take(rec, None, rate=100.0)
    assert (len(ref), len(half), len(double)) == (200, 100, 399)
    assert half.period_us == 40_000 and quat.angle_deg(half.q, ref.q[::2]).max() < 1e-4
    assert quat.angle_deg(double.q[::2], ref.q).max() < 1e-4
    assert quat.angle_deg(double.q[1], quat.slerp(ref.q[0], ref.q[1], 0.5)).max() < 1e-4
    assert np.allclose(double.joints, double.skeleton.positions(double.q), atol=1e-6)


def test_a_full_body_round_trips_through_bvh(tmp_path):
    """A recording of full-layout frames exported to BVH (the layout's hierarchy) and read back
    onto full (``export --layout full``) keeps its 15 orientations (<= 0.1 deg) and its 30 joint
    angles (<= 0.5 deg): the hands, feet, chest and head included."""
    from limbstream.body import FULL, Body

    motion = GeneratorSource(seed=3, layout="full").motion(4.0)
    q = motion.q.astype(np.float32)
    positions = Body.default(FULL).positions(q).astype(np.float32)
    path = tmp_path / "session.mcap"
    writer = RecordingWriter(path)
    for k in range(len(q)):
        t = T0_US + 20_000 * k
        frame = wire.PoseFrame(k, t, wire.KIND_EXACT, 0, q[k], positions[k], FULL)
        writer.add("pose", wire.pose_key("s01"), wire.encode_pose(frame), t * 1000)
    writer.close()
    ref = read_take(path, None)
    assert ref.layout == FULL
    export(ref, "bvh", tmp_path / "out.bvh")
    back = read_take(tmp_path / "out.bvh", None, layout="full")
    assert back.layout == FULL and len(back) == len(ref)
    assert_same("full -> bvh", back.q, angles_of(back), ref)
    assert angles_of(back).shape[1] == len(wire.joint_angles("full"))
