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
    live = 0.0 < live_bound_deg < 180.0
    cos2 = math.cos(math.radians(live_bound_deg) / 2.0) ** 2
    rows = y.tolist()
    a = prev = int(keep[0])
    points, known, omega = [a], [a], [np.zeros(3)]
    syy = stt = 0.0
    sty = [0.0, 0.0, 0.0, 0.0]
    count = 0
    w = np.zeros(3)

    def view_of(anchor: int, rate: np.ndarray) -> tuple[list, list]:
        """Normalised anchor and its tangent qdot = q (0, rate) / 2 (quat.predict's terms)."""
        base = quat.normalize(y[anchor])
        qdot = 0.5 * quat.multiply(base, np.r_[0.0, rate])
        return base.tolist(), qdot.tolist()

    base, qdot = view_of(a, w)
    for n in keep[1:].tolist():
        ya, yv = rows[a], rows[n]
        yn = [yv[d] - ya[d] for d in range(4)]
        tn = t[n] - t[a]
        nn, tt = sum(v * v for v in yn), tn * tn
        dot = sum(yn[d] * sty[d] for d in range(4))
        if count >= max_len or (tt * syy - 2.0 * tn * dot) + nn * stt > threshold * tt:
            old, a = a, prev
            w = (_through(y, t, a, n) if predictor == "rate" else
                 _through(y, t, a, old) if predictor == "slope" else np.zeros(3)) if live else np.zeros(3)
            points.append(a)
            known.append(n)
            omega.append(w)
            base, qdot = view_of(a, w)
            ya = rows[a]
            yn = [yv[d] - ya[d] for d in range(4)]
            tn = t[n] - t[a]
            nn, tt = sum(v * v for v in yn), tn * tn
            syy = stt = 0.0
            sty = [0.0, 0.0, 0.0, 0.0]
            count = 0
        if live:
            pv = [base[d] + tn * qdot[d] for d in range(4)]
            py = sum(pv[d] * yv[d] for d in range(4))
            if py * py < cos2 * sum(v * v for v in pv) * sum(v * v for v in yv):
                old, a = a, n
                w = (_through(y, t, n, prev) if predictor == "rate" else
                     _through(y, t, n, old) if predictor == "slope" else np.zeros(3))
                points.append(n)
                known.append(n)
                omega.append(w)
                base, qdot = view_of(a, w)
                syy = stt = 0.0
                sty = [0.0, 0.0, 0.0, 0.0]
                count = 0
                prev = n
                continue
        syy += nn
        stt += tt
        sty = [sty[d] + tn * yn[d] for d in range(4)]
        count += 1
        prev = n
    if prev != a:
        points.append(prev)
        known.append(len(t))
        omega.append(np.zeros(3))
    return np.asarray(points, np.int64), np.asarray(known, np.int64), np.asarray(omega, np.float64)


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
