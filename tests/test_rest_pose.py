"""The rest pose travels with the data: sources know theirs, devices announce it, the aggregator
builds each subject's skeleton on it, pose frames carry it, exports write it (docs/protocol.md,
"Rest pose")."""
from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest
import zenoh
from support.bvh import read_bvh_positions
from support.stack import ROOT, stack, wait_until  # noqa: F401  (fixture)

from limbstream import wire, zconfig
from limbstream.skeleton import Skeleton
from limbstream.sources import load, load_npz
from limbstream.sources.generator import GeneratorSource

DOWN = np.array([0.0, -1.0, 0.0])
ARMS = (("l_shoulder", "l_elbow"), ("r_shoulder", "r_elbow"))


def arm_angles_deg(joints: np.ndarray) -> np.ndarray:
    """(F, 2) angle of each upper arm (shoulder -> elbow) from straight down, degrees;
    ``joints`` (F, 15, 3) in wire.JOINTS order."""
    out = []
    for a, b in ARMS:
        v = joints[:, wire.JOINTS.index(b)] - joints[:, wire.JOINTS.index(a)]
        v = v / np.linalg.norm(v, axis=-1, keepdims=True)
        out.append(np.degrees(np.arccos(np.clip(v @ DOWN, -1, 1))))
    return np.stack(out, axis=1)


def test_sources_know_their_rest_pose(cmu_npz, cmu_bvh_dir, xio_dir, tmp_path):
    assert load(cmu_bvh_dir / "02_01.bvh")[0].rest_pose == "tpose"
    assert {m.rest_pose for m in load_npz(cmu_npz)} == {"tpose"}  # no rest_pose entry: converted BVH
    assert load(xio_dir)[0].rest_pose == "standing"
    assert GeneratorSource(seed=1).motion(2.0).rest_pose == "standing"
    marked = tmp_path / "standing.npz"
    data = dict(np.load(cmu_npz))
    np.savez(marked, **data, rest_pose=np.array("standing"))
    assert {m.rest_pose for m in load_npz(marked)} == {"standing"}
    np.savez(marked, **data, rest_pose=np.array("sitting"))
    with pytest.raises(ValueError, match="rest pose must be one of standing, tpose"):
        load_npz(marked)


def test_identity_is_the_rest_pose_arms_down_or_out():
    q = np.tile([1.0, 0.0, 0.0, 0.0], (10, 1))
    standing, tpose = Skeleton().positions(q), Skeleton().positions(q, tpose=True)
    assert np.allclose(arm_angles_deg(standing[None]), 0.0, atol=1e-4)
    assert np.allclose(arm_angles_deg(tpose[None]), 90.0, atol=1e-4)  # horizontal
    assert np.allclose(Skeleton(rest_pose="tpose").positions(q), tpose)
    both = Skeleton().positions(np.stack([q, q]), tpose=np.array([False, True]))  # per frame
    assert np.allclose(both, np.stack([standing, tpose]))
    assert wire.frame_rest_pose(wire.rest_pose_flag("tpose") | wire.FRAME_GAP) == "tpose"
    assert wire.frame_rest_pose(wire.FRAME_MISSING) == "standing"


def exact_frames(session, subject: str, n: int, timeout: float = 60.0) -> list[wire.PoseFrame]:
    """The first ``n`` exact frames of ``subject`` after the call."""
    sub = session.declare_subscriber(wire.pose_key(subject), zenoh.handlers.FifoChannel(4096))
    frames: list[wire.PoseFrame] = []

    def enough() -> bool:
        while (s := sub.try_recv()) is not None:
            f = wire.decode_pose(s.payload.to_bytes())
            if f.kind == wire.KIND_EXACT:
                frames.append(f)
        return len(frames) >= n
    wait_until(enough, timeout, f"{n} exact frames of {subject}")
    sub.undeclare()
    return frames


def test_one_aggregator_draws_a_bvh_walk_and_the_generator_each_on_its_rest_pose(stack, cmu_bvh_dir):  # noqa: F811
    """A BVH walk (T-pose data) and a generator subject (standing data) in one aggregator started
    without any rest-pose flag: the walk's upper arms hang (they would point sideways or across the
    chest on the wrong rest pose), the generator's frames are as before."""
    stack.router()
    stack.aggregator()
    stack.emulator(1, 1.0, "--no-truth")  # s01: the generator
    stack.emulator(1, 1.0, "--no-truth", "--first-subject", "2", "--source", str(cmu_bvh_dir / "02_01.bvh"))
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    try:
        walk = exact_frames(session, "s02", 100)
        gen = exact_frames(session, "s01", 20)
    finally:
        session.close()
    assert all(f.flags & wire.FRAME_TPOSE for f in walk[-50:])
    angles = arm_angles_deg(np.stack([f.joints for f in walk[-50:]]))
    median = np.median(angles, axis=0)
    print(f"\nBVH walk under one aggregator: upper arms from straight down, median {median.round(1)} deg")
    assert (median < 45).all(), median
    assert not any(f.flags & wire.FRAME_TPOSE for f in gen)
    for f in gen:  # the generator is drawn as before: the standing skeleton of its orientations
        assert np.allclose(f.joints, Skeleton().positions(f.q.astype(np.float64)), atol=1e-5)


def test_exported_cmu_walk_has_hanging_arms_for_an_independent_bvh_reader(cmu_npz, tmp_path):
    out = tmp_path / "walk.bvh"
    result = subprocess.run([sys.executable, "-m", "limbstream.cli", "export", str(cmu_npz), "--subject", "02_01",
                             "-o", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert re.search(r"\btpose rest pose\b", result.stdout), result.stdout
    pos = read_bvh_positions(out)
    for shoulder, elbow in (("LeftArm", "LeftForeArm"), ("RightArm", "RightForeArm")):
        v = pos[elbow] - pos[shoulder]
        angle = np.degrees(np.arccos(np.clip((v / np.linalg.norm(v, axis=1, keepdims=True)) @ DOWN, -1, 1)))
        print(f"\n{shoulder} -> {elbow}: median {np.median(angle):.1f} deg from straight down")
        assert np.median(angle) < 45, np.median(angle)
