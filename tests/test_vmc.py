"""VMC output: a real ``limbstream vmc`` process between a real Zenoh router and a real OSC server
(python-osc) in the test; the receiver rebuilds every segment's global orientation from the
local bone rotations with Unity's humanoid hierarchy, written here independently of
services/outputs/vmc.py, and compares it with the pose frames published."""
from __future__ import annotations

import socket

import numpy as np
import pytest
from pythonosc.osc_bundle import OscBundle
from scipy.spatial.transform import Rotation

from limbstream import quat, wire, zconfig
from limbstream.cli import main
from limbstream.sources import generator
from limbstream.services.outputs import vmc
from limbstream.services.outputs.kinds import LiveFirst
from support.osc import OscReceiver
from support.stack import wait_until

PARENT = {  # Unity's humanoid hierarchy (the bones sent)
    "Hips": None, "Spine": "Hips", "Chest": "Spine", "Neck": "Chest", "Head": "Neck",
    **{f"{s}{b}": f"{s}{p}" for s in ("Left", "Right") for b, p in (
        ("UpperLeg", None), ("LowerLeg", "UpperLeg"), ("Foot", "LowerLeg"), ("Shoulder", None),
        ("UpperArm", "Shoulder"), ("LowerArm", "UpperArm"), ("Hand", "LowerArm"))},
}
for _s in ("Left", "Right"):
    PARENT[f"{_s}UpperLeg"], PARENT[f"{_s}Shoulder"] = "Hips", "Chest"
BONE_OF = {"hip": "Hips", "neck": "Neck", "l_thigh": "LeftUpperLeg", "l_shank": "LeftLowerLeg",
           "r_thigh": "RightUpperLeg", "r_shank": "RightLowerLeg", "l_upperarm": "LeftUpperArm",
           "l_lowerarm": "LeftLowerArm", "r_upperarm": "RightUpperArm", "r_lowerarm": "RightLowerArm"}
MIRROR = np.diag([-1.0, 1.0, 1.0])  # Unity (x right) <-> limbstream (x left)
TOL_DEG = 0.01


def segment_orientations(local_xyzw: dict[str, list[float]], rest_pose: str) -> np.ndarray:
    """(10, 4) limbstream global segment orientations from Unity local rotations (x, y, z, w)."""
    memo: dict[str, np.ndarray] = {}

    def global_matrix(bone: str) -> np.ndarray:
        if bone not in memo:
            local = Rotation.from_quat(local_xyzw[bone]).as_matrix()
            parent = PARENT[bone]
            memo[bone] = local if parent is None else global_matrix(parent) @ local
        return memo[bone]

    out = []
    for seg in wire.SEGMENTS:
        m = MIRROR @ global_matrix(BONE_OF[seg]) @ MIRROR  # back to limbstream's frame
        if rest_pose == "standing" and "arm" in seg:  # undo T-pose -> arms hanging (+-90 deg about Z)
            m = m @ Rotation.from_rotvec([0, 0, -np.pi / 2 if seg[0] == "l" else np.pi / 2]).inv().as_matrix()
        out.append(quat.from_rotation(Rotation.from_matrix(m)))
    return np.array(out)


def motion_q(n: int) -> np.ndarray:
    """(n, 10, 4) float32 orientations of generated motion: walking, then arm circles."""
    motion = generator.generate(4.0, seed=3, activities=[("walking", 2.0), ("arm_circles", 2.0)])
    return motion.q[np.linspace(0, len(motion.q) - 1, n).astype(int)].astype(np.float32)


@pytest.mark.parametrize("rest_pose", ["standing", "tpose"])
def test_local_rotations_give_back_the_segments(rest_pose):
    q = motion_q(200)
    names = [b.name for b in vmc.VMC_BONES]
    assert set(names) == set(PARENT)
    worst = 0.0
    for frame_q in q:
        local = vmc.local_rotations(frame_q, rest_pose)
        got = segment_orientations(dict(zip(names, local[:, [1, 2, 3, 0]])), rest_pose)
        worst = max(worst, quat.angle_deg(got, frame_q).max())
    assert worst < 1e-4, f"{worst:.3g} deg"  # angle_deg (arccos) resolves ~1e-6 deg


def test_held_bones_are_at_rest_and_positions_mirror():
    local = vmc.local_rotations(motion_q(1)[0], "standing")
    for bone, row in zip(vmc.VMC_BONES, local):
        if not bone.segment:
            assert quat.angle_deg(row, [1, 0, 0, 0]) < 1e-6, bone.name
    pos = dict(zip((b.name for b in vmc.VMC_BONES), vmc.rest_positions()))
    assert pos["LeftUpperLeg"][0] < 0 < pos["RightUpperLeg"][0]  # Unity x points to the right
    assert pos["LeftLowerArm"][0] < 0 < pos["RightLowerArm"][0]


