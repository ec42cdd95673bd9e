"""Offline evaluation of the segmentation algorithms: the fastSW paper's protocol (Sect. 6, Fig. 4).

Every segment stream of every motion is segmented at each threshold; the streams are rebuilt by
SLERP between their (normalised) segment points and compared with the original samples:

- ``icr``: segment points / samples over all streams (paper, eq. 1);
- ``aad``, ``std``, ``p99``, ``max``: angular deviation (eq. 2) of the reconstruction at every
  original timestamp, pooled over all streams (AAD, eq. 3; Fig. 4 left);
- ``point_aad``, ``point_max``: deviation of the segment points themselves from the original
  samples at their timestamps (Fig. 4 right): zero for fastSW and SW, whose points are samples;
  not for CPLR and the Swing filter, whose points are extrapolated.
- ``live_aad``, ``live_p99``, ``live_max``: the live error at every sample (docs/evaluation.md,
  "Live mode"): the receiver's view of the sample's time, made from the points it has by then
  (the newest one extrapolated at its rate, :func:`limbstream.quat.predict`), against the
  sample. A point is known from the update call that emitted it (``Segmentation.known_from``):
  one closed by the SSR or max_len rule from the sample after it, one closed by fastSW's live
  rule (``live_bound`` > 0) from its own. ``predictor`` names the points' rates: ``rate`` (the
  live rule's own: through the neighbouring sample), ``slope`` (the closed segment's slope,
  through the point before) or ``hold`` (none). fastSW's live rule with ``rate`` is the C
  kernel; with ``slope`` or ``hold`` it is :func:`simulate_live` (float64).

Thresholds mean different things per algorithm (an SSR bound for fastsw, sw and cplr, a
largest absolute deviation per component for swing), so algorithms are compared at equal ICR:
:func:`at_icr` interpolates each measure at given ICRs.

Command line: ``limbstream eval`` (:mod:`limbstream.cli.evaluate`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from limbstream import kernel, quat
from limbstream.sources import Motion

THRESHOLDS: np.ndarray = np.concatenate([[0.0], np.logspace(-6.0, 3.0, 205)])
"""The paper's sweep: 0 and 205 log-spaced values from 1e-6 to 1e3 (206 thresholds)."""

MAX_LEN = 1000
"""Largest segment length of the paper's protocol, samples."""

ICR_TARGETS: tuple[float, ...] = (0.05, 0.10, 0.25, 0.50)
"""ICRs of the comparison table."""

ALGORITHMS: tuple[str, ...] = ("fastsw", "sw", "cplr", "swing")
"""Algorithms evaluated by default (keys of :data:`limbstream.kernel.ALGORITHMS`)."""

PREDICTORS: tuple[str, ...] = ("rate", "slope", "hold")
"""The rates a receiver extrapolates points with (live error); ``rate`` is fastSW's live rule's."""

KEYS: tuple[str, ...] = (
    "algorithm",
    "threshold",
    "live_bound",
    "predictor",
    "icr",
    "aad",
    "std",
    "p99",
    "max",
    "point_aad",
    "point_max",
    "live_aad",
    "live_p99",
    "live_max",
)
"""Fields of one result row, in output order."""

MEASURES: tuple[str, ...] = KEYS[5:]
"""The angular measures of a row, degrees."""


@dataclass(frozen=True)
class Stream:
    """One segment's orientation stream.

    Attributes
    ----------
    t : (m,) float64 seconds, increasing.
    q : (m, 4) float64 scalar-first quaternions (may hold non-finite rows: those are
        rejected by the kernels and left out of the deviation statistics).
    name : str, "<motion>/<segment>".
    """

    t: np.ndarray
    q: np.ndarray
    name: str


def streams_of(motions: Iterable[Motion]) -> list[Stream]:
    """Every segment stream of every motion (S streams per motion)."""
    out = []
    for motion in motions:
        for s, segment in enumerate(motion.segments):
            out.append(
                Stream(
                    np.asarray(motion.t, np.float64),
                    np.asarray(motion.q[:, s, :], np.float64),
                    f"{motion.name}/{segment}",
                )
            )
    return out


