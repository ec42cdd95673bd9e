"""Headings that drift as a 6D fusion filter's do: the stand-in for real sensors' heading error.

Without a magnetometer a fusion filter (VQF 6D) keeps inclination from the accelerometer but
integrates the gyro for heading, so each sensor's heading moves with the part of its gyro bias
that lies along the vertical. :class:`DriftModel` draws, per sensor:

- a residual vertical bias ``b0``, uniform +-``bias_dps`` (what the filter's own bias estimate
  leaves: VQF 6D drifts a median 1.7 deg/min on BROAD, i.e. 0.03 deg/s);
- its wander, a random walk of ``walk`` deg/s per sqrt(s) (a MEMS gyro's bias instability and
  temperature);
- an inclination error: a small turn about a horizontal axis, each component of RMS ``tilt_deg``
  and correlation time ``tilt_tau_s``, smooth as a filter's output is (white noise through two
  first-order low-passes: the accelerometer's view of the limb's own acceleration, smoothed by
  the filter).

A sensor then reports ``yaw(h(t)) * tilt(t) * q`` for its segment's orientation ``q``, with
``h(t) = integral of b``: before the strap's mounting and the filter's arbitrary initial heading,
which :mod:`limbstream.calibration` models and removes.

:func:`zero_pose_along_x` makes the other error the correction must not take for drift: a source
whose rest pose is not what it says (its segments' axes are not the anatomical ones).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import lfilter

from limbstream import quat
from limbstream.body import LAYOUTS
from limbstream.calibration import axis_angle, yaw
from limbstream.sources.bvh_rest import shortest_arc

X = np.array([1.0, 0.0, 0.0])


@dataclass(frozen=True)
class Drift:
    """Drawn drift of ``n`` sensors at ``m`` instants: ``heading`` (m, n) rad, ``bias`` (m, n)
    rad/s (the heading's rate), ``tilt`` (m, n, 4) the inclination error (a turn about a
    horizontal axis)."""

    heading: np.ndarray
    bias: np.ndarray
    tilt: np.ndarray

    def apply(self, q: np.ndarray) -> np.ndarray:
        """(m, n, 4) what the sensors read for their segments' orientations ``q`` (m, n, 4)."""
        return quat.multiply(yaw(self.heading), quat.multiply(self.tilt, np.asarray(q, np.float64)))


@dataclass(frozen=True)
class DriftModel:
    """Bounds and rates of the heading drift (see the module). A typical day by default;
    :meth:`bad_day` doubles the bias and its wander."""

    bias_dps: float = 0.1
    walk: float = 2e-4
    tilt_deg: float = 0.5
    tilt_tau_s: float = 2.0
    seed: int = 0

    def __post_init__(self):
        for name in ("bias_dps", "walk", "tilt_deg"):
            if not 0.0 <= getattr(self, name) < 10.0:
                raise ValueError(f"{name} must be in 0..10, got {getattr(self, name)}")
        if not self.tilt_tau_s > 0:
            raise ValueError(f"tilt_tau_s must be > 0, got {self.tilt_tau_s}")

    def bad_day(self) -> DriftModel:
        """The same sensors on a bad day: bias and wander doubled."""
        return replace(self, bias_dps=2 * self.bias_dps, walk=2 * self.walk)

    def draw(self, t: np.ndarray, n: int, stream: int = 0) -> Drift:
        """The drift of ``n`` sensors at times ``t`` (m,) s, uniformly spaced, from ``t[0]`` on
        (seeded by ``seed`` and ``stream``)."""
        t = np.asarray(t, np.float64)
        dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
        rng = np.random.default_rng([self.seed, stream, 0x34])
        b0 = np.radians(self.bias_dps) * rng.uniform(-1.0, 1.0, n)
        steps = np.radians(self.walk) * np.sqrt(dt) * rng.normal(size=(len(t), n))
        steps[0] = 0.0
        bias = b0 + np.cumsum(steps, axis=0)
        heading = np.concatenate([np.zeros((1, n)), np.cumsum(0.5 * (bias[1:] + bias[:-1]) * dt, axis=0)])
        a = np.exp(-dt / self.tilt_tau_s)
        noise = np.radians(self.tilt_deg) * np.sqrt(1 - a * a) * rng.normal(size=(len(t), n, 2))
        noise[0] /= np.sqrt(1 - a * a)  # start in the stationary distribution
        once = lfilter([1.0], [1.0, -a], noise, axis=0)
        xz = lfilter([1.0 - a], [1.0, -a], once, axis=0, zi=a * once[:1])[0]
        xz *= (1.0 + a) / np.sqrt(1.0 + a * a)  # the second pass's loss of variance
        tilt_vec = np.stack([xz[..., 0], np.zeros_like(xz[..., 0]), xz[..., 1]], axis=-1)
        angle = np.linalg.norm(tilt_vec, axis=-1)
        axis = tilt_vec / np.where(angle > 0, angle, 1.0)[..., None]
        return Drift(heading, bias, axis_angle(axis, angle))


def zero_pose_along_x(q: np.ndarray, segments, rest_pose: str) -> np.ndarray:
    """(..., S, 4) the orientations ``q`` (..., S, 4) of ``segments`` (names of the built-in
    layouts' segments) as a BVH file whose zero pose has every bone along +X gives them, read as
    if that zero pose were ``rest_pose``: each segment's ``q * c``, ``c`` the shortest arc that
    turns +X onto its bone's true rest direction (its ``directions[rest_pose]``), so that ``q * c``
    takes the file's bone (+X) where ``q`` takes the true one. A constant error per segment, the
    same a mislabelled rest pose makes (an arm already along +X in a T-pose is left as it is)."""
    directions = {s.name: s.directions[rest_pose] for layout in LAYOUTS.values() for s in layout.segments}
    c = np.array([shortest_arc(X, np.asarray(directions[name], np.float64)) for name in segments])
    return quat.multiply(np.asarray(q, np.float64), c)
