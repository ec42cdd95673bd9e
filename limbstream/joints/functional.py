"""The subject's facing from the motion of its hinges: a functional calibration (docs/evaluation.md,
"Joint angles").

A rest calibration alone (one still standing pose, ``Calibration.rest``) cannot tell a sensor's
turn about the vertical from its heading: each segment comes out as ``yaw(h) q yaw(-h)``, the
true orientation ``q`` seen from a world turned by the heading ``h`` of the subject at the rest
pose. When the subject's sensors share one world heading (a magnetometer, 9D fusion: the Xsens
MTw walk), ``h`` is one angle per subject, and its joint angles need it (with ``h`` = 90 degrees
flexion would read as ad/abduction).

A knee or an elbow is nearly a hinge about the lateral axis X: the rotation vectors of its
rotation (thigh -> shank, upper arm -> lower arm) lie along one direction, which after the rest
calibration is ``yaw(h) X`` (knee flexion turns about +X, elbow flexion about -X). So, as in
functional calibrations of the knee axis: the principal axis of those rotation vectors, signed
so that the hinge bends the way its mean bends, gives ``h`` from its horizontal direction. A
hinge counts once it has moved enough (:data:`MIN_RMS_DEG` along its axis, :data:`MIN_HINGE` of
its motion about that axis, the axis within :data:`MAX_TILT_DEG` of horizontal); the facing is
the mean of the counted hinges' headings, weighted by how much each moved.

The statistics are running sums (:class:`HingeStats`), so the same code serves a whole recording
at once and a live subject frame by frame; :meth:`HingeStats.add` takes any leading batch axes
(subjects). Devices of independent headings (6D fusion) need the mounting pose instead.
Recordings of real sensors that start standing still come rest-calibrated from their loader
(``Motion.orientations`` ``rest``, :func:`limbstream.sources.imu_files.to_body`): what
:meth:`HingeStats.add` takes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from limbstream import calibration, quat, wire
from limbstream.joints.convention import standing

MIN_RMS_DEG = 10.0
"""A hinge counts once its RMS rotation along its axis reaches this, degrees."""
MIN_HINGE = 0.8
"""... and this fraction of its rotation's second moment lies along that axis."""
MAX_TILT_DEG = 30.0
"""... and that axis is within this of horizontal (a vertical axis tells no heading), degrees."""
ONE_SIDED = 0.25
"""... and its mean rotation along the axis is at least this fraction of the RMS (which way it
bends is clear)."""


@dataclass(frozen=True)
class Hinge:
    """A nearly-hinge joint: its segments and the sign of its flexion about the lateral axis X."""

    name: str
    parent: str
    child: str
    sign: float


HINGES: tuple[Hinge, ...] = (Hinge("knee_l", "l_thigh", "l_shank", 1.0), Hinge("knee_r", "r_thigh", "r_shank", 1.0),
                             Hinge("elbow_l", "l_upperarm", "l_lowerarm", -1.0),
                             Hinge("elbow_r", "r_upperarm", "r_lowerarm", -1.0))
"""The hinges the facing is found from."""

_SEG = {name: i for i, name in enumerate(wire.SEGMENTS)}
_P = np.array([_SEG[h.parent] for h in HINGES])
_C = np.array([_SEG[h.child] for h in HINGES])
_SIGN = np.array([h.sign for h in HINGES])


@dataclass(frozen=True)
class Facing:
    """What the hinges tell, per subject (leading batch axes ``B``, then H = len(HINGES)).

    Attributes
    ----------
    heading : (*B,) radians, the subject's heading at the rest pose (NaN: no hinge counts yet).
    counted : (*B, H) bool, the hinges it rests on.
    hinge_heading, tilt_deg, rms_deg, hinge_fraction : (*B, H) each hinge's own heading (rad),
        its axis' tilt from horizontal, its RMS rotation along the axis (deg) and the fraction
        of its motion about that axis.
    """

    heading: np.ndarray
    counted: np.ndarray
    hinge_heading: np.ndarray
    tilt_deg: np.ndarray
    rms_deg: np.ndarray
    hinge_fraction: np.ndarray

    @property
    def found(self) -> np.ndarray:
        """(*B,) bool: a facing was found."""
        return np.isfinite(self.heading)

    def describe(self) -> str:
        """One subject's result as a sentence (batch shape ())."""
        parts = [f"{h.name} {'counted' if c else 'not counted'} (moved {r:.0f} deg rms, {100 * f:.0f}% about one "
                 f"axis, tilt {t:.0f} deg)" for h, c, r, f, t in
                 zip(HINGES, self.counted, self.rms_deg, self.hinge_fraction, self.tilt_deg) if np.isfinite(r)]
        if not parts:
            return "no knee or elbow with data on both sides"
        head = (f"facing {math.degrees(float(self.heading)):.1f} deg" if self.found
                else f"no facing yet (a hinge must move >= {MIN_RMS_DEG:g} deg rms about a horizontal axis)")
        return f"{head}: {'; '.join(parts)}"


