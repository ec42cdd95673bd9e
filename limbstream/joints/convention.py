"""Joint angles from calibrated segment orientations, in the conventions of OpenSim's Rajagopal
(2015) full-body model (docs/evaluation.md, "Joint angles").

Anatomical frames. A calibrated segment's orientation is its turn from the rest pose, in a world
whose axes are the subject's in that pose (limbstream's frame: X to the subject's left, Y up, Z
forward). So the rest pose (standing, arms hanging, knees and elbows straight) defines every
segment's anatomical axes, the mounting pose (or a functional calibration,
:mod:`limbstream.joints.functional`) having resolved which way is forward. BVH data whose rest
pose is the T-pose is first brought to the standing rest pose (arms lowered by 90 degrees about
the forward axis, :func:`limbstream.skeleton.rest_offsets`). The angles are then taken in
OpenSim's axes (X forward, Y up, Z to the subject's right; ``(x, y, z) -> (z, y, -x)``).

Angles. Each joint's rotation (parent anatomical frame -> child's) is split into intrinsic
Z-X-Y Euler angles, the order of the model's joints (its CustomJoints list rotation1 about Z,
rotation2 about X, rotation3 about Y, each about an axis carried by the rotations before): the
first is flexion (sagittal), the second ad/abduction about the floating axis, the third the
rotation about the child's long axis, as ISB's joint coordinate systems (Grood & Suntay; Wu et
al. 2002, 2005) take them. Signs and names are the model's:

- ``hip_r``: hip_flexion_r about +Z, hip_adduction_r about +X, hip_rotation_r about +Y;
  ``hip_l``: hip_adduction_l and hip_rotation_l with coefficient -1 (about -X, -Y).
- ``walker_knee_r/l``: knee_angle about the femur offset frame's X axis, which the frame's
  orientation turns to (0, -0.07, -1) in the femur: about -Z (flexion positive, range 0-120
  degrees in the model; a hyperextended knee reads negative here, no clipping).
- ``acromial_r``: arm_flex_r about +Z, arm_add_r about +X, arm_rot_r about +Y; ``acromial_l``:
  arm_add_l about -X, arm_rot_l about -Y.
- ``elbow_r/l``: elbow_flex about the humerus offset frame's Z axis, (+-0.23, 0.02, 0.97): +Z
  (flexion positive, range 0-150 degrees).
- The model has no neck: ``neck_extension``, ``neck_bending``, ``neck_rotation`` take its back
  joint's axes and signs (lumbar_extension +Z, lumbar_bending +X, lumbar_rotation +Y).

The 10-segment body has no trunk sensor (the trunk follows the pelvis): the shoulders and the
neck are measured from the pelvis, as the model's arm angles would be with its lumbar angles at 0.
The hinges' small axis tilts in the model (knee 4 degrees, elbow 13) are left out: knee and elbow
flexion turn about the rest pose's lateral axis.

Gimbal lock. Z-X-Y angles lock where the middle angle (ad/abduction) reaches +-90 degrees: the
first and third angles then turn about the same axis and only their sum is defined. Within
:data:`GIMBAL_DEG` of it they are flagged :data:`GIMBAL` (finite but ill-conditioned: an
orientation error of e degrees moves them by about e / cos(middle)); at the lock itself the third
is set to 0 and the first carries the sum (scipy's choice). Hips and knees never come near it;
a shoulder does with the arm raised sideways to the horizontal.

Flags per angle: :data:`MISSING` (a segment of the joint has no data: angle NaN),
:data:`UNCALIBRATED` (the subject's frames are not anatomical yet: angle NaN), :data:`GIMBAL`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from limbstream import quat, wire
from limbstream.skeleton import rest_offsets

MISSING, GIMBAL, UNCALIBRATED = 1, 2, 4
"""Flag bits of one angle (0: a valid angle)."""

GIMBAL_DEG = 10.0
"""The first and third angles of a joint are flagged GIMBAL within this many degrees of lock."""

TO_OPENSIM = np.array([math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0])
"""limbstream's axes to OpenSim's, a turn of 90 degrees about Y: (x, y, z) -> (z, y, -x)."""


@dataclass(frozen=True)
class Joint:
    """One joint: the segments it joins and the names and signs of its three Z-X-Y angles
    (None: not reported, e.g. a hinge's ad/abduction)."""

    name: str
    parent: str
    child: str
    angles: tuple[str | None, str | None, str | None]
    signs: tuple[float, float, float] = (1.0, 1.0, 1.0)


JOINT_TABLE: tuple[Joint, ...] = (
    Joint("hip_r", "hip", "r_thigh", ("hip_flexion_r", "hip_adduction_r", "hip_rotation_r")),
    Joint("knee_r", "r_thigh", "r_shank", ("knee_angle_r", None, None), (-1.0, 1.0, 1.0)),
    Joint("hip_l", "hip", "l_thigh", ("hip_flexion_l", "hip_adduction_l", "hip_rotation_l"), (1.0, -1.0, -1.0)),
    Joint("knee_l", "l_thigh", "l_shank", ("knee_angle_l", None, None), (-1.0, 1.0, 1.0)),
    Joint("shoulder_r", "hip", "r_upperarm", ("arm_flex_r", "arm_add_r", "arm_rot_r")),
    Joint("elbow_r", "r_upperarm", "r_lowerarm", ("elbow_flex_r", None, None)),
    Joint("shoulder_l", "hip", "l_upperarm", ("arm_flex_l", "arm_add_l", "arm_rot_l"), (1.0, -1.0, -1.0)),
    Joint("elbow_l", "l_upperarm", "l_lowerarm", ("elbow_flex_l", None, None)),
    Joint("neck", "hip", "neck", ("neck_extension", "neck_bending", "neck_rotation")),
)
"""The joints of the 10-segment body, in the order of their angles in :data:`ANGLES`."""

ANGLES: tuple[str, ...] = tuple(a for j in JOINT_TABLE for a in j.angles if a is not None)
"""The joint angles, in this order in every angle vector (degrees)."""

_SEG = {name: i for i, name in enumerate(wire.SEGMENTS)}
_PARENT = np.array([_SEG[j.parent] for j in JOINT_TABLE])
_CHILD = np.array([_SEG[j.child] for j in JOINT_TABLE])
_AT = [(j, i, s) for j, joint in enumerate(JOINT_TABLE) for i, (a, s) in enumerate(zip(joint.angles, joint.signs))
       if a is not None]
_JOINT_OF = np.array([j for j, _, _ in _AT])
"""(A,) the joint of each angle."""
_COMPONENT = np.array([i for _, i, _ in _AT])
"""(A,) which Z-X-Y angle (0, 1, 2) each angle is."""
_SIGN = np.array([s for _, _, s in _AT])
_STANDING_FROM_TPOSE = quat.conjugate(rest_offsets("standing"))
_OPENSIM_SIGNS = np.array([1.0, 1.0, 1.0, -1.0])
"""A rotation's (w, z, y, -x) is the same rotation in OpenSim's axes (:data:`TO_OPENSIM`)."""


def anatomical(q: np.ndarray, rest_pose: str = wire.DEFAULT_REST_POSE) -> np.ndarray:
    """Anatomical segment frames in OpenSim's axes.

    Parameters
    ----------
    q : (..., 10, 4) calibrated segment orientations, :data:`wire.SEGMENTS` order, scalar-first
        (any nonzero norm; non-finite rows stay non-finite).
    rest_pose : what identity means for ``q`` (``wire.REST_POSES``).

    Returns
    -------
    (..., 10, 4) float64 unit quaternions, ground <- segment, in OpenSim's axes (X forward of
    the rest pose, Y up, Z right); identity in the standing rest pose.
    """
    q = np.asarray(q, np.float64)
    q = standing(q / np.linalg.norm(q, axis=-1, keepdims=True), rest_pose)
    return quat.multiply(quat.multiply(TO_OPENSIM, q), quat.conjugate(TO_OPENSIM))


def standing(q: np.ndarray, rest_pose: str) -> np.ndarray:
    """(..., 10, 4) segment orientations ``q`` referred to the standing rest pose (T-pose data:
    the arms' frames lowered by 90 degrees about the forward axis; standing data unchanged)."""
    if wire.check_rest_pose(rest_pose) == "tpose":
        return quat.multiply(q, _STANDING_FROM_TPOSE)
    return np.asarray(q, np.float64)


def euler_zxy(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsic Z-X-Y angles of rotations ``q`` (..., 4) (``R = Rz(a) Rx(b) Ry(c)``).

    Returns
    -------
    angles : (..., 3) float64 radians (a, b, c); b in [-pi/2, pi/2]. At the lock (|b| = pi/2)
        c is 0 and a carries the sum.
    near_lock : (...) bool, within :data:`GIMBAL_DEG` of the lock.
    """
    w, x, y, z = np.moveaxis(np.asarray(q, np.float64), -1, 0)
    r01, r11 = 2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z)
    r20, r22 = 2.0 * (x * z - w * y), 1.0 - 2.0 * (x * x + y * y)
    r21 = 2.0 * (y * z + w * x)
    cos_b = np.hypot(r01, r11)
    locked = cos_b < 1e-9
    a = np.where(locked, np.arctan2(2.0 * (x * y + w * z), 1.0 - 2.0 * (y * y + z * z)), np.arctan2(-r01, r11))
    c = np.where(locked, 0.0, np.arctan2(-r20, r22))
    return np.stack([a, np.arctan2(r21, cos_b), c], axis=-1), cos_b < math.sin(math.radians(GIMBAL_DEG))


def joint_angles(q: np.ndarray, present: np.ndarray | None = None, rest_pose: str = wire.DEFAULT_REST_POSE,
                 calibrated: np.ndarray | bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The joint angles of calibrated segment orientations, vectorised over frames and subjects.

    Parameters
    ----------
    q : (..., 10, 4) segment orientations, :data:`wire.SEGMENTS` order (anatomical once
        calibrated: identity in the rest pose, the rest pose's forward resolved).
    present : (10,) or (..., 10) bool, the segments that have data (None: every finite one).
    rest_pose : what identity means for ``q``.
    calibrated : bool or (...) bool per leading index (e.g. per subject): False gives no angles
        (NaN, flag UNCALIBRATED).

    Returns
    -------
    angles : (..., A) float64 degrees, :data:`ANGLES` order; NaN where flagged MISSING or
        UNCALIBRATED.
    flags : (..., A) uint8, :data:`MISSING` | :data:`GIMBAL` | :data:`UNCALIBRATED` bits.
    """
    q = np.asarray(q, np.float64)
    finite = np.isfinite(q).all(axis=-1) & (np.abs(q).sum(axis=-1) > 0)
    have = finite if present is None else finite & np.asarray(present, bool)
    q = standing(np.where(have[..., None], q, np.array([1.0, 0.0, 0.0, 0.0])), rest_pose)
    relative = quat.multiply(quat.conjugate(q[..., _PARENT, :]), q[..., _CHILD, :])  # (..., J, 4)
    relative = relative[..., [0, 3, 2, 1]] * _OPENSIM_SIGNS  # in OpenSim's axes (conjugated by TO_OPENSIM)
    relative /= np.linalg.norm(relative, axis=-1, keepdims=True)
    euler, near_lock = euler_zxy(relative)
    angles = np.degrees(euler[..., _JOINT_OF, _COMPONENT]) * _SIGN
    flags = np.where(near_lock[..., _JOINT_OF] & (_COMPONENT != 1), GIMBAL, 0).astype(np.uint8)
    missing = ~(have[..., _PARENT] & have[..., _CHILD])[..., _JOINT_OF]
    flags |= np.where(missing, MISSING, 0).astype(np.uint8)
    flags |= np.where(~np.asarray(calibrated, bool), UNCALIBRATED, 0).astype(np.uint8)[..., None]
    return np.where(flags & (MISSING | UNCALIBRATED), np.nan, angles), flags
