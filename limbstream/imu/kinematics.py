"""What ideal IMUs strapped on the segments read: body angular rate and specific force.

A sensor aligned with its segment (the mounting is applied per device, :mod:`.devices`) at its
place on the segment (:data:`PLACES`) reads, at sample instant ``t`` of the sensor rate ``r``:

- **angular rate** (rad/s, segment frame): the mean body rate over the sample interval that ends
  at ``t``, ``log(q(t - 1/r)^-1 q(t)) r`` as a rotation vector. Strapdown integration
  (``q[k] = q[k-1] exp(omega[k] / r)``, as VQF integrates) gives back the orientation stream
  exactly.
- **specific force** (m/s^2, segment frame): ``R^T (a - g)`` with ``a`` the acceleration of the
  sensor's place at ``t`` and ``g`` gravity (``-GRAVITY`` along the world's up): a still sensor
  reads ``+GRAVITY`` on the axis that points up.

The place comes from the skeleton's forward kinematics (:class:`limbstream.skeleton.Skeleton`)
plus the motion's root path where it has one (BVH clips), else a fixed root. Sampled motions are
made twice differentiable by :class:`SmoothMotion`; ``a`` is the second central difference of
the place over :data:`DIFF_H_S` (the interpolant's own second derivative to about 1e-7 m/s^2).

World frame: the motion's (Y up). The filter's earth frame is Z up: :func:`to_earth` turns one into
the other.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from limbstream import quat
from limbstream.body import Body
from limbstream.skeleton import Skeleton
from limbstream.sources import Motion
from limbstream.wire import JOINTS, SEGMENTS

GRAVITY = 9.80665
"""Standard gravity, m/s^2 (the g of datasheets)."""
UP = np.array([0.0, 1.0, 0.0])
"""The world's up axis (the skeleton's Y)."""
DIFF_H_S = 1e-4
"""Step of the central differences that give accelerations, s."""
SMOOTH_HZ = 6.0
"""Cut-off of the zero-lag low-pass applied to sampled motions, Hz (a 2nd-order Butterworth run
forward and backward, the usual filter for human movement data). Motion capture carries
millimetre and sub-degree jitter that a second derivative multiplies by the rate squared (CMU's
hip: angular accelerations of 90 rad/s^2 at 120 Hz unfiltered, limb sensors reading 4-5 g at a
walk); filtered, a walk reads 1.0-1.2 g in the median, as body-worn sensors do."""

PLACES: dict[str, tuple[str, str, float]] = {
    "hip": ("pelvis", "pelvis", 0.0),
    "neck": ("neck_base", "head", 0.5),
    **{f"{side}_{segment}": (f"{side}_{top}", f"{side}_{bottom}", 0.5)
       for side in ("l", "r")
       for segment, top, bottom in (("thigh", "hip", "knee"), ("shank", "knee", "ankle"),
                                    ("upperarm", "shoulder", "elbow"), ("lowerarm", "elbow", "wrist"))},
}
"""Where each segment's sensor sits: (joint, next joint, fraction of the way): halfway down the
limb bones and the neck, on the pelvis for the hip. A motion of another layout (``full``) places
its sensors on its own body likewise (halfway along each bone, the root's on the pelvis)."""


class SmoothMotion:
    """A sampled motion as a twice-differentiable function of time.

    Quaternion components (signs made continuous) and the root path are low-passed with zero lag
    at ``smooth_hz`` (skipped when the motion's rate is not above twice it), then interpolated by
    one cubic spline (continuous second derivatives) and the quaternions normalised. The spline's
    end polynomials extend a little past the samples.

    Parameters
    ----------
    motion : at least 4 samples at a uniform rate.
    smooth_hz : low-pass cut-off, Hz; None: no filtering (the samples are smooth already).
    """

    def __init__(self, motion: Motion, smooth_hz: float | None = SMOOTH_HZ):
        if len(motion.t) < 4:
            raise ValueError(f"motion {motion.name!r}: needs at least 4 samples to differentiate, got {len(motion.t)}")
        # imported here: scipy.signal (with scipy.stats) costs about a second of CPU to import, and
        # every emulator imports this module whether its devices read raw sensors or not
        from scipy.interpolate import CubicSpline
        from scipy.signal import butter, sosfiltfilt
        self.segments, self.rest_pose = motion.segments, motion.rest_pose
        self.source = motion  # its layout and body place the sensors
        n, s = motion.q.shape[:2]
        q = quat.continuous(motion.q).reshape(n, 4 * s)
        values = q if motion.root is None else np.concatenate([q, motion.root], axis=1)
        if smooth_hz is not None and motion.fs > 2.0 * smooth_hz:
            sos = butter(2, smooth_hz, fs=motion.fs, output="sos")
            values = sosfiltfilt(sos, values, axis=0)
        self._spline = CubicSpline(motion.t, values, axis=0)
        self._has_root = motion.root is not None

    def orientations(self, t: np.ndarray) -> np.ndarray:
        """(n, S, 4) unit segment orientations at times ``t`` (n,) s."""
        values = self._spline(np.asarray(t, np.float64))
        q = values[:, : 4 * len(self.segments)].reshape(len(values), len(self.segments), 4)
        return q / np.linalg.norm(q, axis=-1, keepdims=True)

    def root(self, t: np.ndarray) -> np.ndarray | None:
        """(n, 3) root positions at ``t``, m; None: a fixed root."""
        return self._spline(np.asarray(t, np.float64))[:, -3:] if self._has_root else None


@dataclass(frozen=True)
class Readings:
    """Ideal readings of sensors aligned with their segments.

    Attributes
    ----------
    t : (n,) float64 sample instants, s.
    q : (n, S, 4) float64 segment orientations at ``t`` (world frame, Y up): the truth.
    gyr : (n, S, 3) float64 angular rate, rad/s, segment frame.
    acc : (n, S, 3) float64 specific force, m/s^2, segment frame.
    segments : tuple of S str.
    """

    t: np.ndarray
    q: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    segments: tuple[str, ...]


def readings(motion: SmoothMotion, t: np.ndarray, rate: float, skeleton: Skeleton | None = None) -> Readings:
    """Ideal readings of ``motion``'s sensors at the instants ``t`` of a ``rate`` Hz sensor.

    Parameters
    ----------
    motion : the smooth motion.
    t : (n,) sample instants, s (any; each rate is the mean over the interval ``1 / rate`` before).
    rate : sensor rate, Hz.
    skeleton : bone lengths of the forward kinematics (default: :class:`Skeleton`'s).
    """
    t = np.asarray(t, np.float64)
    q = motion.orientations(t)
    before = motion.orientations(t - 1.0 / rate)
    step = quat.to_rotation(quat.multiply(quat.conjugate(before), q)).as_rotvec()
    h = DIFF_H_S
    places = [_places(motion, t + d, skeleton or Skeleton()) for d in (-h, 0.0, h)]
    acceleration = (places[0] - 2.0 * places[1] + places[2]) / (h * h)
    force = quat.rotate(quat.conjugate(q), acceleration + GRAVITY * UP)
    return Readings(t, quat.continuous(q), step * rate, force, motion.segments)


def _places(motion: SmoothMotion, t: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """(n, S, 3) positions of the sensors' places at ``t``, m, world frame."""
    if not set(motion.segments) <= set(SEGMENTS):
        return _layout_places(motion, t)
    q = motion.orientations(t)
    full = np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (len(t), len(SEGMENTS), 1))
    for s, name in enumerate(motion.segments):
        if name in SEGMENTS:
            full[:, SEGMENTS.index(name)] = q[:, s]
    joints = skeleton.positions(full, motion.rest_pose == "tpose", dtype=np.float64)
    places = np.zeros((len(t), len(motion.segments), 3))
    for s, name in enumerate(motion.segments):
        if name in PLACES:
            top, bottom, fraction = PLACES[name]
            a, b = joints[:, JOINTS.index(top)], joints[:, JOINTS.index(bottom)]
            places[:, s] = a + fraction * (b - a)
    root = motion.root(t)
    return places if root is None else places + root[:, None, :]


def _layout_places(motion: SmoothMotion, t: np.ndarray) -> np.ndarray:
    """:func:`_places` of a motion of another layout than the 10-IMU one (``full``, a layout
    file): drawn with its body (the layout's default where it has none); each sensor halfway
    along its segment's bone, the root's on its proximal joint (the pelvis)."""
    layout = motion.source.layout
    body = motion.source.body or Body.default(layout)
    q = motion.orientations(t)
    full = np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (len(t), len(layout.segments), 1))
    index = layout.segment_index
    for s, name in enumerate(motion.segments):
        full[:, index[name]] = q[:, s]
    joints = body.positions(full, motion.rest_pose == "tpose", dtype=np.float64)
    at = layout.joint_index
    places = np.zeros((len(t), len(motion.segments), 3))
    for s, name in enumerate(motion.segments):
        seg = layout.segment(name)
        a = joints[:, at[seg.joint]]
        places[:, s] = a if seg.parent is None else 0.5 * (a + joints[:, at[seg.end]])
    root = motion.root(t)
    return places if root is None else places + root[:, None, :]


def sample_times(start: float, end: float, rate: float) -> np.ndarray:
    """(n,) the instants ``start + k / rate`` up to ``end`` (inclusive within 1e-9 s), s."""
    if not rate > 0:
        raise ValueError(f"sensor rate must be > 0 Hz, got {rate}")
    return start + np.arange(int(np.floor((end - start) * rate + 1e-9)) + 1) / rate


def to_earth(q: np.ndarray) -> np.ndarray:
    """(..., 4) orientations in the world frame (Y up) -> the same in the earth frame (Z up)."""
    return quat.multiply(quat.conjugate(quat.Z_UP_TO_Y_UP), q)