def test_conjugate_is_the_inverse():
    q = quat.normalize(np.random.default_rng(1).normal(size=(50, 4)))
    want = quat.from_rotation(quat.to_rotation(q).inv())
    want *= np.sign(np.sum(want * quat.conjugate(q), axis=-1, keepdims=True))  # q ~ -q
    assert np.abs(quat.conjugate(q) - want).max() < 1e-12
    assert np.abs(quat.multiply(q, quat.conjugate(q)) - [1, 0, 0, 0]).max() < 1e-12


def test_live_frames_first():
    """The contract's one frame-kind rule (wire.auto_kind, window wire.AUTO_LIVE_WINDOW_S = 1 s)."""
    assert wire.AUTO_LIVE_WINDOW_S == 1.0
    rule = LiveFirst()
    q = np.tile([1, 0, 0, 0], (10, 1)).astype(np.float32)
    exact = wire.PoseFrame(0, 0, wire.KIND_EXACT, 0, q)
    live = wire.PoseFrame(0, 0, wire.KIND_LIVE, 0, q)
    assert rule.wanted("s01", exact, now=0.0)  # no live frame yet: exact shown
    assert rule.wanted("s01", live, now=1.0)
    assert not rule.wanted("s01", exact, now=1.5)  # live ones come: exact skipped
    assert rule.wanted("s02", exact, now=1.5)  # per subject
    assert rule.wanted("s01", exact, now=2.1)  # live ones stopped for 1 s
    assert rule.skipped == 1


def test_a_bad_frame_is_counted_and_the_others_sent():
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(5.0)
    sender = vmc.VmcSender({"s01": receiver.getsockname(), "s02": receiver.getsockname()})
    try:
        q = motion_q(3)
        bad = np.zeros((10, 4), np.float32)
        frames = [("s01", wire.PoseFrame(0, 0, wire.KIND_LIVE, 0, q[0])),
                  ("s02", wire.PoseFrame(0, 0, wire.KIND_LIVE, 0, bad)),
                  ("s03", wire.PoseFrame(0, 0, wire.KIND_LIVE, 0, q[1])),  # not one of its subjects
                  ("s02", wire.PoseFrame(1, 20_000, wire.KIND_LIVE, 0, q[2]))]
        assert sender.send(frames) == 2
        assert (sender.counters.sent, sender.counters.bad) == (2, 1)
        got = [OscBundle(receiver.recv(65536)) for _ in range(2)]
        names = [[m.params[0] for m in b if m.address == "/VMC/Ext/Bone/Pos"] for b in got]
        assert names[0] == names[1] == [b.name for b in vmc.VMC_BONES]
    finally:
        sender.close()
        receiver.close()


def test_vmc_process_sends_every_live_frame(stack):
    stack.router()
    receiver = OscReceiver()
    try:
        stack.start("vmc", "vmc", "--subject", "s01", "--to", f"127.0.0.1:{receiver.port}", "--connect",
                    stack.endpoint, "--wait", "0")
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
        try:
            pub = session.declare_publisher(wire.pose_key("s01"))
            wait_until(lambda: pub.matching_status.matching, 30, "vmc to subscribe to s01's pose")
            q = motion_q(150)
            t0 = 1_700_000_000_000_000
            noise = quat.normalize(np.random.default_rng(2).normal(size=(10, 4)))
            live_flags = []
            for i, frame_q in enumerate(q):
                flags = wire.FRAME_MISSING if i == 40 else 0
                live_flags.append(flags)
                pub.put(wire.encode_pose(wire.PoseFrame(i, t0 + 20_000 * i, wire.KIND_LIVE, flags, frame_q)))
                if i % 10 == 5:  # exact frames of other orientations: not sent while live ones come
                    pub.put(wire.encode_pose(wire.PoseFrame(i, t0 - 400_000, wire.KIND_EXACT, 0, noise)))
                if i % 20 == 0:  # let the receiver keep up (loopback UDP buffer)
                    n = i + 1
                    wait_until(lambda n=n: len(receiver.bundles("/VMC/Ext/T")) >= n, 20, f"{n} bundles")
            wait_until(lambda: len(receiver.bundles("/VMC/Ext/T")) >= len(q), 20, f"{len(q)} VMC bundles",
                       on_fail=lambda: print(stack.logs()))
        finally:
            session.close()
        bundles = receiver.bundles("/VMC/Ext/T")
        assert len(bundles) == len(q)
        bone_names = {b.name for b in vmc.VMC_BONES}
        worst = 0.0
        for i, (bundle, want) in enumerate(zip(bundles, q)):
            addresses = [a for a, _ in bundle]
            assert addresses[0] == "/VMC/Ext/Root/Pos" and bundle[0][1] == ["root", 0, 0, 0, 0, 0, 0, 1]
            assert addresses[-2:] == ["/VMC/Ext/OK", "/VMC/Ext/T"]
            bones = {args[0]: args[1:] for a, args in bundle if a == "/VMC/Ext/Bone/Pos"}
            assert set(bones) == bone_names and len(bundle) == len(bone_names) + 3
            got = segment_orientations({b: v[3:7] for b, v in bones.items()}, "standing")
            worst = max(worst, quat.angle_deg(got, want).max())
            assert bundle[-2][1] == [1, 3, 0, 0 if live_flags[i] else 1]
            assert bundle[-1][1][0] == pytest.approx(0.02 * i, abs=1e-6)
        assert worst < TOL_DEG, f"segment orientations off by {worst:.4g} deg"
    finally:
        receiver.close()