@dataclass
class HingeStats:
    """Running sums of the hinges' rotation vectors (radians), per subject: ``n`` (*B, H),
    ``total`` (*B, H, 3), ``scatter`` (*B, H, 3, 3)."""

    n: np.ndarray
    total: np.ndarray
    scatter: np.ndarray

    @staticmethod
    def empty(batch: tuple[int, ...] = ()) -> HingeStats:
        h = len(HINGES)
        return HingeStats(np.zeros((*batch, h)), np.zeros((*batch, h, 3)), np.zeros((*batch, h, 3, 3)))

    def add(self, q: np.ndarray, present: np.ndarray | None = None,
            rest_pose: str = wire.DEFAULT_REST_POSE) -> None:
        """Take in rest-calibrated segment orientations ``q`` (*B, m, 10, 4) (SEGMENTS order;
        ``present`` (10,) or (*B, m, 10) bool: the segments with data; non-finite rows are
        skipped)."""
        q = standing(np.asarray(q, np.float64), rest_pose)
        ok = np.isfinite(q).all(axis=-1)
        if present is not None:
            ok &= np.asarray(present, bool)
        use = ok[..., _P] & ok[..., _C]  # (*B, m, H)
        q = np.where(ok[..., None], q, np.array([1.0, 0.0, 0.0, 0.0]))
        relative = quat.multiply(quat.conjugate(q[..., _P, :]), q[..., _C, :])
        v = rotation_vector(relative) * use[..., None]  # (*B, m, H, 3)
        self.n += use.sum(axis=-2)
        self.total += v.sum(axis=-3)
        self.scatter += np.einsum("...mhi,...mhj->...hij", v, v)

    def facing(self, min_frames: int = 1) -> Facing:
        """The facing the sums tell so far; a hinge counts only once it has ``min_frames`` frames
        (live: a few frames of a bent knee are not yet a hinge's motion)."""
        n = np.maximum(self.n, 1.0)[..., None]
        values, vectors = np.linalg.eigh(self.scatter)  # ascending
        axis = vectors[..., :, 2]  # (*B, H, 3) principal direction
        along = np.einsum("...hi,...hi->...h", self.total, axis) / n[..., 0]
        axis = axis * np.where(along < 0, -1.0, 1.0)[..., None] * _SIGN[:, None]  # = yaw(h) X
        rms = np.sqrt(np.maximum(values[..., 2], 0.0) / n[..., 0])
        fraction = values[..., 2] / np.maximum(values.sum(axis=-1), 1e-300)
        tilt = np.degrees(np.arcsin(np.clip(np.abs(axis[..., 1]), 0.0, 1.0)))
        heading = np.arctan2(-axis[..., 2], axis[..., 0])
        counted = ((self.n >= max(min_frames, 1)) & (np.degrees(rms) >= MIN_RMS_DEG) & (fraction >= MIN_HINGE)
                   & (tilt <= MAX_TILT_DEG) & (np.abs(along) >= ONE_SIDED * rms))
        weight = np.where(counted, values[..., 2], 0.0)
        sin, cos = (weight * np.sin(heading)).sum(axis=-1), (weight * np.cos(heading)).sum(axis=-1)
        mean = np.where(counted.any(axis=-1), np.arctan2(sin, cos), np.nan)
        seen = self.n > 0
        return Facing(mean, counted, heading, np.where(seen, tilt, np.nan), np.where(seen, np.degrees(rms), np.nan),
                      np.where(seen, fraction, np.nan))


def rotation_vector(q: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors (radians, angle in [0, pi]) of rotations ``q`` (..., 4)."""
    q = np.asarray(q, np.float64)
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    return q[..., 1:] * np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 2.0)


def face(q: np.ndarray, heading: np.ndarray | float) -> np.ndarray:
    """(..., S, 4) rest-calibrated orientations ``q`` with the heading ``heading`` (...) rad
    undone: ``yaw(-h) q yaw(h)`` (the anatomical frames, :mod:`limbstream.joints.convention`)."""
    y = calibration.yaw(np.asarray(heading, np.float64))[..., None, :]
    return quat.multiply(quat.multiply(quat.conjugate(y), np.asarray(q, np.float64)), y)


def functional_calibration(rest: calibration.Calibration, heading: float) -> calibration.Calibration:
    """A device's rest calibration completed by the facing ``heading`` (rad) the hinges found:
    its corrections then give anatomical frames (as a mounting calibration's do)."""
    if rest.poses[:1] != ("rest",):
        raise calibration.CalibrationError("functional: calibrate the rest pose first")
    s0 = quat.multiply(calibration.yaw(np.array(rest.heading)), rest.mounting)  # the rest reading
    return calibration.Calibration(("rest", "functional"), quat.multiply(calibration.yaw(np.array(-heading)), s0),
                                   float(heading), 0.0, rest.t_ref)
