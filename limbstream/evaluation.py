"""Offline evaluation of the segmentation algorithms: the fastSW paper's protocol (Sect. 6, Fig. 4).

Every segment stream of every motion is segmented at each threshold; the streams are rebuilt by
SLERP between their (normalised) segment points and compared with the original samples:

- ``icr``: segment points / samples over all streams (paper, eq. 1);
- ``aad``, ``std``, ``p99``, ``max``: angular deviation (eq. 2) of the reconstruction at every
  original timestamp, pooled over all streams (AAD, eq. 3; Fig. 4 left);
- ``point_aad``, ``point_max``: deviation of the segment points themselves from the original
  samples at their timestamps (Fig. 4 right): zero for fastSW and SW, whose points are samples;
  not for CPLR and the Swing filter, whose points are extrapolated.

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

KEYS: tuple[str, ...] = (
    "algorithm",
    "threshold",
    "icr",
    "aad",
    "std",
    "p99",
    "max",
    "point_aad",
    "point_max",
)
"""Fields of one result row, in output order."""

MEASURES: tuple[str, ...] = KEYS[3:]
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
        self.q = np.concatenate([s.q for s in streams]) if streams else np.zeros((0, 4))
        self.stream_of = np.repeat(np.arange(len(streams)), lengths)
        norm = np.linalg.norm(self.q, axis=1)
        self.valid = np.isfinite(norm) & (norm > 0) & np.isfinite(self.key)
        self.q_unit = np.where(
            self.valid[:, None], self.q / np.where(self.valid, norm, 1.0)[:, None], 0.0
        )
        self.n_samples = int(lengths.sum())


def _stats(dev: np.ndarray) -> tuple[float, float, float, float]:
    """mean, std, p99, max of (n,) degrees; NaN if empty."""
    if dev.size == 0:
        return (math.nan,) * 4
    return float(dev.mean()), float(dev.std()), float(np.percentile(dev, 99)), float(dev.max())


def evaluate_threshold(
    pool: _Pool, algorithm: str, threshold: float, max_len: int = MAX_LEN
) -> dict:
    """Segment every stream of ``pool`` at one threshold and measure the result.

    Returns
    -------
    dict with the fields of :data:`KEYS` (degrees for the angular measures).
    """
    run = kernel.ALGORITHMS[algorithm]
    point_key, point_q, point_dev, owners = [], [], [], []
    n_points = 0
    for j, stream in enumerate(pool.streams):
        if len(stream.t) == 0:
            continue
        seg = run(stream.t, stream.q, threshold, max_len)
        k = len(seg.t)
        if k == 0:  # every sample rejected: nothing to rebuild this stream from
            continue
        n_points += k
        index = seg.index if seg.index is not None else np.searchsorted(stream.t, seg.t)
        point_dev.append(quat.angle_deg(stream.q[index], seg.q))
        q_points = quat.normalize(seg.q)
        key = seg.t - pool.t0[j] + pool.offset[j]
        if k == 1:  # a single point: hold it (zero-length span)
            key, q_points = np.repeat(key, 2), np.repeat(q_points, 2, axis=0)
        point_key.append(key)
        point_q.append(q_points)
        owners.append(j)
    icr = n_points / pool.n_samples if pool.n_samples else math.nan
    row = {"algorithm": algorithm, "threshold": float(threshold), "icr": icr}
    if not point_key:
        return row | dict.fromkeys(MEASURES, math.nan)

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
    }


def evaluate(
    motions: Iterable[Motion] | Sequence[Stream],
    algorithms: Sequence[str] = ALGORITHMS,
    thresholds: Sequence[float] = THRESHOLDS,
    max_len: int = MAX_LEN,
) -> list[dict]:
    """Run the protocol: one row per (algorithm, threshold), in that order.

    Parameters
    ----------
    motions : Motion objects (every segment stream is used) or :class:`Stream` objects.
    algorithms : keys of :data:`limbstream.kernel.ALGORITHMS`.
    thresholds : (T,) thresholds, >= 0, each algorithm's own unit.
    max_len : largest segment length, samples.

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
    pool = _Pool(streams)
    return [evaluate_threshold(pool, a, th, max_len) for a in algorithms for th in thresholds]


def at_icr(
    rows: Sequence[dict], algorithm: str, targets: Sequence[float] = ICR_TARGETS
) -> list[dict]:
    """Measures of one algorithm interpolated at given ICRs (linear in log ICR).

    Rows with equal ICR are averaged first; a target outside the swept ICR range gives NaN.

    Returns
    -------
    list of dict: ``algorithm``, ``icr`` (the target), the :data:`MEASURES` and ``threshold``
    (interpolated in log threshold, NaN where a bracketing threshold is 0).
    """
    own = [
        r for r in rows if r["algorithm"] == algorithm and np.isfinite(r["icr"]) and r["icr"] > 0
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
        values = np.array([r[field] for r in own], np.float64)
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
    rows: Sequence[dict], algorithms: Sequence[str], targets: Sequence[float] = ICR_TARGETS
) -> str:
    """The comparison table (measures at the target ICRs) as aligned text."""
    head = f"{'algorithm':<9} {'ICR':>5} {'AAD':>7} {'p99':>7} {'max':>7} {'pt_AAD':>8} {'pt_max':>8}  {'~TH':>9}"
    lines = [head, "-" * len(head)]
    for a in algorithms:
        for r in at_icr(rows, a, targets):
            lines.append(
                f"{a:<9} {r['icr']:>5.2f} {r['aad']:>7.2f} {r['p99']:>7.2f} {r['max']:>7.2f} "
                f"{r['point_aad']:>8.3f} {r['point_max']:>8.3f}  {r['threshold']:>9.2e}"
            )
    lines.append(
        "(angles in degrees; pt_ = segment points vs. the samples at their timestamps;"
        " ~TH = interpolated threshold)"
    )
    return "\n".join(lines)


def write_json(rows: Sequence[dict], path: str | Path) -> None:
    """All rows as a JSON list of objects with the :data:`KEYS`; NaN becomes null."""
    clean = [
        {k: (None if isinstance(r[k], float) and not math.isfinite(r[k]) else r[k]) for k in KEYS}
        for r in rows
    ]
    Path(path).write_text(json.dumps(clean, indent=1) + "\n")
