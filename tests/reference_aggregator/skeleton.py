"""Forward kinematics: joint positions of a default body from the 10 segment orientations.

Each segment's bone points along a fixed direction of its own frame; with every segment
orientation at identity the body stands in its rest pose (Y up, X to the subject's left).
Two rest poses cover the sources (``wire.REST_POSES``): ``"standing"`` (arms hanging: the
built-in generator and IMU recordings) and ``"tpose"`` (arms out along +-X: BVH clips). The rest
pose is a property of the data: motion sources know theirs, devices announce it, pose frames
carry it. No sensor on the trunk, so the spine follows the hip (pelvis) segment.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from limbstream import quat, wire
from limbstream.wire import JOINTS, SEGMENTS

_S = {name: i for i, name in enumerate(SEGMENTS)}
_J = {name: i for i, name in enumerate(JOINTS)}


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

    def positions(self, q: np.ndarray, tpose: np.ndarray | bool | None = None) -> np.ndarray:
        """Joint positions, pelvis at the origin.

        Parameters
        ----------
        q : (..., 10, 4) segment orientations, SEGMENTS order, scalar-first.
        tpose : (...) bool or a bool: the orientations refer to the T-pose (else to the standing
            rest pose); None: the skeleton's ``rest_pose``.

        Returns
        -------
        (..., 15, 3) float32 metres, wire.JOINTS order.
        """
        q = np.asarray(q, np.float64)
        out = np.zeros(q.shape[:-2] + (len(JOINTS), 3))

        def seg(name):
            return q[..., _S[name], :]

        def put(joint, value):
            out[..., _J[joint], :] = value

        def get(joint):
            return out[..., _J[joint], :]

        down = np.array([0.0, -1.0, 0.0])
        if tpose is None:
            tpose = self.rest_pose == "tpose"
        tpose = np.asarray(tpose, bool)[..., None]  # (..., 1)
        hip = seg("hip")
        put("neck_base", quat.rotate(hip, [0.0, self.spine, 0.0]))
        put("head", get("neck_base") + quat.rotate(seg("neck"), [0.0, self.neck, 0.0]))
        for side, lateral in (("l", 1.0), ("r", -1.0)):
            put(f"{side}_hip", quat.rotate(hip, [lateral * self.hip_width / 2, 0.0, 0.0]))
            put(f"{side}_knee", get(f"{side}_hip") + quat.rotate(seg(f"{side}_thigh"), down * self.thigh))
            put(f"{side}_ankle", get(f"{side}_knee") + quat.rotate(seg(f"{side}_shank"), down * self.shank))
            arm = np.where(tpose, np.array([lateral, 0.0, 0.0]), down)
            put(f"{side}_shoulder", get("neck_base") + quat.rotate(hip, [lateral * self.shoulder_width / 2, -0.05, 0.0]))
            put(f"{side}_elbow", get(f"{side}_shoulder") + quat.rotate(seg(f"{side}_upperarm"), arm * self.upperarm))
            put(f"{side}_wrist", get(f"{side}_elbow") + quat.rotate(seg(f"{side}_lowerarm"), arm * self.lowerarm))
        return out.astype(np.float32)
