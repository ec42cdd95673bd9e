"""The receiver's live view in the offline evaluation: fastSW's live rule with any predictor
(float64; the C kernel has ``rate`` only) and the rates a receiver gives points made without
it. Times are seconds, rates rad/s."""
from __future__ import annotations

import math
import numpy as np

from limbstream import kernel, quat

__all__ = ["accepted", "segment_live", "simulate_live"]


def accepted(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Positions of the samples a kernel accepts: finite values, time after the last accepted."""
    ok = np.isfinite(q).all(axis=1) & np.isfinite(t)
    keep, last = [], -math.inf
    for i in np.flatnonzero(ok):
        if t[i] > last:
            keep.append(i)
            last = t[i]
    return np.asarray(keep, np.int64)


def _through(y: np.ndarray, t: np.ndarray, p: int, r: int) -> np.ndarray:
    """(3,) body rate carrying sample p through sample r (:func:`limbstream.quat.through_rate`)."""
    return quat.through_rate(y[p], y[r], t[r] - t[p])


def simulate_live(
    t: np.ndarray, q: np.ndarray, threshold: float, max_len: int, live_bound_deg: float, predictor: str | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """fastSW with its live rule and any predictor, float64 (the C kernel has ``rate`` only).

    The rules of ``limbstream.kernel`` (docs/kernel.md): running sums, the SSR and max_len
    rules close a segment at sample n-1, the live rule at sample n when the receiver's view of n
    (newest point extrapolated by :func:`limbstream.quat.predict`) is more than ``live_bound_deg``
    degrees from it. A new point's rate: ``rate``, through the next sample (SSR/max_len) or the
    one before (live); ``slope``, through the previous point; ``hold``, none. With ``slope`` and
    ``hold`` the view of sample n after a break at n-1 can miss it: then n is a point as well
    (two points known from the same sample). Rejected samples as the kernel's.

    Parameters
    ----------
    t : (m,) seconds; q : (m, 4) quaternions; threshold, max_len: the SSR rules;
    live_bound_deg : degrees, 0 for off; predictor : one of :data:`PREDICTORS`.

    Returns
    -------
    index, known_from : (K,) int64 sample positions (known_from = m for the final flush);
    omega : (K, 3) float64 rad/s.
    """
    t = np.asarray(t, np.float64)
    y = np.asarray(q, np.float64)
    keep = accepted(t, y)
    if len(keep) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    run = _LiveRun(t, y, int(keep[0]), 0.0 < live_bound_deg < 180.0, math.cos(math.radians(live_bound_deg) / 2.0) ** 2,
                   predictor)
    for n in keep[1:].tolist():
        run.sample(n, threshold, max_len)
    if run.prev != run.a:
        run.point(run.prev, len(t), np.zeros(3))
    return np.asarray(run.points, np.int64), np.asarray(run.known, np.int64), np.asarray(run.omega, np.float64)


class _LiveRun:
    """The state of :func:`simulate_live` over one stream: the anchor ``a`` (newest point), the
    previous accepted sample, the running sums of the open segment, the receiver's view of the
    anchor (normalised, and its tangent), the points made so far."""

    def __init__(self, t: np.ndarray, y: np.ndarray, first: int, live: bool, cos2: float, predictor: str | None):
        self.t, self.y, self.rows, self.live, self.cos2, self.predictor = t, y, y.tolist(), live, cos2, predictor
        self.a = self.prev = first
        self.points, self.known, self.omega = [first], [first], [np.zeros(3)]
        self.restart()
        self.base, self.qdot = self.view_of(first, np.zeros(3))

    def restart(self) -> None:
        """An empty segment from the anchor."""
        self.syy = self.stt = 0.0
        self.sty = [0.0, 0.0, 0.0, 0.0]
        self.count = 0

    def view_of(self, anchor: int, rate: np.ndarray) -> tuple[list, list]:
        """Normalised anchor and its tangent qdot = q (0, rate) / 2 (quat.predict's terms)."""
        base = quat.normalize(self.y[anchor])
        qdot = 0.5 * quat.multiply(base, np.r_[0.0, rate])
        return base.tolist(), qdot.tolist()

    def rate(self, point: int, ssr_close: int, slope_from: int) -> np.ndarray:
        """A new point's rate: ``rate`` through sample ``ssr_close``, ``slope`` through ``slope_from``, ``hold`` none."""
        if self.predictor == "rate":
            return _through(self.y, self.t, point, ssr_close)
        if self.predictor == "slope":
            return _through(self.y, self.t, point, slope_from)
        return np.zeros(3)

    def point(self, index: int, known: int, rate: np.ndarray) -> None:
        self.points.append(index)
        self.known.append(known)
        self.omega.append(rate)

    def relative(self, n: int, yv: list) -> tuple[list, float, float, float]:
        """Sample n (values ``yv``) relative to the anchor: (yn, tn, |yn|^2, tn^2)."""
        ya = self.rows[self.a]
        yn = [yv[d] - ya[d] for d in range(4)]
        tn = self.t[n] - self.t[self.a]
        return yn, tn, sum(v * v for v in yn), tn * tn

    def sample(self, n: int, threshold: float, max_len: int) -> None:
        """Accepted sample n: the SSR and max_len rules (a point at the previous sample), then the
        live rule (a point at n itself), then n joins the open segment."""
        yv = self.rows[n]
        yn, tn, nn, tt = self.relative(n, yv)
        dot = sum(yn[d] * self.sty[d] for d in range(4))
        if self.count >= max_len or (tt * self.syy - 2.0 * tn * dot) + nn * self.stt > threshold * tt:
            old, self.a = self.a, self.prev
            w = self.rate(self.a, n, old) if self.live else np.zeros(3)
            self.point(self.a, n, w)
            self.base, self.qdot = self.view_of(self.a, w)
            yn, tn, nn, tt = self.relative(n, yv)
            self.restart()
        if self.live:
            pv = [self.base[d] + tn * self.qdot[d] for d in range(4)]
            py = sum(pv[d] * yv[d] for d in range(4))
            if py * py < self.cos2 * sum(v * v for v in pv) * sum(v * v for v in yv):
                old, self.a = self.a, n
                w = self.rate(n, self.prev, old)
                self.point(n, n, w)
                self.base, self.qdot = self.view_of(self.a, w)
                self.restart()
                self.prev = n
                return
        self.syy += nn
        self.stt += tt
        self.sty = [self.sty[d] + tn * yn[d] for d in range(4)]
        self.count += 1
        self.prev = n


def _plain_rates(t: np.ndarray, q: np.ndarray, index: np.ndarray, known: np.ndarray, q_points: np.ndarray,
                 predictor: str) -> np.ndarray:
    """(K, 3) rates a receiver would give points made without the live rule: ``rate``, through
    the sample the point was emitted at (the next one); ``slope``, through the point before;
    ``hold``, none. The first point and a final flush are held."""
    omega = np.zeros((len(index), 3))
    if predictor == "rate":
        inner = (known > index) & (known < len(t))
        nxt = known[inner]
        omega[inner] = quat.through_rate(q_points[inner], q[nxt], t[nxt] - t[index[inner]])
    elif predictor == "slope" and len(index) > 1:
        omega[1:] = quat.through_rate(q_points[1:], q_points[:-1], t[index[:-1]] - t[index[1:]])
        omega[known >= len(t)] = 0.0
    return np.nan_to_num(omega, nan=0.0)


def segment_live(t: np.ndarray, q: np.ndarray, algorithm: str, threshold: float, max_len: int,
                 live_bound_deg: float, predictor: str | None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """One stream (times ``t`` (m,) s, orientations ``q`` (m, 4)) as a receiver gets it: (index,
    t_points, q_points, known_from, omega) for the row's algorithm, threshold, live bound
    (degrees, 0: off) and predictor (None: no rates, omega None). The one entry of the sweep
    (:mod:`.sweep`) into the live model."""
    if live_bound_deg > 0 and predictor != "rate":
        index, known, omega = simulate_live(t, q, threshold, max_len, live_bound_deg, predictor)
        return index, t[index], q[index], known, omega
    if algorithm == "fastsw":
        seg = kernel.segment(t, q, threshold, max_len, live_bound_deg=live_bound_deg)
        assert seg.index is not None and seg.known_from is not None  # (fastSW's points are samples)
        index, known = seg.index, seg.known_from
    else:
        seg = kernel.ALGORITHMS[algorithm](t, q, threshold, max_len)
        index = seg.index if seg.index is not None else np.searchsorted(t, seg.t)
        known = np.minimum(index + 1, len(t))
        if len(known):
            known[0] = index[0]
    if predictor is None:
        return index, seg.t, seg.q, known, None
    rates = seg.omega if live_bound_deg > 0 else _plain_rates(t, q, index, known, seg.q, predictor)
    return index, seg.t, seg.q, known, rates
