"""Python binding of the C kernels in ``firmware_c/`` (built into ``limbstream._kernels``).

Offline use: :func:`segment` runs a whole stream through one algorithm.
Streaming use (one device): :class:`Segmenter`. Many devices per tick: :class:`SegmenterBank`,
and their samples' common-time stamps: :class:`Stamper`.

Live rule (fastSW, ``live_bound_deg`` > 0; docs/kernel.md): every segment point carries a body
angular rate ``omega`` (rad/s), and a receiver's live view of time t is
``limbstream.quat.predict(q_point, omega, t - t_point)`` from the newest point it has; the
kernel keeps every sample within ``live_bound_deg`` of that view.

Time: the kernels take ``uint32`` ticks (microseconds here, ``TICK_HZ``); only ratios of
time differences enter the SSR, so the unit does not change the result. Seconds are
converted with :func:`to_ticks`, relative to the first sample, modulo 2**32.
"""
from __future__ import annotations

import ctypes
import importlib.machinery
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Callable

import numpy as np

from limbstream import quat, wire

TICK_HZ = 1_000_000.0
"""Kernel ticks per second used by the bindings (microseconds)."""

NONE, POINT, REJECTED = 0, 1, 2
"""FastswStatus values (fastsw.h)."""


def _load_library() -> ctypes.CDLL:
    here = Path(__file__).resolve().parent
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        candidate = here / f"_kernels{suffix}"
        if candidate.exists():
            return ctypes.CDLL(str(candidate))
    raise ImportError(
        f"limbstream C kernels not built in {here}: run `pip install -e .` in the repository"
    )


_lib = _load_library()
MAX_DIM: int = _lib.fastsw_max_dim()


class Settings(ctypes.Structure):
    """FastswSettings: SSR threshold, max segment length (samples), dimension D, live rule bound
    (degrees; 0 off)."""

    _fields_ = [("threshold", ctypes.c_float), ("max_len", ctypes.c_uint32), ("dim", ctypes.c_uint32),
                ("live_bound_deg", ctypes.c_float)]


class BatchOut(ctypes.Structure):
    """FastswBatchOut (fastsw_batch.h): optional per-point outputs of a batch run."""

    _fields_ = [("index", ctypes.c_void_p), ("points", ctypes.c_void_p), ("call", ctypes.c_void_p),
                ("rates", ctypes.c_void_p)]


class Point(ctypes.Structure):
    """FastswPoint: a segment point (sample index, tick, value)."""

    _fields_ = [("index", ctypes.c_uint32), ("t", ctypes.c_uint32), ("y", ctypes.c_float * MAX_DIM)]


_u32p = np.ctypeslib.ndpointer(np.uint32, flags="C_CONTIGUOUS")
_f32p = np.ctypeslib.ndpointer(np.float32, flags="C_CONTIGUOUS")
_u8p = np.ctypeslib.ndpointer(np.uint8, flags="C_CONTIGUOUS")
_sizep = ctypes.POINTER(ctypes.c_size_t)

_lib.fastsw_state_size.restype = ctypes.c_size_t
_lib.sw_state_size.restype = ctypes.c_size_t
_lib.fastsw_init.argtypes = [ctypes.c_void_p, ctypes.POINTER(Settings)]
_lib.fastsw_init.restype = ctypes.c_int
_lib.fastsw_update.argtypes = [ctypes.c_void_p, ctypes.c_uint32, _f32p, ctypes.POINTER(Point)]
_lib.fastsw_update.restype = ctypes.c_int
_lib.fastsw_flush.argtypes = [ctypes.c_void_p, ctypes.POINTER(Point)]
_lib.fastsw_flush.restype = ctypes.c_int
_lib.fastsw_retune.argtypes = [ctypes.c_void_p, ctypes.POINTER(Settings)]
_lib.fastsw_retune.restype = ctypes.c_int
_lib.fastsw_point_rate.argtypes = [ctypes.c_void_p, _f32p]
_lib.fastsw_point_rate.restype = None
_lib.fastsw_segment.argtypes = [ctypes.POINTER(Settings), _u32p, _f32p, ctypes.c_size_t,
                                ctypes.POINTER(BatchOut), _sizep]
