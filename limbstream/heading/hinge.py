"""The hinge constraint (knees, elbows): one axis fixed in both segments.

Calibration makes both segment frames equal in the rest pose, so a hinge's axis ``j`` is the same
vector in both and its relative orientation is ``R = rot(j, flexion)``: ``R j = j``. A heading
error ``e`` of the child turns ``R j`` about the vertical ``g`` (in the parent's frame) by ``e``,
so the angle that turns the horizontal part of ``R j`` back onto that of ``j`` measures it
(Laidig et al., EMBC 2019: the axis seen by both segments must agree).

A real knee or a wrist-mounted forearm sensor is not a perfect hinge: the child also turns a
little about its own bone ``l`` (tibial rotation, pronation), which moves ``R j`` along
``u1 = R (l x j)``, and about the axis across both (varus-valgus, the carrying angle), which moves
it along ``u2 = R j x u1``. A heading error moves it along ``J = g x R j``. Each sample's
information is ``(J.u1)^2 / s1 + (J.u2)^2 / s2``, the spread of those two turns ``s1``, ``s2``: a
straight, upright leg (``J`` along ``u1``) says little, a bent one (``J`` along ``u2``) much
(that is why the heading is observable when the joint flexes).

The axis itself is learnt from the relative orientations, together with the heading error
they still hold (:class:`HingeAxes`).
"""
from __future__ import annotations

import numpy as np

from limbstream import quat

EPS = 1e-12


def measure(r: np.ndarray, g: np.ndarray, axis: np.ndarray, bone: np.ndarray,
            spread: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The heading offset each sample of a hinge shows, and its information.

    Parameters
    ----------
    r : (..., H, 4) relative orientations (parent <- child), uncorrected.
    g : (..., H, 3) the vertical in the parent's frame.
    axis : (..., H, 3) the hinge axes (unit), the same in both frames.
    bone : (H, 3) the child's bone direction in its frame (unit).
    spread : (H, 2) variances (rad^2) of the turn about the bone and across it.

    Returns
    -------
    measured : (...) rad, the turn about ``g`` that puts ``r`` back on its hinge.
    information : (...) 1/rad^2 per sample (0 where the axis is vertical).
    """
    rj = quat.rotate(r, axis)
    jp = axis - np.sum(axis * g, axis=-1, keepdims=True) * g
    rp = rj - np.sum(rj * g, axis=-1, keepdims=True) * g
    measured = np.arctan2(np.sum(g * np.cross(rp, jp), axis=-1), np.sum(rp * jp, axis=-1))
    about = np.cross(bone, axis)
    u1 = quat.rotate(r, about / np.maximum(np.linalg.norm(about, axis=-1, keepdims=True), EPS))
    u2 = np.cross(rj, u1)
    moved = np.cross(g, rj)
    information = (np.sum(moved * u1, axis=-1) ** 2 / spread[:, 0]
                   + np.sum(moved * u2, axis=-1) ** 2 / spread[:, 1])
    return measured, information


OFFSETS = np.radians(np.arange(-6.0, 6.1, 1.5))
"""Heading offsets (rad, evenly spaced) at which :class:`HingeAxes` tries the accumulated orientations."""


def _outer_sum(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the sum over the first axis of the outer products of ``a``, ``b`` (T, ..., 3)."""
    return np.einsum("t...i,t...j->...ij", a, b)


class HingeAxes:
    """The learnt axes of ``shape`` hinges (e.g. (subjects, hinges)), learnt together with the
    heading error left in the orientations they are learnt from.

    The vector part of a hinge's relative orientation is ``v = sin(flexion / 2) j``: the axis is
    the principal direction of ``sum v v^T`` (Seel et al., Sensors 2014, identify it from motion
    too). But a heading error ``e`` left in the orientations would bend it: ``rot(g, e) R`` has
    the vector part ``cos(e/2) v + sin(e/2) d`` with ``d = R_w g + g x v``. So the three sums
    ``A = sum v v^T``, ``B = sum (v d^T + d v^T)``, ``C = sum d d^T`` of the corrected relative
    orientations are kept (over time in s, forgetting with ``memory_s``), which give the scatter
    ``S(e) = c^2 A + c s B + s^2 C`` of any further turn ``e`` exactly; the ``e`` that makes it
    most one-dimensional is the heading error, and its principal direction the axis.

    ``ready`` (0..1) says how far the axis can be trusted: enough flexion seen (``min_amount``,
    in s at 90 deg) and one axis dominating (``min_share`` of the scatter)."""

    def __init__(self, shape: tuple[int, ...], memory_s: float, min_amount: float, min_share: float):
        self.memory_s, self.min_amount, self.min_share = memory_s, min_amount, min_share
        self.sums = np.zeros((3,) + shape + (3, 3))
        self.axis = np.zeros(shape + (3,))
        self.axis[..., 0] = 1.0
        self.ready = np.zeros(shape)
        self.error = np.zeros(shape)

    def add(self, r: np.ndarray, g: np.ndarray, mask: np.ndarray, dt: float) -> None:
        """Accumulate corrected relative orientations ``r`` (T, ..., 4) with the vertical ``g``
        (T, ..., 3) in their parents' frames, where ``mask`` (T, ...), each sample standing for
        ``dt`` s; then forget and find the axes (and the heading error left) again."""
        sign = np.where(r[..., 0] < 0, -1.0, 1.0) * mask
        r = r * sign[..., None]
        v = r[..., 1:]
        d = r[..., :1] * g + np.cross(g, v)
        keep = np.exp(-len(r) * dt / self.memory_s)
        cross = _outer_sum(v, d)
        self.sums = keep * self.sums + dt * np.stack([_outer_sum(v, v), cross + np.swapaxes(cross, -1, -2), _outer_sum(d, d)])
        c, s = np.cos(OFFSETS / 2), np.sin(OFFSETS / 2)
        scatter = (c[:, None, None] ** 2 * self.sums[0][..., None, :, :]
                   + (c * s)[:, None, None] * self.sums[1][..., None, :, :]
                   + s[:, None, None] ** 2 * self.sums[2][..., None, :, :])  # (..., K, 3, 3)
        values = np.linalg.eigvalsh(scatter)
        cost = values[..., 0] + values[..., 1]
        best = np.clip(np.argmin(cost, axis=-1), 1, len(OFFSETS) - 2)
        around = np.take_along_axis(cost, np.stack([best - 1, best, best + 1], -1), -1)
        curve = around[..., 0] - 2 * around[..., 1] + around[..., 2]
        step = np.where(curve > EPS, 0.5 * (around[..., 0] - around[..., 2]) / np.maximum(curve, EPS), 0.0)
        self.error = OFFSETS[best] + np.clip(step, -1.0, 1.0) * (OFFSETS[best + 1] - OFFSETS[best])
        c, s = np.cos(self.error / 2)[..., None, None], np.sin(self.error / 2)[..., None, None]
        values, vectors = np.linalg.eigh(c * c * self.sums[0] + c * s * self.sums[1] + s * s * self.sums[2])
        top = vectors[..., :, 2]
        self.axis = top * np.where(np.sum(top * self.axis, axis=-1, keepdims=True) < 0, -1.0, 1.0)
        amount = values[..., 2] / 0.5  # sin^2(45 deg) = 0.5: seconds at 90 deg of flexion
        share = values[..., 2] / np.maximum(values.sum(axis=-1), EPS)
        self.ready = (np.clip(amount / self.min_amount - 1.0, 0.0, 1.0)
                      * np.clip((share - self.min_share) / (1.0 - self.min_share), 0.0, 1.0))
