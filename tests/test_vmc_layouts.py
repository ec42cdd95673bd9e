"""VMC of a ``full`` subject: its chest, head, hands and feet drive Unity's Chest, Head, hands and
feet; a receiver composing the local rotations down Unity's hierarchy (test_vmc's, written
independently of services/outputs/vmc.py) gets every one of its 15 segments back; the bundles a
real UDP receiver gets carry the rig's bones at the subject's own lengths."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.osc import OscReceiver
from support.stack import wait_until
from test_vmc import MIRROR, PARENT, motion_q

from limbstream import quat, wire
from limbstream.body import FULL, Body
from limbstream.services.outputs import vmc

BONE_OF = {"hip": "Hips", "chest": "Chest", "head": "Head", "l_thigh": "LeftUpperLeg", "l_shank": "LeftLowerLeg",
           "l_foot": "LeftFoot", "r_thigh": "RightUpperLeg", "r_shank": "RightLowerLeg", "r_foot": "RightFoot",
           "l_upperarm": "LeftUpperArm", "l_lowerarm": "LeftLowerArm", "l_hand": "LeftHand",
           "r_upperarm": "RightUpperArm", "r_lowerarm": "RightLowerArm", "r_hand": "RightHand"}
HELD = {"Spine", "Neck", "LeftShoulder", "RightShoulder"}
T0_US = 1_700_000_000_000_000


def full_q(n: int) -> np.ndarray:
    """(n, 15, 4) float32: paper10's generated motion on its segments, the chest, head, hands and
    feet turning on their own."""
    base = motion_q(n)
    out = np.empty((n, 15, 4), np.float32)
    for i, s in enumerate(FULL.segment_names):
        if s in wire.SEGMENTS:
            out[:, i] = base[:, wire.SEGMENTS.index(s)]
        else:
            angle = 0.5 * np.sin(np.linspace(0, 6, n) + i)[:, None]
            axis = Rotation.random(random_state=i).apply([0.0, 0.0, 1.0])
            out[:, i] = quat.from_rotation(Rotation.from_rotvec(angle * axis))
    return out


def segments_back(local_xyzw: dict[str, list[float]], rest_pose: str) -> np.ndarray:
    """(15, 4) limbstream global orientations of full's segments from Unity local rotations."""
    memo: dict[str, np.ndarray] = {}

    def global_matrix(bone: str) -> np.ndarray:
        if bone not in memo:
            local = Rotation.from_quat(local_xyzw[bone]).as_matrix()
            memo[bone] = local if PARENT[bone] is None else global_matrix(PARENT[bone]) @ local
        return memo[bone]

    out = []
    for seg in FULL.segment_names:
        m = MIRROR @ global_matrix(BONE_OF[seg]) @ MIRROR
        if rest_pose == "standing" and ("arm" in seg or "hand" in seg):  # T-pose -> hanging: 90 deg about Z
            m = m @ Rotation.from_rotvec([0, 0, -np.pi / 2 if seg[0] == "l" else np.pi / 2]).inv().as_matrix()
        out.append(quat.from_rotation(Rotation.from_matrix(m)))
    return np.array(out)


@pytest.mark.parametrize("rest_pose", ["standing", "tpose"])
def test_full_local_rotations_give_back_every_segment(rest_pose):
    rig = vmc.rig(FULL)
    names = [b.name for b in rig.bones]
    assert set(names) == set(PARENT) and {b.parent or None for b in rig.bones} <= set(PARENT) | {None}
    assert all(PARENT[b.name] == (b.parent or None) for b in rig.bones)
    assert {b.name: b.segment for b in rig.bones if b.segment} == {v: k for k, v in BONE_OF.items()}
    assert {b.name for b in rig.bones if not b.segment} == HELD
    q = full_q(100)
    local = vmc.local_rotations(q, rest_pose, FULL)
    worst = max(quat.angle_deg(segments_back(dict(zip(names, row[:, [1, 2, 3, 0]])), rest_pose), frame).max()
                for row, frame in zip(local, q))
    assert worst < 1e-4, f"{worst:.3g} deg"
    for name in HELD:  # held at rest: identity local rotations
        assert quat.angle_deg(local[:, names.index(name)], [1, 0, 0, 0]).max() < 1e-6


def test_a_full_subjects_bundles_carry_its_rig_at_its_lengths():
    body = Body.from_height(FULL, 1.9)
    q = full_q(3)
    receiver = OscReceiver()
    sender = vmc.VmcSender({"s01": ("127.0.0.1", receiver.port), "s02": ("127.0.0.1", receiver.port)})
    try:
        frames = [("s01", wire.PoseFrame(k, T0_US + 20_000 * k, wire.KIND_LIVE, 0, q[k], body.positions(q[k]), FULL))
                  for k in range(3)]
        assert sender.send(frames) == 3
        wait_until(lambda: receiver.count("/VMC/Ext/T") == 3, 10, "three bundles")
        bundle = receiver.bundles("/VMC/Ext/T")[-1]
    finally:
        sender.close()
        receiver.close()
    bones = {args[0]: np.array(args[1:], float) for address, args in bundle if address == "/VMC/Ext/Bone/Pos"}
    assert list(bones) == [b.name for b in vmc.rig(FULL).bones] and len(bones) == 19
    want = vmc.local_rotations(q[2], "standing", FULL)[:, [1, 2, 3, 0]]
    got = np.array([v[3:] for v in bones.values()])
    assert np.abs(got - want).max() < 1e-6  # float32 on the wire
    L = body.lengths
    pos = {name: v[:3] for name, v in bones.items()}  # Unity frame: x to the right (limbstream's -x)
    assert pos["LeftFoot"] == pytest.approx([0.0, -L["l_shank"], 0.0], abs=1e-5)
    assert pos["LeftHand"] == pytest.approx([-L["l_lowerarm"], 0.0, 0.0], abs=1e-5)  # T-pose: left arm along -x
    assert pos["RightHand"] == pytest.approx([L["r_lowerarm"], 0.0, 0.0], abs=1e-5)
    assert pos["Chest"] == pytest.approx([0.0, L["hip"] / 2, 0.0], abs=1e-5)
    assert pos["Head"] == pytest.approx([0.0, vmc.HEAD_AT * L["head"], 0.0], abs=1e-5)
    assert pos["Neck"] == pytest.approx([0.0, L["chest"], 0.0], abs=1e-5)
    rest = body.positions(np.tile([1.0, 0, 0, 0], (15, 1)))
    assert pos["Hips"] == pytest.approx([0.0, -rest[:, 1].min(), 0.0], abs=1e-5)  # toes on the floor
