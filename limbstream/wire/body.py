"""The body layout every message shares: the 10 measured segments, the joints of a pose
frame and the bones a client draws between them."""
from __future__ import annotations

SEGMENTS: tuple[str, ...] = (
    "l_shank", "r_shank", "l_thigh", "r_thigh", "l_lowerarm",
    "r_lowerarm", "l_upperarm", "r_upperarm", "neck", "hip",
)
"""The 10-IMU layout: one device per segment, in this order in pose frames and motion arrays."""

JOINTS: tuple[str, ...] = (
    "pelvis", "neck_base", "head",
    "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle",
    "l_shoulder", "l_elbow", "l_wrist", "r_shoulder", "r_elbow", "r_wrist",
)
"""Joint positions of a pose frame, in this order (see limbstream.skeleton)."""

BONES: tuple[tuple[str, str], ...] = (
    ("pelvis", "neck_base"), ("neck_base", "head"),
    ("pelvis", "l_hip"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"),
    ("pelvis", "r_hip"), ("r_hip", "r_knee"), ("r_knee", "r_ankle"),
    ("neck_base", "l_shoulder"), ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"),
    ("neck_base", "r_shoulder"), ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"),
)
"""Lines a client draws between joints."""

REST_POSES: tuple[str, ...] = ("standing", "tpose")
"""What identity segment orientations mean, the body's **rest pose**: ``standing`` (arms hanging
along -Y: the built-in generator and IMU recordings) or ``tpose`` (arms out along +-X: BVH clips
and files converted from them). Every motion source knows its own; devices announce it in their
status, pose frames in their flags (docs/protocol.md, "Rest pose")."""
DEFAULT_REST_POSE = "standing"
"""The rest pose of data that does not say (a device status without the field)."""


def check_rest_pose(name: str) -> str:
    """``name`` if it is one of REST_POSES, else ValueError with the choices."""
    if name not in REST_POSES:
        raise ValueError(f"rest pose must be one of {', '.join(REST_POSES)}, got {name!r}")
    return name