_lib.fastsw_segment.restype = ctypes.c_size_t
_lib.sw_segment.argtypes = [
    ctypes.c_void_p, ctypes.POINTER(Settings), _u32p, _f32p, ctypes.c_size_t, _u32p, _sizep,
]
_lib.sw_segment.restype = ctypes.c_size_t
_lib.fastsw_update_many.argtypes = [
    ctypes.c_void_p, ctypes.c_size_t, _u32p, _f32p, _u8p, ctypes.c_void_p, ctypes.c_void_p,
]
_lib.fastsw_update_many.restype = ctypes.c_size_t


class BankWire(ctypes.Structure):
    """LswBankWire (lsw_bank.h): pointers to the wire fields of a bank's streams."""

    _fields_ = [("stream", ctypes.c_void_p), ("seq", ctypes.c_void_p), ("base", ctypes.c_void_p),
                ("sample", ctypes.c_void_p), ("t_us", ctypes.c_void_p), ("rate", ctypes.c_void_p),
                ("ring", ctypes.c_uint32), ("stride", ctypes.c_uint32)]


_lib.lsw_bank_update.argtypes = [
    ctypes.c_void_p, ctypes.c_size_t, _u32p, _f32p, _u8p, ctypes.c_void_p, ctypes.c_void_p,
    ctypes.POINTER(BankWire), ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
]
_lib.lsw_bank_update.restype = ctypes.c_size_t

_lib.cplr_segment.argtypes = [ctypes.POINTER(Settings), _u32p, _f32p, ctypes.c_size_t, ctypes.c_void_p, _sizep]
_lib.cplr_segment.restype = ctypes.c_size_t
_lib.swing_segment.argtypes = [ctypes.POINTER(Settings), _u32p, _f32p, ctypes.c_size_t, ctypes.c_void_p, _sizep]
_lib.swing_segment.restype = ctypes.c_size_t


class _Sync(ctypes.Structure):
    """LswSync (lsw_clock.h)."""

    _fields_ = [(name, ctypes.c_void_p) for name in ("a", "b", "ref", "c", "c_local", "step", "ever", "stepped")] + [
        ("slew", ctypes.c_double)]