def _run(argv, capsys) -> tuple[int, str]:
    code = main(["vmc", *argv])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("argv, flag", [
    (["--to", "127.0.0.1:39539"], "--subject"),
    (["--subject", "s01", "--to", "127.0.0.1"], "--to 127.0.0.1"),
    (["--subject", "s01", "--to", "127.0.0.1:70000"], "--to 127.0.0.1:70000"),
    (["--subject", "s01", "--to", "no.such.host.invalid:39539"], "--to no.such.host.invalid:39539"),
    (["--subject", "s01", "--subject", "s02", "--to", "127.0.0.1:39539"], "--to"),
    (["--subject", "s/1", "--to", "127.0.0.1:39539"], "--subject s/1"),
])
def test_bad_flags_are_one_line_errors(argv, flag, capsys):
    code, err = _run(argv, capsys)
    assert code == 2
    assert err.count("\n") == 1 and err.startswith(f"limbstream vmc: error: {flag}"), err


def test_missing_subject_is_an_error(stack):
    stack.router()
    child = stack.start("vmc", "vmc", "--subject", "nobody", "--to", "127.0.0.1:39539", "--connect",
                        stack.endpoint, "--wait", "0.5")
    wait_until(lambda: not child.alive(), 30, "vmc to give up on a missing subject")
    assert child.returncode == 2
    errors = [line for line in child.tail() if "error" in line]
    assert errors == ["limbstream vmc: error: --subject nobody: no pose frame in 0.5 s "
                      "(is it running? limbstream watch nobody --kind auto)"]
    assert not any("Traceback" in line for line in child.tail())


def test_the_root_message_carries_the_frames_root():
    """Frames carrying a root: ``/VMC/Ext/Root/Pos`` puts the avatar root under it in Unity's frame
    (x mirrored), lowered by the Hips bone's rest height so the Hips stand at the root, unrotated;
    a frame without a root (zeros, no contacts) keeps the root at the origin."""
    import dataclasses

    from limbstream.skeleton import Skeleton
    q = np.tile(np.float32([1, 0, 0, 0]), (10, 1))
    still = wire.PoseFrame(0, 1_700_000_000_000_000, wire.KIND_LIVE, 0, q, Skeleton().positions(q.astype(np.float64)))
    roots = [(0.3, 0.88, -0.5), (0.35, 0.9, -0.45), (0.0, 0.0, 0.0)]
    frames = [("s01", dataclasses.replace(still, seq=k, t_us=still.t_us + 20_000 * k, root=np.float32(r),
                                          contacts=0b0001 if any(r) else 0)) for k, r in enumerate(roots)]
    receiver = OscReceiver()
    sender = vmc.VmcSender({"s01": ("127.0.0.1", receiver.port)})
    try:
        assert sender.send(frames) == 3
        wait_until(lambda: receiver.count("/VMC/Ext/T") == 3, 10, "three bundles")
        bundles = receiver.bundles("/VMC/Ext/T")
    finally:
        sender.close()
        receiver.close()
    hips = next(args for address, args in bundles[0] if address == "/VMC/Ext/Bone/Pos" and args[0] == "Hips")[2]
    assert hips == pytest.approx(0.88, abs=1e-6)   # the default adult's Hips rest height
    sent = [next(args for address, args in b if address == "/VMC/Ext/Root/Pos") for b in bundles]
    for (x, y, z), args in zip(roots[:2], sent):
        assert args[0] == "root" and args[1:4] == pytest.approx([-x, y - hips, z], abs=1e-6), args
        assert args[4:] == [0, 0, 0, 1]
    assert sent[2] == ["root", 0, 0, 0, 0, 0, 0, 1]
