"""Offline segmentation: a whole stream through one algorithm (fastSW, SW, CPLR, Swing)."""
from __future__ import annotations

import ctypes
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from limbstream.kernel._lib import (_POINT_DTYPE, LIVE_BOUND, SW_STATE_SIZE, BatchOut, _lib, body_rates,
                                    live_rule, make_settings, to_ticks)


@dataclass(frozen=True)
class Segmentation:
    """Segment points of one stream.

    Attributes
    ----------
    index : (K,) int64 or None
        Sample indices of the segment points, increasing, first and last accepted sample
        included. None for algorithms whose points are not original samples (CPLR, Swing).
    t : (K,) float64
        Timestamps of the points, seconds.
    q : (K, D) float
        Values of the points: the original rows ``q[index]`` bit for bit where ``index`` is set.
    n_samples : int
        Samples in the input stream (m).
    rejected : int
        Input samples the kernel rejected (non-finite values, time not increasing).
    omega : (K, 3) float64 or None
        fastSW: each point's body angular rate, rad/s, the live rule's rate (zero with the rule
        off, for the first point and for the final flush). None for other algorithms.
    known_from : (K,) int64 or None
        fastSW: position of the sample whose update call emitted each point (a receiver knows
        it from that sample's time on); ``n_samples`` for the final flush. A point closed by
        the SSR or max_len rule is known from the sample after it, one closed by the live rule
        from its own. None for other algorithms.
    """

    index: np.ndarray | None
    t: np.ndarray
    q: np.ndarray
    n_samples: int
    rejected: int = 0
    omega: np.ndarray | None = None
    known_from: np.ndarray | None = None

    @property
    def icr(self) -> float:
        """Inverse compression ratio: points sent / samples taken (paper, eq. 1)."""
        return len(self.t) / self.n_samples if self.n_samples else float("nan")


def _as_stream(t, q) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t, dtype=np.float64)
    q = np.asarray(q)
    if q.ndim == 1:
        q = q[:, None]
    if t.ndim != 1 or q.ndim != 2 or len(t) != len(q):
        raise ValueError(f"t must be (m,) and q (m, D); got t {t.shape}, q {q.shape}")
    return t, q


def _run_indexed(kernel: Callable, t, q, threshold, max_len) -> Segmentation:
    """Run an index-returning C batch kernel (SW) and gather the original rows."""
    t, q = _as_stream(t, q)
    settings = make_settings(threshold, max_len, q.shape[1])
    ticks = to_ticks(t)
    y = np.ascontiguousarray(q, dtype=np.float32)
    out = np.empty(max(len(t), 1), np.uint32)
    rejected = ctypes.c_size_t(0)
    k = kernel(ctypes.byref(settings), ticks, y, len(t), out, ctypes.byref(rejected))
    index = out[:k].astype(np.int64)
    return Segmentation(index, t[index], q[index], len(t), int(rejected.value))


def _fastsw(t, q, threshold, max_len, live_bound_deg: float = 0.0) -> Segmentation:
    """fastSW (fastsw.h), with each point's rate and the sample it is known from."""
    t, q = _as_stream(t, q)
    settings = make_settings(threshold, max_len, q.shape[1], live_bound_deg)
    m, dim = len(t), q.shape[1]
    ticks = to_ticks(t)
    y = np.ascontiguousarray(q, dtype=np.float32)
    index = np.empty(max(m, 1), np.uint32)
    call = np.empty(max(m, 1), np.uint32)
    rates = np.zeros((max(m, 1), dim), np.float32)
    out = BatchOut(index.ctypes.data, None, call.ctypes.data, rates.ctypes.data)
    rejected = ctypes.c_size_t(0)
    k = _lib.fastsw_segment(ctypes.byref(settings), ticks, y, m, ctypes.byref(out), ctypes.byref(rejected))
    index = index[:k].astype(np.int64)
    omega = body_rates(y[index], rates[:k]) if live_rule(settings) else np.zeros((k, 3))
    return Segmentation(index, t[index], q[index], m, int(rejected.value), omega, call[:k].astype(np.int64))


