"""A BVH file's rest pose, from its own OFFSETs.

A BVH joint's rotation turns it away from the hierarchy's **zero pose** (every rotation channel
0), in which each bone points along the OFFSET of the joint it leads to. limbstream's
orientations are rotations from one of two rest poses (``wire.REST_POSES``): trunk up and legs
down in both, the arms hanging (``standing``) or out along +-X (``tpose``). So a file's zero
pose is read from its OFFSETs:

- the upper arms decide which rest pose it is: ``tpose`` if their zero-pose bones point nearer
  +-X than -Y (the CMU clips of subjects 1-5, Mixamo), ``standing`` otherwise (CMU subject 131,
  the files limbstream writes of standing data);
- an arm segment whose zero-pose bone is off that rest pose's (an A-pose's arms 45 deg down, a
  bent elbow) is turned onto it by the shortest arc: its orientation becomes
  ``q_zero_pose * c`` with ``c`` turning the rest pose's bone onto the file's;
- legs and trunk are taken as they are: every rest pose has them down and up, and the small
  tilts a file's zero pose gives them (CMU's thighs, about 20 deg out) are its skeleton's build.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from limbstream import quat, wire
from limbstream.skeleton import bone_axis

if TYPE_CHECKING:
    from limbstream.sources.bvh import BvhClip

NO_ARMS_REST_POSE = "tpose"
"""The rest pose of a file whose map names no arm (nothing in it can tell)."""
_ARMS = ("l_upperarm", "r_upperarm", "l_lowerarm", "r_lowerarm")


def zero_pose_positions(clip: BvhClip) -> np.ndarray:
    """(J, 3) every joint's position in the zero pose, file units, the root at its OFFSET."""
    out = np.zeros((len(clip.joints), 3))
    for j, parent in enumerate(clip.parents):  # parents come before their children
        out[j] = clip.offsets[j] + (out[parent] if parent >= 0 else 0.0)
    return out


def bone_end(clip: BvhClip, joint: int, at: np.ndarray) -> int | None:
    """The first joint below ``joint`` (depth first, file order) at another place in the zero
    pose ``at`` (J, 3): where the bone from ``joint`` ends; None if every joint below sits on it."""
    children: dict[int, list[int]] = {}
    for j, parent in enumerate(clip.parents):
        children.setdefault(int(parent), []).append(j)
    todo = list(children.get(joint, []))
    while todo:
        j = todo.pop(0)
        if np.linalg.norm(at[j] - at[joint]) > 1e-9:
            return j
        todo[:0] = children.get(j, [])
    return None


def bone_vector(clip: BvhClip, joint: int, at: np.ndarray) -> np.ndarray | None:
    """(3,) the zero-pose bone from ``joint`` to :func:`bone_end`, else to its End Site; None if
    neither exists."""
    end = bone_end(clip, joint, at)
    if end is not None:
        return at[end] - at[joint]
    site = clip.end_offsets[joint]
    return site if np.all(np.isfinite(site)) and np.linalg.norm(site) > 1e-9 else None


def shortest_arc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(4,) the unit quaternion of the smallest rotation turning direction ``a`` onto ``b``."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    dot = float(a @ b)
    if dot < -1.0 + 1e-12:  # opposite: half a turn about any axis normal to a
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return np.array([0.0, *(axis / np.linalg.norm(axis))])
    return quat.normalize(np.array([1.0 + dot, *np.cross(a, b)]))


def rest_pose(clip: BvhClip, segment_map: Mapping[str, str]) -> tuple[str, dict[str, np.ndarray]]:
    """The file's rest pose (``wire.REST_POSES``) and, per arm segment whose zero-pose bone is off
    it, the (4,) rotation ``c`` to apply on the right of its orientations (see the module)."""
    at = zero_pose_positions(clip)
    index = {name: j for j, name in enumerate(clip.joints)}
    bones: dict[str, np.ndarray] = {}
    for seg, joint in segment_map.items():
        bone = bone_vector(clip, index[joint], at) if seg in _ARMS and joint in index else None
        if bone is not None:
            bones[seg] = bone
    votes = []
    for seg in ("l_upperarm", "r_upperarm"):
        if seg in bones:
            d = bones[seg] / np.linalg.norm(bones[seg])
            votes.append(float(d @ bone_axis(seg, "tpose") - d @ bone_axis(seg, "standing")))
    pose = NO_ARMS_REST_POSE if not votes else ("tpose" if np.mean(votes) > 0 else "standing")
    corrections = {}
    for seg, bone in bones.items():
        c = shortest_arc(bone_axis(seg, pose), bone)
        if abs(c[0]) < 1.0 - 1e-15:
            corrections[seg] = c
    return wire.check_rest_pose(pose), corrections
