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

Layouts. Each layout has its joints (``wire.joint_table``): the ``full`` layout's chest, head,
hands and feet add

- ``back`` (pelvis -> chest): lumbar_extension +Z, lumbar_bending +X, lumbar_rotation +Y (trunk
  flexion is negative extension); the shoulders (``acromial``) and the neck are then measured
  from the chest, as the model measures the arm against its torso.
- ``ankle_r/l`` (shank -> foot): ankle_angle about +Z (the model's talocrural axis
  (-0.105, -0.174, 0.979), its tilt left out; dorsiflexion positive, both sides), then
  ``subtalar_angle`` as the middle Z-X-Y angle, about the floating axis along the foot (+X on
  the right, -X on the left: inversion positive, the model's sign). The model's subtalar axis
  is oblique ((0.787, 0.605, -0.121) in the calcaneus: about 42 degrees up from the sole), so
  this angle is the inversion part of the foot's turn, not exactly the model's subtalar
  coordinate; the third angle (the foot turned in or out about the vertical) is not reported.
  The foot's rest, flat on the floor, is the model's zero.
- ``radius_hand_r/l`` (lower arm -> hand): wrist_flex about +Z, wrist_dev about +X on the right
  (-X on the left), in the model's forearm frame, whose zero holds the palm forward. The rest
  pose holds the palms against the thighs (thumbs forward: a T-pose's palms-down hands brought
  down to the sides), a quarter turn of pronation from the model's zero, so the joint's frames
  are the rest frames turned by that quarter turn about the forearm (``Joint.frame``: +Y on the
  right, -Y on the left): flexion (towards the palm) and ulnar deviation positive. Pronation
  is not observable between the lower arm and the hand segments as modelled (the hand turns
  with the radius, the lower-arm segment with both): the third angle is not reported.

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

import functools
import math
from dataclasses import dataclass

import numpy as np

from limbstream import quat, wire
from limbstream.body import LAYOUTS, Layout
from limbstream.body import layout as load_layout
from limbstream.wire import JOINT_TABLE, Joint  # noqa: F401  (re-exported: the joints, the contract's table)

MISSING, GIMBAL, UNCALIBRATED = wire.ANGLE_MISSING, wire.ANGLE_GIMBAL, wire.ANGLE_UNCALIBRATED
"""Flag bits of one angle (0: a valid angle; the contract's, ``limbstream.wire.angles``)."""

GIMBAL_DEG = 10.0
"""The first and third angles of a joint are flagged GIMBAL within this many degrees of lock."""

TO_OPENSIM = np.array([math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0])
"""limbstream's axes to OpenSim's, a turn of 90 degrees about Y: (x, y, z) -> (z, y, -x)."""

ANGLES: tuple[str, ...] = wire.JOINT_ANGLES
"""The joint angles of the 10-segment body (``paper10``), in this order in its angle vectors
(degrees); another layout's: ``wire.joint_angles(layout)``."""

_LOCK_SIN = math.sin(math.radians(GIMBAL_DEG))


def from_tpose(layout: Layout) -> np.ndarray:
    """(S, 4) per segment of ``layout`` the turn that refers a T-pose orientation to the standing
    rest pose (``q_standing = q_tpose * from_tpose``): the conjugate of the shortest turn taking
    its bone's T-pose direction to its standing one (the arms and hands lowered by 90 degrees
    about the forward axis; identity where both are the same)."""
    out = np.tile([1.0, 0.0, 0.0, 0.0], (len(layout.segments), 1))
    for k, segment in enumerate(layout.segments):
        a, b = (np.array(segment.directions[pose]) for pose in ("tpose", "standing"))
        axis = np.cross(a, b)
        if np.linalg.norm(axis) > 1e-12:
            half = 0.5 * math.atan2(float(np.linalg.norm(axis)), float(a @ b))
            sin_half = math.cos(0.5 * math.pi - half)  # (a quarter turn: exactly cos, as skeleton.rest_offsets has it)
            out[k] = quat.conjugate(np.concatenate([[math.cos(half)], sin_half * axis / np.linalg.norm(axis)]))
    return out


@dataclass(frozen=True)
class _Plan:
    """What :func:`joint_angles` needs of a layout: its segments, its joints and angles, and the
    arrays that index them."""

    segments: tuple[str, ...]
    table: tuple[Joint, ...]
    angles: tuple[str, ...]
    parent: np.ndarray        # (J,) segment index of each joint's parent
    child: np.ndarray         # (J,) ... and child
    joint_of: np.ndarray      # (A,) the joint of each angle
    take: np.ndarray          # (A,) each angle's place in a (J, 3) array of the joints' Z-X-Y angles, flattened
    deg: np.ndarray           # (A,) radians to degrees, times each angle's sign
    side_angle: np.ndarray    # (A,) the first or third angle of its joint (those gimbal lock makes ill-conditioned)
    frames: np.ndarray | None  # (J, 4) the joints' model frames (None: all identity)
    from_tpose: np.ndarray    # (S, 4) T-pose -> standing per segment
    framed: np.ndarray        # (K,) the joints whose model frame is not identity

    @property
    def ends(self) -> np.ndarray:
        return np.concatenate([self.parent, self.child])


@functools.lru_cache(maxsize=16)
def _plan_of(layout: Layout) -> _Plan:
    table = wire.joint_table(layout)
    seg = layout.segment_index
    at = [(j, i, s) for j, joint in enumerate(table) for i, (a, s) in enumerate(zip(joint.angles, joint.signs))
          if a is not None]
    joint_of = np.array([j for j, _, _ in at], int)
    component = np.array([i for _, i, _ in at], int)
    frames = np.array([j.frame for j in table], np.float64).reshape(-1, 4)
    framed = np.flatnonzero((frames != [1.0, 0.0, 0.0, 0.0]).any(axis=1))
    return _Plan(layout.segment_names, table, tuple(a for j in table for a in j.angles if a is not None),
                 np.array([seg[j.parent] for j in table], int), np.array([seg[j.child] for j in table], int),
                 joint_of, 3 * joint_of + component, np.degrees(np.array([s for _, _, s in at])), component != 1,
                 frames if len(framed) else None, from_tpose(layout), framed)


def plan(layout: str | Layout = "paper10") -> _Plan:
    """The plan of a layout: a built-in's name, a layout file's path or a
    :class:`limbstream.body.Layout` (ValueError naming the choices for an unknown one)."""
    if isinstance(layout, str):
        layout = LAYOUTS[layout] if layout in LAYOUTS else _loaded(layout)
    return _plan_of(layout)


@functools.lru_cache(maxsize=16)
def _loaded(path: str) -> Layout:
    return load_layout(path)


def angle_names(layout: str | Layout = "paper10") -> tuple[str, ...]:
    """(A,) the joint angles of ``layout`` in the order of its angle vectors (``paper10``'s:
    :data:`ANGLES`)."""
    return plan(layout).angles


def anatomical(q: np.ndarray, rest_pose: str = wire.DEFAULT_REST_POSE, layout: str | Layout = "paper10") -> np.ndarray:
    """Anatomical segment frames in OpenSim's axes.

    Parameters
    ----------
    q : (..., S, 4) calibrated segment orientations in the layout's segment order (``paper10``:
        :data:`wire.SEGMENTS`), scalar-first (any nonzero norm; non-finite rows stay non-finite).
    rest_pose : what identity means for ``q`` (``wire.REST_POSES``).
    layout : the layout of ``q`` (a built-in's name, a layout file or a Layout).

    Returns
    -------
    (..., S, 4) float64 unit quaternions, ground <- segment, in OpenSim's axes (X forward of
    the rest pose, Y up, Z right); identity in the standing rest pose.
    """
    q = np.asarray(q, np.float64)
    q = standing(q / np.linalg.norm(q, axis=-1, keepdims=True), rest_pose, layout)
    return quat.multiply(quat.multiply(TO_OPENSIM, q), quat.conjugate(TO_OPENSIM))


def standing(q: np.ndarray, rest_pose: str, layout: str | Layout = "paper10") -> np.ndarray:
    """(..., S, 4) segment orientations ``q`` of ``layout`` referred to the standing rest pose
    (T-pose data: the arms' and hands' frames lowered by 90 degrees about the forward axis,
    :func:`from_tpose`; standing data unchanged)."""
    if wire.check_rest_pose(rest_pose) == "tpose":
        return quat.multiply(q, plan(layout).from_tpose)
    return np.asarray(q, np.float64)


def euler_zxy(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsic Z-X-Y angles of rotations ``q`` (..., 4) (``R = Rz(a) Rx(b) Ry(c)``; any
    nonzero norm).

    Returns
    -------
    angles : (..., 3) float64 radians (a, b, c); b in [-pi/2, pi/2]. At the lock (|b| = pi/2)
        c is 0 and a carries the sum.
    near_lock : (...) bool, within :data:`GIMBAL_DEG` of the lock.
    """
    a, b, c, near_lock, _ = _euler_zxy(*np.moveaxis(np.asarray(q, np.float64), -1, 0))
    return np.stack([a, b, c], axis=-1), near_lock


def _euler_zxy(w: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`euler_zxy` of the quaternion components ``w, x, y, z`` (each (...)): a, b, c (...)
    radians, near_lock (...) bool and the squared norm n (...). The rotation matrix's entries are
    taken times n, which leaves every ratio, and so every angle, as it is."""
    ww, xx, yy, zz = w * w, x * x, y * y, z * z
    n = ww + xx + yy + zz
    r01, r11 = 2.0 * (x * y - w * z), ww - xx + yy - zz
    r20, r22 = 2.0 * (x * z - w * y), ww - xx - yy + zz
    cos_b = np.sqrt(r01 * r01 + r11 * r11)
    a = np.arctan2(-r01, r11)
    c = np.arctan2(-r20, r22)
    locked = cos_b < 1e-9 * n
    if locked.any():
        a = np.where(locked, np.arctan2(2.0 * (x * y + w * z), ww + xx - yy - zz), a)
        c = np.where(locked, 0.0, c)
    return a, np.arctan2(2.0 * (y * z + w * x), cos_b), c, cos_b < _LOCK_SIN * n, n


def _in_frames(r: list[np.ndarray], frames: np.ndarray) -> tuple[np.ndarray, ...]:
    """conj(F) * r * F of relative rotations ``r`` (components w, x, y, z, each (..., K)) in the
    joints' model frames ``frames`` (K, 4): ``quat.multiply``'s products, operation for operation
    in float64, without stacking the components; returned in ``r``'s type."""
    aw, ax, ay, az = quat.conjugate(frames).T
    bw, bx, by, bz = (np.asarray(c, np.float64) for c in r)
    mw, mx, my, mz = (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                      aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)
    fw, fx, fy, fz = np.asarray(frames, np.float64).T
    return tuple(c.astype(r[0].dtype) for c in (mw * fw - mx * fx - my * fy - mz * fz, mw * fx + mx * fw + my * fz - mz * fy,
                                               mw * fy - mx * fz + my * fw + mz * fx, mw * fz + mx * fy - my * fx + mz * fw))


def joint_angles(q: np.ndarray, present: np.ndarray | None = None, rest_pose: str = wire.DEFAULT_REST_POSE,
                 calibrated: np.ndarray | bool = True, layout: str | Layout = "paper10") -> tuple[np.ndarray, np.ndarray]:
    """The joint angles of calibrated segment orientations, vectorised over frames and subjects.

    Parameters
    ----------
    q : (..., S, 4) segment orientations in the layout's segment order (``paper10``:
        :data:`wire.SEGMENTS`; anatomical once calibrated: identity in the rest pose, the rest
        pose's forward resolved); float32 is worked in float32 (a pose frame's precision: about
        1e-5 degrees away from lock), any other type in float64.
    present : (S,) or (..., S) bool, the segments that have data (None: every finite one).
    rest_pose : what identity means for ``q``.
    calibrated : bool or (...) bool per leading index (e.g. per subject): False gives no angles
        (NaN, flag UNCALIBRATED).
    layout : the layout of ``q``: a built-in's name, a layout file or a
        :class:`limbstream.body.Layout`; its joints are ``wire.joint_table(layout)``'s.

    Returns
    -------
    angles : (..., A) float64 degrees, in the layout's angle order (:func:`angle_names`;
        ``paper10``: :data:`ANGLES`); NaN where flagged MISSING or UNCALIBRATED.
    flags : (..., A) uint8, :data:`MISSING` | :data:`GIMBAL` | :data:`UNCALIBRATED` bits.
    """
    p = plan(layout)
    q = np.asarray(q)
    q = q if q.dtype == np.float32 else q.astype(np.float64)
    if wire.check_rest_pose(rest_pose) == "tpose":
        q = quat.multiply(q, p.from_tpose).astype(q.dtype)
    j = len(p.table)
    ends = np.take(q, p.ends, axis=-2).reshape(*q.shape[:-2], 2, j, 4)  # the joints' parents, then children
    (pw, cw), (px, cx), (py, cy), (pz, cz) = np.ascontiguousarray(np.moveaxis(ends, (-1, -3), (0, 1)))  # fast to work on
    with np.errstate(invalid="ignore", over="ignore"):  # a segment without data: its joints are flagged below
        # conj(parent) * child, in OpenSim's axes: (w, x, y, z) -> (w, z, y, -x) (conjugated by TO_OPENSIM)
        relative = (pw * cw + px * cx + py * cy + pz * cz, pw * cz - pz * cw - px * cy + py * cx,
                    pw * cy - py * cw + px * cz - pz * cx, px * cw - pw * cx + py * cz - pz * cy)
        if p.frames is not None:  # in the joints' model frames (those not identity: a few)
            for c, turned in zip(relative, _in_frames([c[..., p.framed] for c in relative], p.frames[p.framed])):
                c[..., p.framed] = turned
        a, b, c, near_lock, norm2 = _euler_zxy(*relative)
    joint_missing = ~(np.isfinite(norm2) & (norm2 > 0))  # (..., J): a segment non-finite or zero
    if present is not None:
        present = np.asarray(present, bool)
        joint_missing |= ~(np.take(present, p.parent, axis=-1) & np.take(present, p.child, axis=-1))
    angles = np.take(np.stack([a, b, c], axis=-1).reshape(*a.shape[:-1], 3 * j), p.take, axis=-1) * p.deg
    flags = (np.take(near_lock, p.joint_of, axis=-1) & p.side_angle).astype(np.uint8) * np.uint8(GIMBAL)
    no_number = np.take(joint_missing, p.joint_of, axis=-1)
    flags |= no_number.astype(np.uint8) * np.uint8(MISSING)
    uncalibrated = ~np.asarray(calibrated, bool)
    if uncalibrated.any():
        flags |= np.where(uncalibrated[..., None], np.uint8(UNCALIBRATED), np.uint8(0))
        no_number = no_number | uncalibrated[..., None]
    angles[no_number] = np.nan
    return angles, flags
