"""One small Kalman filter per joint, all of them at once: the joint's heading offset, its rate and
the joint's mean twist.

State per joint ``x = [delta, rate, mean]``:

- ``delta`` (rad): the turn about the vertical that the child segment needs relative to its
  parent (the relative heading drift of the two sensors since calibration, plus anything a
  restart put there);
- ``rate`` (rad/s): its rate, the difference of the two sensors' vertical gyro biases, a random
  walk;
- ``mean`` (rad): what the joint's own measure shows when no correction is needed, a
  near-constant: for a ball joint its mean twist about the vertical (how far its child usually
  turns from the rest pose, e.g. a hip's habitual external rotation), for a hinge the bias that
  its deviations from a perfect hinge leave in the hinge measure.

Measurements are angles, each with its information (1/rad^2): *absolute* ones of ``delta``
(the range of motion, a still joint, the relaxed pose) and *mean-referenced* ones of
``delta - mean`` (the twist a ball joint shows; the hinge measure). Innovations are wrapped to (-pi, pi], and an
innovation beyond :data:`GATE` standard deviations is taken as if it were at the gate, so one
wrong window moves the state a bounded step.
"""
from __future__ import annotations

import numpy as np

GATE = 3.0
"""Innovations beyond this many standard deviations move the state as if they were at it."""

ABSOLUTE = np.array([1.0, 0.0, 0.0])
"""Measurement row of ``delta``."""
MEAN_REFERENCED = np.array([1.0, 0.0, -1.0])
"""Measurement row of ``delta - mean``."""


def wrap(angle: np.ndarray) -> np.ndarray:
    """Angles (rad) wrapped to (-pi, pi]."""
    return -np.remainder(np.pi - np.asarray(angle, np.float64), 2 * np.pi) + np.pi


class JointFilters:
    """The filters of ``shape`` joints (e.g. (subjects, joints)).

    Parameters
    ----------
    shape : leading shape of the state arrays.
    sd0 : (..., 3) initial standard deviations of ``delta`` (rad), ``rate`` (rad/s), ``mean``
        (rad), broadcast to ``shape``.
    walk : (3,) random-walk densities of the three (rad/sqrt(s), rad/s/sqrt(s), rad/sqrt(s)).
    """

    def __init__(self, shape: tuple[int, ...], sd0: np.ndarray, walk: np.ndarray):
        self.sd0 = np.asarray(sd0, np.float64)
        self.walk = np.asarray(walk, np.float64)
        self.x = np.zeros(shape + (3,))
        self.p = np.zeros(shape + (3, 3))
        diagonal = np.arange(3)
        self.p[..., diagonal, diagonal] = self.sd0 ** 2

    def predict(self, dt: float) -> None:
        """Move every state ``dt`` seconds on: ``delta += rate * dt``; uncertainties grow."""
        f = np.array([[1.0, dt, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        self.x = self.x @ f.T
        self.p = f @ self.p @ f.T + np.diag(self.walk ** 2 * dt)

    def update(self, row: np.ndarray, measured: np.ndarray, information: np.ndarray) -> None:
        """Fold in measurements ``measured`` (...) rad of ``row @ x`` (``row`` (3,)) with
        ``information`` (...) 1/rad^2; where it is 0, nothing changes."""
        ok = information > 0
        if not ok.any():
            return
        r = np.where(ok, 1.0 / np.where(ok, information, 1.0), np.inf)
        ph = self.p @ row  # (..., 3)
        s = ph @ row + r
        z = wrap(measured - self.x @ row)
        s = np.maximum(s, z * z / GATE ** 2)  # a gated innovation counts as one at the gate
        gain = np.where(ok[..., None], ph / s[..., None], 0.0)
        self.x = self.x + gain * z[..., None]
        self.p = self.p - gain[..., :, None] * ph[..., None, :]

    def hold(self, mask: np.ndarray, delta: np.ndarray, p: np.ndarray) -> None:
        """Where ``mask`` (...), set ``delta`` (...) rad as measured exactly relative to an
        earlier state whose covariance was ``p`` (..., 3, 3): the uncertainty stays that one."""
        self.x[..., 0] = np.where(mask, delta, self.x[..., 0])
        self.p = np.where(mask[..., None, None], p, self.p)

    def forget(self, mask: np.ndarray, keep_mean: bool = True, delta_sd: float = np.pi) -> None:
        """Start the joints of ``mask`` (...) afresh: ``delta`` 0 with standard deviation
        ``delta_sd`` (rad; by default unknown, half a turn either way), ``rate`` 0 at its initial
        uncertainty; the mean twist is kept unless ``keep_mean`` is False."""
        fresh = np.zeros(self.p.shape)
        diagonal = np.arange(3)
        fresh[..., diagonal, diagonal] = np.stack(np.broadcast_arrays(delta_sd, self.sd0[..., 1], self.sd0[..., 2]),
                                                  -1) ** 2
        p = np.where(mask[..., None, None], fresh, self.p)
        x = np.where(mask[..., None], 0.0, self.x)
        if keep_mean:
            x[..., 2] = self.x[..., 2]
            p[..., 2, 2] = np.where(mask, self.p[..., 2, 2], p[..., 2, 2])
        self.x, self.p = x, p

    def delta_sd(self) -> np.ndarray:
        """(...) the standard deviation of ``delta``, rad."""
        return np.sqrt(np.maximum(self.p[..., 0, 0], 0.0))