def _sw(t, q, threshold, max_len) -> Segmentation:
    if max_len > 1000:
        raise ValueError(f"max_len for algorithm 'sw' is at most 1000 (SW_MAX_LEN), got {max_len}")
    work = ctypes.create_string_buffer(SW_STATE_SIZE)

    def kernel(settings, ticks, y, m, out, rejected):
        return _lib.sw_segment(work, settings, ticks, y, m, out, rejected)

    return _run_indexed(kernel, t, q, threshold, max_len)


def _run_fitted(kernel: Callable, t, q, threshold, max_len) -> Segmentation:
    """Run a point-returning C batch kernel (CPLR, Swing): values are fitted, not original rows.

    A point has the timestamp of the sample it closes a segment at (``t`` is that sample's
    time, exactly) and the value of the segment's line there (float32 precision).
    """
    t, q = _as_stream(t, q)
    settings = make_settings(threshold, max_len, q.shape[1])
    ticks = to_ticks(t)
    y = np.ascontiguousarray(q, dtype=np.float32)
    out = np.zeros(max(len(t), 1), _POINT_DTYPE)
    rejected = ctypes.c_size_t(0)
    k = kernel(ctypes.byref(settings), ticks, y, len(t), out.ctypes.data, ctypes.byref(rejected))
    points = out[:k]
    index = points["index"].astype(np.int64)
    values = points["y"][:, : q.shape[1]].astype(np.float64)
    return Segmentation(None, t[index], values, len(t), int(rejected.value))


def _cplr(t, q, threshold, max_len) -> Segmentation:
    """CPLR (baselines.h): threshold is the SSR bound of the regression line."""
    return _run_fitted(_lib.cplr_segment, t, q, threshold, max_len)


def _swing(t, q, threshold, max_len) -> Segmentation:
    """Swing filter (baselines.h): threshold is the largest absolute deviation per dimension."""
    return _run_fitted(_lib.swing_segment, t, q, threshold, max_len)


ALGORITHMS: dict[str, Callable[..., Segmentation]] = {
    "fastsw": _fastsw, "sw": _sw, "cplr": _cplr, "swing": _swing,
}
"""Segmentation algorithms by name: (t, q, threshold, max_len) -> Segmentation."""


def segment(t, q, threshold: float, max_len: int = 1000, algorithm: str = "fastsw",
            live_bound_deg: float = 0.0) -> Segmentation:
    """Segment one stream offline.

    Parameters
    ----------
    t : (m,) float64
        Sample timestamps, seconds, increasing (samples that are not are rejected).
    q : (m, D) float
        Samples, e.g. scalar-first unit quaternions (D = 4); computed in float32.
    threshold : float
        Threshold TH (>= 0): the SSR bound for fastsw, sw and cplr; the largest absolute
        deviation per dimension for swing.
    max_len : int
        Most samples one segment covers after its first point (paper: 1000).
    algorithm : {"fastsw", "sw", "cplr", "swing"}
        A key of :data:`ALGORITHMS`.
    live_bound_deg : float
        fastSW's live rule: the bound in degrees, 0 (or 180) for off (:data:`LIVE_BOUND`).

    Returns
    -------
    Segmentation
    """
    try:
        run = ALGORITHMS[algorithm]
    except KeyError:
        raise ValueError(f"algorithm must be one of {sorted(ALGORITHMS)}, got {algorithm!r}") from None
    if algorithm == "fastsw":
        return run(t, q, threshold, max_len, live_bound_deg)
    if LIVE_BOUND.check(live_bound_deg) != 0.0:
        raise ValueError(f"live_bound_deg is a rule of algorithm 'fastsw', not {algorithm!r}")
    return run(t, q, threshold, max_len)
