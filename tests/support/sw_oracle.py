"""Independent reference: the Sliding Window algorithm, brute force in NumPy float64.

Written from the paper's definition, sharing no code with the C kernels: for each new
sample n the segment from the anchor a to n is the straight line through both; if the sum
of squared residuals of the samples a < i < n exceeds the threshold, or the segment would
cover more than max_len samples, sample n-1 becomes a segment point and the new anchor.

The live rule (docs/kernel.md) is written from its definition too, with scipy rotations
(axis and angle) instead of the kernel's linear algebra: :func:`live_sliding_window`,
:func:`live_view`.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def sliding_window(t: np.ndarray, y: np.ndarray, threshold: float, max_len: int = 1000) -> np.ndarray:
    """Segment-point indices (K,) int64 of (t (m,), y (m, D)), first and last sample included."""
    t = np.asarray(t, np.float64)
    y = np.asarray(y, np.float64).reshape(len(t), -1)
    points = [0]
    anchor = 0
    for n in range(1, len(t)):
        if n - 1 - anchor >= max_len:
            split = True
        else:
            t_rel = t[anchor + 1 : n] - t[anchor]
            y_rel = y[anchor + 1 : n] - y[anchor]
            slope = (y[n] - y[anchor]) / (t[n] - t[anchor])
            ssr = np.sum((y_rel - t_rel[:, None] * slope) ** 2)
            split = ssr > threshold
        if split:
            points.append(n - 1)
            anchor = n - 1
    if len(t) and points[-1] != len(t) - 1:
        points.append(len(t) - 1)
    return np.asarray(points, np.int64)


def _through(rot: Rotation, p: int, r: int, t: np.ndarray) -> tuple[np.ndarray, float]:
    """The live rule's rate at point p: the rotation that carries p through sample r.

    Returns (axis (3,), body frame of p, and the rate's magnitude |omega| = 2 tan(phi / 2) / dt,
    rad/s, signed by dt), phi being the angle from p to r and dt = t[r] - t[p].
    """
    step = (rot[p].inv() * rot[r]).as_rotvec()
    phi = np.linalg.norm(step)
    if phi < 1e-12 or phi > np.pi - 1e-9:  # no motion, or half a turn: no finite rate
        return np.zeros(3), 0.0
    return step / phi, 2.0 * np.tan(phi / 2.0) / (t[r] - t[p])


def _predicted(rot: Rotation, a: int, axis: np.ndarray, rate: float, s: float) -> Rotation:
    """Receiver's view s seconds after point a: a turned about axis (body frame) by
    2 arctan(rate s / 2), i.e. the tangent extrapolation q_a + s q_a (0, omega) / 2, normalised."""
    return rot[a] * Rotation.from_rotvec(axis * 2.0 * np.arctan(rate * s / 2.0))


def ssr(t: np.ndarray, y: np.ndarray, a: int, b: int) -> float:
    """Sum of squared residuals of the samples strictly between a and b about the line
    through samples a and b (t (m,) seconds, y (m, D))."""
    t_rel = t[a + 1 : b] - t[a]
    y_rel = y[a + 1 : b] - y[a]
    slope = (y[b] - y[a]) / (t[b] - t[a])
    return float(np.sum((y_rel - t_rel[:, None] * slope) ** 2))


def _ssr_breaks(t: np.ndarray, y: np.ndarray, anchor: int, n: int, threshold: float) -> bool:
    """Whether the segment from anchor to n has an SSR above threshold."""
    return ssr(t, y, anchor, n) > threshold


def live_sliding_window(t: np.ndarray, q: np.ndarray, threshold: float, max_len: int = 1000,
                        live_bound_deg: float = 0.0, predictor: str = "rate",
                        chunk: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Sliding Window with the live rule, brute force in float64 (scipy rotations).

    For each new sample n: if the SSR or max_len rule breaks, sample n-1 becomes a point with
    the rate that carries it through sample n; then, if the receiver's view of n (the newest
    point extrapolated at its rate) is more than live_bound_deg from sample n, sample n becomes
    a point with the rate that carries it back through sample n-1. (With that rate the view of
    n after a break is n itself.) ``predictor`` "slope" carries each new point back through the
    point before instead, "hold" gives it no rate; then a break and a live point can come at the
    same sample. (The views of the samples after an anchor are computed ``chunk`` at a time.)

    Returns
    -------
    points : (K,) int64 segment-point indices, first and last sample included.
    known_from : (K,) int64 the sample from which each point is known (len(t) for the last
        sample added at the end).
    omega : (K, 3) float64 body angular rates, rad/s (zero with the rule off).
    """
    t = np.asarray(t, np.float64)
    y = np.asarray(q, np.float64).reshape(len(t), -1)
    rot = Rotation.from_quat(y[:, [1, 2, 3, 0]])
    live = 0.0 < live_bound_deg < 180.0
    points, known, omega = [0], [0], [np.zeros(3)]
    anchor, axis, rate = 0, np.zeros(3), 0.0
    errors, first = np.zeros(0), 1
    for n in range(1, len(t)):
        if n - 1 - anchor >= max_len or _ssr_breaks(t, y, anchor, n, threshold):
            before, anchor = anchor, n - 1
            axis, rate = (np.zeros(3), 0.0) if not live or predictor == "hold" else \
                _through(rot, anchor, n if predictor == "rate" else before, t)
            points.append(anchor)
            known.append(n)
            omega.append(axis * rate)
            errors = np.zeros(0)
        if not live:
            continue
        if not first <= n < first + len(errors):  # the views of the next samples from this anchor
            first = n
            span = np.arange(n, min(n + chunk, len(t)))
            turn = Rotation.from_rotvec(axis[None] * (2.0 * np.arctan(rate * (t[span] - t[anchor]) / 2.0))[:, None])
            errors = np.degrees(((rot[anchor] * turn).inv() * rot[span]).magnitude())
        if errors[n - first] > live_bound_deg:
            before, anchor = anchor, n
            axis, rate = (np.zeros(3), 0.0) if predictor == "hold" else \
                _through(rot, n, n - 1 if predictor == "rate" else before, t)
            points.append(n)
            known.append(n)
            omega.append(axis * rate)
            errors = np.zeros(0)
    if len(t) and points[-1] != len(t) - 1:
        points.append(len(t) - 1)
        known.append(len(t))
        omega.append(np.zeros(3))
    return np.asarray(points, np.int64), np.asarray(known, np.int64), np.asarray(omega)


