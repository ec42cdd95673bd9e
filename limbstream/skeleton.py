"""Forward kinematics: joint positions of a default body from the 10 segment orientations.

Each segment's bone points along a fixed direction of its own frame; with every segment
orientation at identity the body stands in its rest pose (Y up, X to the subject's left).
Two rest poses cover the sources (``wire.REST_POSES``): ``"standing"`` (arms hanging: the
built-in generator and IMU recordings) and ``"tpose"`` (arms out along +-X: most BVH files). The rest
pose is a property of the data: motion sources know theirs, devices announce it, pose frames
carry it. No sensor on the trunk, so the spine follows the hip (pelvis) segment.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from limbstream import wire
from limbstream.kernel import reconstruct
from limbstream.wire import JOINTS, SEGMENTS

_S = {name: i for i, name in enumerate(SEGMENTS)}
_J = {name: i for i, name in enumerate(JOINTS)}


def rest_offsets(rest_pose: str) -> np.ndarray:
    """(10, 4) scalar-first rotation from the T-pose to ``rest_pose`` per segment (SEGMENTS order):
    identity for ``tpose``; for ``standing`` the arms lowered by 90 deg about +Z (left arm +X -> -Y).
    An orientation referred to the T-pose is ``q_standing * rest_offsets("standing")``; one referred
    to the standing pose is ``q_tpose * conjugate(rest_offsets("standing"))``."""
    wire.check_rest_pose(rest_pose)
    out = np.tile([1.0, 0.0, 0.0, 0.0], (len(SEGMENTS), 1))
    if rest_pose == "standing":
        h = np.sqrt(0.5)
        for s, sign in (("l", -1.0), ("r", 1.0)):
            out[_S[f"{s}_upperarm"]] = out[_S[f"{s}_lowerarm"]] = (h, 0.0, 0.0, sign * h)
    return out


@dataclass(frozen=True)
class Skeleton:
    """Bone lengths in metres (defaults: an adult of about 1.75 m) and the default rest pose
    (of orientations that do not say theirs)."""

    thigh: float = 0.45
    shank: float = 0.43
    upperarm: float = 0.30
    lowerarm: float = 0.27
    spine: float = 0.50
    neck: float = 0.22
    hip_width: float = 0.20
    shoulder_width: float = 0.38
    rest_pose: str = "standing"

    def __post_init__(self):
        wire.check_rest_pose(self.rest_pose)
        for name in ("thigh", "shank", "upperarm", "lowerarm", "spine", "neck", "hip_width", "shoulder_width"):
            if not getattr(self, name) > 0:
                raise ValueError(f"bone length {name} must be > 0 m, got {getattr(self, name)}")

    def positions(self, q: np.ndarray, tpose: np.ndarray | bool | None = None,
                  dtype: type = np.float32) -> np.ndarray:
        """Joint positions, pelvis at the origin: each joint its parent's position plus its bone
        turned by its segment's orientation (``limbstream.quat.rotate``; the bones in C:
        ``limbstream.kernel.reconstruct.Chain``).

        Parameters
        ----------
        q : (..., 10, 4) segment orientations, SEGMENTS order, scalar-first.
        tpose : (...) bool or a bool: the orientations refer to the T-pose (else to the standing
            rest pose); None: the skeleton's ``rest_pose``.
        dtype : of the result (float32 for pose frames; float64 where positions are differentiated).

        Returns
        -------
        (..., 15, 3) metres, wire.JOINTS order.
        """
        if tpose is None:
            tpose = self.rest_pose == "tpose"
        return self._chain.positions(q, tpose, dtype)

    @classmethod
    def of_joints(cls, joints: np.ndarray, rest_pose: str = wire.DEFAULT_REST_POSE) -> Skeleton:
        """The skeleton whose bones joint positions ``joints`` (15, 3) m (a pose frame's, JOINTS
        order) have (:func:`joint_lengths`); ValueError if a length is not > 0."""
        thigh, shank, upperarm, lowerarm, spine, neck, hip_width, shoulder_width = joint_lengths(joints).tolist()
        return cls(thigh, shank, upperarm, lowerarm, spine, neck, hip_width, shoulder_width, rest_pose)

    @cached_property
    def _chain(self) -> reconstruct.Chain:
        """The bones in the order their joints are placed: the segment that turns each, its joint
        and parent joint (the pelvis: the origin), its vector in its segment's frame at rest, m,
        standing and with the arms out (T-pose)."""
        down = np.array([0.0, -1.0, 0.0])
        rows: list[tuple[str, str | None, str, Any, Any]] = [("neck_base", None, "hip", [0.0, self.spine, 0.0], None),
                ("head", "neck_base", "neck", [0.0, self.neck, 0.0], None)]
        for side, lateral in (("l", 1.0), ("r", -1.0)):
            out = np.array([lateral, 0.0, 0.0])
            rows += [(f"{side}_hip", None, "hip", [lateral * self.hip_width / 2, 0.0, 0.0], None),
                     (f"{side}_knee", f"{side}_hip", f"{side}_thigh", down * self.thigh, None),
                     (f"{side}_ankle", f"{side}_knee", f"{side}_shank", down * self.shank, None),
                     (f"{side}_shoulder", "neck_base", "hip", [lateral * self.shoulder_width / 2, -0.05, 0.0], None),
                     (f"{side}_elbow", f"{side}_shoulder", f"{side}_upperarm", down * self.upperarm, out * self.upperarm),
                     (f"{side}_wrist", f"{side}_elbow", f"{side}_lowerarm", down * self.lowerarm, out * self.lowerarm)]
        return reconstruct.Chain([_S[seg] for _, _, seg, _, _ in rows], [_J[joint] for joint, *_ in rows],
                          [-1 if up is None else _J[up] for _, up, *_ in rows], np.array([r[3] for r in rows]),
                          np.array([r[3] if r[4] is None else r[4] for r in rows]), len(JOINTS))


_LENGTH_PAIRS = np.array([[_J[a], _J[b]] for a, b in (
    ("l_knee", "l_hip"), ("l_ankle", "l_knee"), ("l_elbow", "l_shoulder"), ("l_wrist", "l_elbow"),
    ("neck_base", "pelvis"), ("head", "neck_base"), ("l_hip", "r_hip"), ("l_shoulder", "r_shoulder"))])


def joint_lengths(joints: np.ndarray) -> np.ndarray:
    """(8,) float64 the :class:`Skeleton` lengths (thigh, shank, upperarm, lowerarm, spine, neck,
    hip_width, shoulder_width), m, of joint positions ``joints`` (15, 3) m: the left limbs', the
    widths between the two sides' joints."""
    j = np.asarray(joints, np.float64)
    d = j[_LENGTH_PAIRS[:, 0]] - j[_LENGTH_PAIRS[:, 1]]
    return np.sqrt(np.einsum("ij,ij->i", d, d))


def bone_axis(segment: str, rest_pose: str = wire.DEFAULT_REST_POSE) -> np.ndarray:
    """(3,) the unit direction of ``segment``'s bone in its own frame, from its proximal joint
    on (as :meth:`Skeleton.positions` draws it): down (-Y) for legs and, standing, arms; along
    +-X for the arms of the T-pose; up (+Y) for the hip (the spine) and the neck."""
    wire.check_rest_pose(rest_pose)
    if segment not in SEGMENTS:
        raise ValueError(f"unknown segment {segment!r}")
    if segment in ("hip", "neck"):
        return np.array([0.0, 1.0, 0.0])
    if segment.endswith("arm") and rest_pose == "tpose":
        return np.array([1.0 if segment.startswith("l_") else -1.0, 0.0, 0.0])
    return np.array([0.0, -1.0, 0.0])