class _Pool:
    """All streams concatenated, for one vectorised reconstruction per (algorithm, threshold).

    Stream j's samples occupy ``start[j]:start[j + 1]``; its time axis is shifted to
    ``t - t[0] + offset[j]`` so that one ``searchsorted`` serves every stream at once.
    """

    def __init__(self, streams: Sequence[Stream]):
        if not streams:
            raise ValueError("no streams to evaluate")
        self.streams = list(streams)
        lengths = np.array([len(s.t) for s in streams])
        self.start = np.concatenate([[0], np.cumsum(lengths)])
        spans = np.array([s.t[-1] - s.t[0] if len(s.t) else 0.0 for s in streams])
        gap = float(np.nanmax(spans)) + 1.0 if len(spans) else 1.0
        self.offset = np.arange(len(streams)) * gap
        self.t0 = np.array([s.t[0] if len(s.t) else 0.0 for s in streams])
        self.key = np.concatenate([s.t - s.t[0] + o for s, o in zip(streams, self.offset)])
        self.t = np.concatenate([s.t for s in streams])
        self.q = np.concatenate([s.q for s in streams]) if streams else np.zeros((0, 4))
        self.stream_of = np.repeat(np.arange(len(streams)), lengths)
        norm = np.linalg.norm(self.q, axis=1)
        self.valid = np.isfinite(norm) & (norm > 0) & np.isfinite(self.key)
        self.q_unit = np.where(
            self.valid[:, None], self.q / np.where(self.valid, norm, 1.0)[:, None], 0.0
        )
        self.n_samples = int(lengths.sum())
        self.accepted = np.zeros(self.n_samples, bool)  # what a kernel accepts (time increasing too)
        for j, s in enumerate(streams):
            self.accepted[self.start[j] + _accepted(s.t, np.asarray(s.q, np.float64))] = True


def _stats(dev: np.ndarray) -> tuple[float, float, float, float]:
    """mean, std, p99, max of (n,) degrees; NaN if empty."""
    if dev.size == 0:
        return (math.nan,) * 4
    return float(dev.mean()), float(dev.std()), float(np.percentile(dev, 99)), float(dev.max())


def _accepted(t: np.ndarray, q: np.ndarray) -> np.ndarray:
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
    t: np.ndarray, q: np.ndarray, threshold: float, max_len: int, live_bound: float, predictor: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """fastSW with its live rule and any predictor, float64 (the C kernel has ``rate`` only).

    The rules of ``limbstream.kernel`` (docs/kernel.md): running sums, the SSR and max_len
    rules close a segment at sample n-1, the live rule at sample n when the receiver's view of n
    (newest point extrapolated by :func:`limbstream.quat.predict`) is more than ``live_bound``
    degrees from it. A new point's rate: ``rate``, through the next sample (SSR/max_len) or the
    one before (live); ``slope``, through the previous point; ``hold``, none. With ``slope`` and
    ``hold`` the view of sample n after a break at n-1 can miss it: then n is a point as well
    (two points known from the same sample). Rejected samples as the kernel's.

    Parameters
    ----------
    t : (m,) seconds; q : (m, 4) quaternions; threshold, max_len: the SSR rules;
    live_bound : degrees, 0 for off; predictor : one of :data:`PREDICTORS`.

    Returns
    -------
    index, known_from : (K,) int64 sample positions (known_from = m for the final flush);
    omega : (K, 3) float64 rad/s.
    """
    t = np.asarray(t, np.float64)
    y = np.asarray(q, np.float64)
    keep = _accepted(t, y)
    if len(keep) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    live = 0.0 < live_bound < 180.0
    cos2 = math.cos(math.radians(live_bound) / 2.0) ** 2
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