def view_error(t: np.ndarray, q: np.ndarray, point: int, omega: np.ndarray, n: int) -> float:
    """Angle in degrees between sample n and the receiver's view of it from segment point
    ``point`` with body rate ``omega`` (rad/s)."""
    t = np.asarray(t, np.float64)
    rot = Rotation.from_quat(np.asarray(q, np.float64)[[point, n]][:, [1, 2, 3, 0]])
    speed = float(np.linalg.norm(omega))
    axis = np.asarray(omega) / speed if speed > 0 else np.zeros(3)
    turn = Rotation.from_rotvec(axis * 2.0 * np.arctan(speed * (t[n] - t[point]) / 2.0))
    return float(np.degrees(((rot[0] * turn).inv() * rot[1]).magnitude()))


def live_view(t: np.ndarray, q: np.ndarray, points: np.ndarray, known_from: np.ndarray,
              omega: np.ndarray) -> np.ndarray:
    """Live error of every sample, degrees: the receiver's view of sample n (the newest point
    known at n, extrapolated at its rate) against sample n."""
    t = np.asarray(t, np.float64)
    rot = Rotation.from_quat(np.asarray(q, np.float64)[:, [1, 2, 3, 0]])
    j = np.searchsorted(known_from, np.arange(len(t)), side="right") - 1
    a = np.asarray(points)[j]
    speed = np.linalg.norm(omega[j], axis=1)
    axis = np.where(speed[:, None] > 0, omega[j] / np.where(speed > 0, speed, 1.0)[:, None], 0.0)
    turn = Rotation.from_rotvec(axis * (2.0 * np.arctan(speed * (t - t[a]) / 2.0))[:, None])
    return np.degrees(((rot[a] * turn).inv() * rot).magnitude())