_lib.lsw_stamp.argtypes = [ctypes.POINTER(_Sync), ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
_lib.lsw_stamp.restype = ctypes.c_size_t

STATE_SIZE: int = _lib.fastsw_state_size()
SW_STATE_SIZE: int = _lib.sw_state_size()


class Stamper:
    """Common-time stamps of ``n`` devices' samples with a bounded slew (lsw_clock.h), one C call
    per tick. The caller sets each device's line (``a``, ``b``, ``ref``), ``step`` and ``ever``;
    the stamps keep ``c``, ``c_local`` and ``stepped``.

    Attributes
    ----------
    a, b, ref : (n,) float64 the line: correction ``a + b * (L - ref)`` at device time L (us).
    c, c_local : (n,) float64 correction of each device's last stamp and its device time (NaN: none yet).
    step : (n,) bool the next stamp sets c to the line at once.
    ever : (n,) bool synced once (else a stamp is the device's own time).
    stepped : (n,) bool the device's last stamp was a step.
    """

    def __init__(self, n: int, slew: float):
        self.a, self.b, self.ref, self.c = (np.zeros(n) for _ in range(4))
        self.c_local = np.full(n, np.nan)
        self.step, self.ever, self.stepped = (np.zeros(n, bool) for _ in range(3))
        arrays = (self.a, self.b, self.ref, self.c, self.c_local, self.step, self.ever, self.stepped)
        self._sync = ctypes.pointer(_Sync(*(x.ctypes.data for x in arrays), slew))
        # the call's arguments, in buffers whose addresses are taken once (numpy's .ctypes costs
        # tens of microseconds per tick when the tick loop wakes with cold caches)
        self._slots, self._local, self._out = np.zeros(n, np.int64), np.zeros(n), np.zeros(n)
        self._ptrs = tuple(x.ctypes.data for x in (self._slots, self._local, self._out))

    def stamp(self, slots: np.ndarray, local_us: np.ndarray) -> tuple[np.ndarray, int]:
        """Stamps of samples taken at device times ``local_us`` (K,) float64 us by devices ``slots``
        (K,) (each once, its times increasing over calls): (K,) float64 us (a view, valid until
        the next call), and how many of them were steps (``stepped`` tells which)."""
        k = len(slots)
        self._slots[:k] = slots
        self._local[:k] = local_us
        steps = _lib.lsw_stamp(self._sync, k, *self._ptrs)
        return self._out[:k], int(steps)


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


def to_ticks(t: np.ndarray, t0: float | None = None) -> np.ndarray:
    """Seconds -> uint32 kernel ticks relative to ``t0`` (default: ``t[0]``), modulo 2**32.

    Parameters
    ----------
    t : (m,) float64, seconds.
    """
    t = np.asarray(t, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0, np.uint32)
    origin = t[0] if t0 is None else t0
    ticks = np.round((t - origin) * TICK_HZ)
    ticks = np.where(np.isfinite(ticks), ticks, 0.0)
    return (ticks.astype(np.int64) & 0xFFFFFFFF).astype(np.uint32)


LIVE_BOUND = wire.LIVE_BOUND_DEG
"""The live rule's bound as the binding accepts it (0 and 180: off): the device tunable."""


def make_settings(threshold: float, max_len: int, dim: int, live_bound_deg: float = 0.0) -> Settings:
    """Validated :class:`Settings`; raises ValueError naming the bad argument. The bounds of
    threshold and max_len are the device tunables' (limbstream.wire.TUNABLES), those of
    live_bound_deg :data:`LIVE_BOUND`'s; the live rule needs dim 4 (quaternions)."""
    if not 1 <= dim <= MAX_DIM:
        raise ValueError(f"dim must be in 1..{MAX_DIM}, got {dim}")
    live = LIVE_BOUND.check(live_bound_deg)
    if 0.0 < live < 180.0 and dim != 4:
        raise ValueError(f"live_bound_deg needs quaternion samples (dim 4), got dim {dim}")
    return Settings(wire.THRESHOLD.check(threshold), wire.MAX_LEN.check(max_len), int(dim), live)


def live_rule(settings: Settings) -> bool:
    """Whether the kernel runs the live rule with these settings (bound in (0, 180) as float32)."""
    return 0.0 < settings.live_bound_deg < 180.0


def body_rates(y: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Kernel rates (value units per tick, tangent to their points) -> body angular rates.

    Parameters
    ----------
    y : (K, 4) float, the points; rates : (K, 4) float, their rates per tick.

    Returns
    -------
    (K, 3) float64, rad/s: ``2 vec(conj(y) v) TICK_HZ`` (:func:`limbstream.quat.body_rate`).
    """
    return quat.body_rate(y, np.asarray(rates, np.float64) * TICK_HZ)


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


_POINT_DTYPE = np.dtype(
    {"names": ["index", "t", "y"], "formats": [np.uint32, np.uint32, (np.float32, MAX_DIM)],
     "offsets": [0, 4, 8], "itemsize": ctypes.sizeof(Point)}
)
"""numpy layout of :class:`Point` (FastswPoint)."""


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
    """CPLR (cplr.h): threshold is the SSR bound of the regression line."""
    return _run_fitted(_lib.cplr_segment, t, q, threshold, max_len)


def _swing(t, q, threshold, max_len) -> Segmentation:
    """Swing filter (swing.h): threshold is the largest absolute deviation per dimension."""
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


class Segmenter:
    """fastSW on one live stream (one device).

    >>> seg = Segmenter(threshold=1e-2, max_len=25, live_bound_deg=5.0)
    >>> point = seg.update(0.0, [1, 0, 0, 0])   # first sample is a point
    >>> seg.point_omega()                        # its body rate, rad/s (live rule)
    """

    def __init__(self, threshold: float = 1e-2, max_len: int = 1000, dim: int = 4, live_bound_deg: float = 0.0):
        self.dim = dim
        self._settings = make_settings(threshold, max_len, dim, live_bound_deg)
        self._state = ctypes.create_string_buffer(STATE_SIZE)
        self._point = Point()
        self._rate = np.zeros(MAX_DIM, np.float32)
        self._t0: float | None = None
        _lib.fastsw_init(self._state, ctypes.byref(self._settings))

    def _emit(self, status: int) -> tuple[int, float, np.ndarray] | None:
        if status != POINT:
            return None
        p = self._point
        return p.index, p.t / TICK_HZ + (self._t0 or 0.0), np.array(p.y[: self.dim], np.float32)

    def update(self, t: float, y) -> tuple[int, float, np.ndarray] | None:
        """Feed one sample (t seconds, y (D,)); return (index, t, y float32) of a new point or None."""
        if self._t0 is None:
            self._t0 = float(t)
        tick = int(round((float(t) - self._t0) * TICK_HZ)) & 0xFFFFFFFF
        y = np.ascontiguousarray(y, dtype=np.float32).reshape(self.dim)
        return self._emit(_lib.fastsw_update(self._state, tick, y, ctypes.byref(self._point)))

    def flush(self) -> tuple[int, float, np.ndarray] | None:
        """End of stream: the last sample as a point, unless it already is one."""
        return self._emit(_lib.fastsw_flush(self._state, ctypes.byref(self._point)))

    def point_omega(self) -> np.ndarray:
        """(3,) float64 body angular rate (rad/s) of the newest point: what a receiver
        extrapolates it with (zero with the live rule off)."""
        _lib.fastsw_point_rate(self._state, self._rate)
        y = np.array(self._point.y[:4], np.float32)
        return body_rates(y[None], self._rate[None, :4])[0] if self.dim == 4 else np.zeros(3)

    def retune(self, threshold: float, max_len: int, live_bound_deg: float | None = None) -> None:
        """Change threshold, max segment length and (unless None) the live bound from the next
        sample on."""
        if live_bound_deg is None:
            live_bound_deg = self._settings.live_bound_deg
        self._settings = make_settings(threshold, max_len, self.dim, live_bound_deg)
        _lib.fastsw_retune(self._state, ctypes.byref(self._settings))


class SegmenterBank:
    """fastSW states of many streams in one buffer, advanced together one tick at a time.

    One C call per tick for all streams (a device emulator's inner loop).

    Parameters
    ----------
    count : int
        Number of streams.
    threshold, max_len, live_bound_deg : scalar or (count,)
        Settings per stream.
    dim : int
        Sample dimension, shared.
    ring : int
        With ring >= 1, :meth:`update_wire` encodes the points as segment point messages
        (docs/protocol.md) in the same C call; the caller keeps their wire fields in these arrays
        (written in place, never rebound):

        - ``stream`` (count,) uint16: each stream's id;
        - ``seq`` (count,) uint32: the sequence number of its next message (advanced per point);
        - ``base`` (count,) int64: the sample number of its sample 0;
        - ``sample`` (ring, count) int64: the sample number each stream took at update call c,
          in row c % ring (the kernel's point index counts update calls);
        - ``t_us`` (ring, count) int64: that sample's device time, microseconds since the epoch.
    """

    def __init__(self, count: int, threshold=1e-2, max_len=1000, dim: int = 4, live_bound_deg=0.0,
                 ring: int = 0):
        self.count, self.dim = count, dim
        self._states = ctypes.create_string_buffer(STATE_SIZE * max(count, 1))
        self._points = (Point * max(count, 1))()
        self._status = np.zeros(max(count, 1), np.uint8)
        self._rates = np.zeros((max(count, 1), dim), np.float32)
        self._rates_ptr = self._rates.ctypes.data
        self._n = count  # streams advanced by the last update
        thresholds = np.broadcast_to(np.asarray(threshold, np.float64), (count,))
        max_lens = np.broadcast_to(np.asarray(max_len, np.int64), (count,))
        bounds = np.broadcast_to(np.asarray(live_bound_deg, dtype=object), (count,))
        self._settings = [make_settings(thresholds[k], max_lens[k], dim, bounds[k]) for k in range(count)]
        base = ctypes.addressof(self._states)
        for k, settings in enumerate(self._settings):
            _lib.fastsw_init(base + k * STATE_SIZE, ctypes.byref(settings))
        self._point_view = np.frombuffer(self._points, dtype=_POINT_DTYPE)
        size = max(count, 1)
        self._live = np.array([live_rule(st) for st in self._settings] or [0], np.uint8)
        if ring >= 1:
            self.stream = np.zeros(size, np.uint16)
            self.seq = np.zeros(size, np.uint32)
            self.base = np.zeros(size, np.int64)
            self.sample = np.full((ring, size), -1, np.int64)
            self.t_us = np.zeros((ring, size), np.int64)
            self._out = np.zeros(size * wire.POINT_SIZE_RATE, np.uint8)
            self._slots = np.zeros(size, np.uint32)
            self._ends = np.zeros(size, np.uint32)
            self._wire = BankWire(*(a.ctypes.data for a in (self.stream, self.seq, self.base, self.sample,
                                                             self.t_us, self._live)), ring, size)
            # addresses taken once (numpy's .ctypes costs tens of microseconds per call when the
            # tick loop wakes with cold caches)
            self._wire_ptrs = (ctypes.pointer(self._wire), *(a.ctypes.data for a in (self._out, self._slots, self._ends)))
        else:
            self._wire = None

    def _samples(self, ticks: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """``ticks`` and ``y`` as the C calls take them, checked against the bank; and n."""
        ticks = np.ascontiguousarray(ticks, np.uint32)
        y = np.ascontiguousarray(y, np.float32)
        n = len(ticks)
        if n > self.count or y.shape != (n, self.dim):
            raise ValueError(f"ticks (n,) and y (n, {self.dim}) with n <= {self.count}; got {ticks.shape}, {y.shape}")
        return ticks, y, n

    def update(self, ticks: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance the first n streams by one sample (n = len(ticks) <= count; the others,
        e.g. streams that have ended, are left as they are).

        Parameters
        ----------
        ticks : (n,) uint32, kernel ticks (microseconds).
        y : (n, D) float32 samples.

        Returns
        -------
        status : (n,) uint8 view (NONE, POINT, REJECTED); valid until the next call.
        index : (n,) uint32 sample index of each stream's point (where status == POINT).
        y : (n, D) float32 value of each stream's point (where status == POINT).
        """
        ticks, y, n = self._samples(ticks, y)
        _lib.fastsw_update_many(self._states, n, ticks, y, self._status, self._points, self._rates_ptr)
        self._n = n
        view = self._point_view[:n]
        return self._status[:n], view["index"], view["y"][:, : self.dim]

    def update_wire(self, ticks: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, bytes, np.ndarray]:
        """:meth:`update`, and every point emitted as its segment point message (flags 0), encoded
        by the C encoder in the same call (lsw_bank.h): version 2 with its body rate where the
        stream's live rule is on, else version 1; each stream's ``seq`` advances by one per point.
        Needs ``ring`` >= 1. Parameters as :meth:`update`.

        Returns
        -------
        slots : (K,) uint32 the streams that emitted a point, increasing.
        payload : bytes, the K messages back to back.
        ends : (K,) uint32 offset in payload just after each message
            (message i is ``payload[ends[i - 1]:ends[i]]``, from 0 for i = 0).
        """
        if self._wire is None:
            raise ValueError("update_wire needs a bank made with ring >= 1")
        ticks, y, n = self._samples(ticks, y)
        k = _lib.lsw_bank_update(self._states, n, ticks, y, self._status, self._points, self._rates_ptr,
                                 *self._wire_ptrs)
        self._n = n
        end = int(self._ends[k - 1]) if k else 0
        return self._slots[:k].copy(), self._out[:end].tobytes(), self._ends[:k].copy()

    def live(self, k: int) -> bool:
        """Whether stream k runs the live rule (its points then carry a rate: version 2)."""
        return bool(self._live[k])

    def points_t(self) -> np.ndarray:
        """(n,) uint32 ticks of the points returned by the last :meth:`update`."""
        return self._point_view[: self._n]["t"]

    def points_omega(self) -> np.ndarray:
        """(n, 3) float64 body angular rates (rad/s) of the points returned by the last
        :meth:`update`, where status == POINT (zero elsewhere, and with the live rule off)."""
        n = self._n
        omega = np.zeros((n, 3))
        rows = np.flatnonzero(self._status[:n] == POINT)
        if self.dim == 4 and len(rows):
            omega[rows] = body_rates(self._point_view["y"][rows, :4], self._rates[rows])
        return omega

    def retune(self, k: int, threshold: float, max_len: int, live_bound_deg: float | None = None) -> None:
        """Change one stream's threshold, max_len and (unless None) live bound from its next sample on."""
        if live_bound_deg is None:
            live_bound_deg = self._settings[k].live_bound_deg
        self._settings[k] = make_settings(threshold, max_len, self.dim, live_bound_deg)
        self._live[k] = live_rule(self._settings[k])
        _lib.fastsw_retune(ctypes.addressof(self._states) + k * STATE_SIZE, ctypes.byref(self._settings[k]))

    def flush(self, k: int) -> tuple[int, int, np.ndarray] | None:
        """End stream k: (index, tick, y) of its last point (held: rate 0), or None."""
        point = Point()
        if _lib.fastsw_flush(ctypes.addressof(self._states) + k * STATE_SIZE, ctypes.byref(point)) != POINT:
            return None
        return point.index, point.t, np.array(point.y[: self.dim], np.float32)