def _segment_live(stream: Stream, algorithm: str, threshold: float, max_len: int, live_bound: float,
                  predictor: str | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """One stream: (index, t_points, q_points, known_from, omega) for the row's algorithm,
    threshold, live bound and predictor (None: no rates, omega None)."""
    t, q = stream.t, stream.q
    if live_bound > 0 and predictor != "rate":
        index, known, omega = simulate_live(t, q, threshold, max_len, live_bound, predictor)
        return index, t[index], q[index], known, omega
    if algorithm == "fastsw":
        seg = kernel.segment(t, q, threshold, max_len, live_bound_deg=live_bound)
        index, known = seg.index, seg.known_from
    else:
        seg = kernel.ALGORITHMS[algorithm](t, q, threshold, max_len)
        index = seg.index if seg.index is not None else np.searchsorted(t, seg.t)
        known = np.minimum(index + 1, len(t))
        if len(known):
            known[0] = index[0]
    if predictor is None:
        return index, seg.t, seg.q, known, None
    omega = seg.omega if live_bound > 0 else _plain_rates(t, q, index, known, seg.q, predictor)
    return index, seg.t, seg.q, known, omega


def evaluate_threshold(
    pool: _Pool, algorithm: str, threshold: float, max_len: int = MAX_LEN, live_bound: float = 0.0,
    predictor: str = "rate", live: bool = False,
) -> dict:
    """Segment every stream of ``pool`` at one threshold (and live bound) and measure the result
    (the live error only if ``live``: it costs about as much as the reconstruction; else the
    ``live_*`` fields are NaN).

    Returns
    -------
    dict with the fields of :data:`KEYS` (degrees for the angular measures).
    """
    if live_bound > 0 and algorithm != "fastsw":
        raise ValueError(f"the live rule is fastSW's, not {algorithm!r}'s")
    point_key, point_q, point_dev, owners = [], [], [], []
    live_pos, live_q, live_t, live_omega, live_owner = [], [], [], [], []
    n_points = 0
    for j, stream in enumerate(pool.streams):
        if len(stream.t) == 0:
            continue
        index, seg_t, seg_q, known, omega = _segment_live(stream, algorithm, threshold, max_len,
                                                          live_bound, predictor if live else None)
        k = len(seg_t)
        if k == 0:  # every sample rejected: nothing to rebuild this stream from
            continue
        n_points += k
        if live:
            live_pos.append(pool.start[j] + known)
            live_q.append(quat.normalize(seg_q))
            live_t.append(seg_t)
            live_omega.append(omega)
            live_owner.append(np.full(k, j))
        point_dev.append(quat.angle_deg(stream.q[index], seg_q))
        q_points = quat.normalize(seg_q)
        key = seg_t - pool.t0[j] + pool.offset[j]
        if k == 1:  # a single point: hold it (zero-length span)
            key, q_points = np.repeat(key, 2), np.repeat(q_points, 2, axis=0)
        point_key.append(key)
        point_q.append(q_points)
        owners.append(j)
    icr = n_points / pool.n_samples if pool.n_samples else math.nan
    row = {"algorithm": algorithm, "threshold": float(threshold), "live_bound": float(live_bound),
           "predictor": predictor if live else None, "icr": icr}
    if not point_key:
        return row | dict.fromkeys(MEASURES, math.nan)
    errors = _live_errors(pool, np.concatenate(live_pos), np.concatenate(live_q), np.concatenate(live_t),
                          np.concatenate(live_omega), np.concatenate(live_owner)) if live else np.zeros(0)

    keys = np.concatenate(point_key)
    q_points = np.concatenate(point_q)
    counts = np.array([len(p) for p in point_key])
    have = np.zeros(len(pool.streams), bool)
    first = np.zeros(len(pool.streams), np.int64)
    have[owners] = True
    first[owners] = np.concatenate([[0], np.cumsum(counts)[:-1]])
    last = first.copy()
    last[owners] += counts - 1

    mask = pool.valid & have[pool.stream_of]
    sample_key = pool.key[mask]
    owner = pool.stream_of[mask]
    k = np.searchsorted(keys, sample_key, side="right") - 1
    k = np.clip(k, first[owner], last[owner] - 1)  # stay inside the sample's own stream
    span = keys[k + 1] - keys[k]
    u = np.clip((sample_key - keys[k]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    recon = quat.slerp(q_points[k], q_points[k + 1], u)
    dev = quat.angle_deg(pool.q_unit[mask], recon)
    aad, std, p99, mx = _stats(dev)
    pdev = np.concatenate(point_dev)
    pdev = pdev[np.isfinite(pdev)]
    return row | {
        "aad": aad,
        "std": std,
        "p99": p99,
        "max": mx,
        "point_aad": float(pdev.mean()) if pdev.size else math.nan,
        "point_max": float(pdev.max()) if pdev.size else math.nan,
        "live_aad": float(errors.mean()) if errors.size else math.nan,
        "live_p99": float(np.percentile(errors, 99)) if errors.size else math.nan,
        "live_max": float(errors.max()) if errors.size else math.nan,
    }


def _live_errors(pool: _Pool, known: np.ndarray, q_points: np.ndarray, t_points: np.ndarray,
                 omega: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """Live error (degrees) of every sample of the pool a kernel accepts (finite, time increasing)
    that has a point known by then.

    known : (K,) pooled sample positions from which each point is known, by stream then time;
    q_points (K, 4) unit, t_points (K,) seconds (stream time), omega (K, 3) rad/s, owner (K,).
    """
    position = np.flatnonzero(pool.valid & pool.accepted)
    j = np.searchsorted(known, position, side="right") - 1
    stream = pool.stream_of[position]
    ok = (j >= 0) & (owner[np.maximum(j, 0)] == stream)
    position, j = position[ok], j[ok]
    view = quat.predict(q_points[j], omega[j], pool.t[position] - t_points[j])
    return quat.angle_deg(view, pool.q_unit[position])


def evaluate(
    motions: Iterable[Motion] | Sequence[Stream],
    algorithms: Sequence[str] = ALGORITHMS,
    thresholds: Sequence[float] = THRESHOLDS,
    max_len: int = MAX_LEN,
    live_bounds: Sequence[float] | None = None,
    predictor: str = "rate",
) -> list[dict]:
    """Run the protocol: one row per (algorithm, live bound, threshold), in that order.

    Parameters
    ----------
    motions : Motion objects (every segment stream is used) or :class:`Stream` objects.
    algorithms : keys of :data:`limbstream.kernel.ALGORITHMS`.
    thresholds : (T,) thresholds, >= 0, each algorithm's own unit.
    max_len : largest segment length, samples.
    live_bounds : fastSW live rule bounds, degrees in [0, 180) (0: the plain rules; a bound
        above 0 needs algorithms == ["fastsw"]); None: the plain rules, and no live error
        (the ``live_*`` fields are NaN).
    predictor : the points' rates for the live error, one of :data:`PREDICTORS`.

    Returns
    -------
    list of dict with the fields of :data:`KEYS`; deviations in degrees, pooled over all
    samples of all streams.
    """
    items = list(motions)
    streams = [s for s in items if isinstance(s, Stream)] + streams_of(
        m for m in items if isinstance(m, Motion)
    )
    for name in algorithms:
        if name not in kernel.ALGORITHMS:
            raise ValueError(f"algorithm must be one of {sorted(kernel.ALGORITHMS)}, got {name!r}")
    if predictor not in PREDICTORS:
        raise ValueError(f"predictor must be one of {', '.join(PREDICTORS)}, got {predictor!r}")
    live = live_bounds is not None
    for bound in live_bounds or ():
        if kernel.LIVE_BOUND.check(bound) > 0 and set(algorithms) != {"fastsw"}:
            raise ValueError(f"a live bound needs algorithms ['fastsw'], got {list(algorithms)}")
    pool = _Pool(streams)
    return [evaluate_threshold(pool, a, th, max_len, bound, predictor, live)
            for a in algorithms for bound in (live_bounds or (0.0,)) for th in thresholds]


def at_icr(
    rows: Sequence[dict], algorithm: str, targets: Sequence[float] = ICR_TARGETS,
    live_bound: float | None = None,
) -> list[dict]:
    """Measures of one algorithm (and live bound, unless None) interpolated at given ICRs
    (linear in log ICR).

    Rows with equal ICR are averaged first; a target outside the swept ICR range gives NaN.

    Returns
    -------
    list of dict: ``algorithm``, ``icr`` (the target), the :data:`MEASURES` and ``threshold``
    (interpolated in log threshold, NaN where a bracketing threshold is 0).
    """
    own = [
        r for r in rows if r["algorithm"] == algorithm and np.isfinite(r["icr"]) and r["icr"] > 0
        and (live_bound is None or r.get("live_bound", 0.0) == live_bound)
    ]
    out = []
    if not own:
        return [
            {"algorithm": algorithm, "icr": c, "threshold": math.nan}
            | dict.fromkeys(MEASURES, math.nan)
            for c in targets
        ]
    icr = np.array([r["icr"] for r in own])
    unique, inverse = np.unique(icr, return_inverse=True)
    x = np.log(unique)

    def curve(field: str, log: bool = False) -> np.ndarray:
        values = np.array([r.get(field, math.nan) for r in own], np.float64)
        if log:
            with np.errstate(divide="ignore"):
                values = np.log(values)
        sums = np.bincount(inverse, weights=values, minlength=len(unique))
        return sums / np.bincount(inverse, minlength=len(unique))

    for c in targets:
        row = {"algorithm": algorithm, "icr": float(c)}
        inside = unique[0] <= c <= unique[-1]
        for field in MEASURES:
            row[field] = float(np.interp(np.log(c), x, curve(field))) if inside else math.nan
        th = (
            float(np.exp(np.interp(np.log(c), x, curve("threshold", log=True))))
            if inside
            else math.nan
        )
        row["threshold"] = th
        out.append(row)
    return out


def format_table(
    rows: Sequence[dict], algorithms: Sequence[str], targets: Sequence[float] = ICR_TARGETS,
    live_bounds: Sequence[float] = (0.0,),
) -> str:
    """The comparison table (measures at the target ICRs, per algorithm and live bound) as
    aligned text."""
    head = (f"{'algorithm':<9} {'bound':>5} {'ICR':>5} {'AAD':>7} {'p99':>7} {'max':>7} {'pt_AAD':>8} "
            f"{'pt_max':>8} {'live':>7} {'live99':>7}  {'~TH':>9}")
    lines = [head, "-" * len(head)]
    for a in algorithms:
        for bound in live_bounds:
            for r in at_icr(rows, a, targets, live_bound=bound):
                lines.append(
                    f"{a:<9} {bound:>5g} {r['icr']:>5.2f} {r['aad']:>7.2f} {r['p99']:>7.2f} {r['max']:>7.2f} "
                    f"{r['point_aad']:>8.3f} {r['point_max']:>8.3f} {r['live_aad']:>7.2f} {r['live_p99']:>7.2f}  "
                    f"{r['threshold']:>9.2e}"
                )
    lines.append(
        "(angles in degrees; pt_ = segment points vs. the samples at their timestamps; live = live"
        " error, mean and p99; bound = live rule bound, 0 off; ~TH = interpolated threshold)"
    )
    return "\n".join(lines)


def frontier(rows: Sequence[dict], bound: float | None, tolerance: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """The best exact AAD at each ICR among rows whose live error stays within ``bound`` degrees
    at every sample (``live_max <= bound + tolerance``; None: every row): the rows not beaten by
    another with lower or equal ICR and lower AAD.

    Returns
    -------
    icr, aad : (F,) float64, ICR increasing, AAD decreasing.
    """
    ok = [r for r in rows if np.isfinite(r["icr"]) and np.isfinite(r["aad"])
          and (bound is None or r["live_max"] <= bound + tolerance)]
    ok.sort(key=lambda r: (r["icr"], r["aad"]))
    icr, aad = [], []
    for r in ok:
        if not aad or r["aad"] < aad[-1]:
            icr.append(r["icr"])
            aad.append(r["aad"])
    return np.array(icr), np.array(aad)


def write_json(rows: Sequence[dict], path: str | Path) -> None:
    """All rows as a JSON list of objects with the :data:`KEYS`; NaN becomes null."""
    clean = [
        {k: (None if isinstance(r[k], float) and not math.isfinite(r[k]) else r[k]) for k in KEYS}
        for r in rows
    ]
    Path(path).write_text(json.dumps(clean, indent=1) + "\n")
