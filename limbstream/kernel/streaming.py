"""Streaming segmentation: fastSW on one live stream (:class:`Segmenter`) or on many at once, one
C call per tick, with the segment point messages encoded in the same call (:class:`SegmenterBank`)."""
from __future__ import annotations

import ctypes
from collections.abc import Callable

import numpy as np

from limbstream import wire
from limbstream.kernel._lib import (_POINT_DTYPE, MAX_DIM, POINT, STATE_SIZE, TICK_HZ, BankWire, Point, Settings,
                                    _lib, body_rates, live_rule, make_settings)

_NEWEST_Y = ctypes.sizeof(Settings) + 8 + ctypes.sizeof(Point) + Point.y.offset
"""Offset of the newest accepted sample's value in a FastswState (settings, next_index, count,
anchor, then ``prev``: fastsw.h)."""


class Segmenter:
    """fastSW on one live stream (one device).

    >>> seg = Segmenter(threshold=1e-2, max_len=25, live_bound_deg=5.0)
    >>> point = seg.update(0.0, [1, 0, 0, 0])   # first sample is a point
    >>> seg.point_omega()                        # its body rate, rad/s (live rule)
    """

    def __init__(self, threshold: float = wire.THRESHOLD.default, max_len: int = int(wire.MAX_LEN.default), dim: int = 4,
                 live_bound_deg: float = wire.LIVE_BOUND_DEG.default):
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
        Settings per stream (default: the device tunables' defaults, limbstream.wire.TUNABLES).
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

    def __init__(self, count: int, threshold=wire.THRESHOLD.default, max_len=wire.MAX_LEN.default, dim: int = 4,
                 live_bound_deg=wire.LIVE_BOUND_DEG.default,
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
        self._point_view = np.frombuffer(memoryview(self._points), dtype=_POINT_DTYPE)
        size = max(count, 1)
        self._live = np.array([int(live_rule(st)) for st in self._settings] or [0], np.uint8)
        if ring >= 1:
            self.stream = np.zeros(size, np.uint16)
            self.seq = np.zeros(size, np.uint32)
            self.base = np.zeros(size, np.int64)
            self.sample = np.full((ring, size), -1, np.int64)
            self.t_us = np.zeros((ring, size), np.int64)
            self._out = np.zeros(size * wire.POINT_SIZE_RATE, np.uint8)
            self._slots = np.zeros(size, np.uint32)
            self._ends = np.zeros(size, np.uint32)
            self._wire: BankWire | None = BankWire(*(a.ctypes.data for a in (self.stream, self.seq, self.base, self.sample,
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
        return self.advance(lambda states, status, points, rates, *_: _lib.fastsw_update_many(
            states, n, ticks, y, status, points, rates), n)

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
        ticks, y, n = self._samples(ticks, y)
        return self.advance_wire(lambda states, *out: _lib.lsw_bank_update(states, n, ticks, y, *out), n)

    def advance(self, call: Callable[..., object], n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance the first n streams with a C call that feeds them (a stage in front of fastSW,
        e.g. :class:`~limbstream.kernel.fusion.ImuBank`'s fusion): ``call(states, status, points,
        rates, wire, out, slots, ends)`` (the last four NULL here). Returns as :meth:`update`."""
        if n > self.count:
            raise ValueError(f"at most {self.count} streams, got {n}")
        call(self._states, self._status, self._points, self._rates_ptr, None, None, None, None)
        self._n = n
        view = self._point_view[:n]
        return self._status[:n], view["index"], view["y"][:, : self.dim]

    def advance_wire(self, call: Callable[..., int], n: int) -> tuple[np.ndarray, bytes, np.ndarray]:
        """:meth:`advance` with the points encoded as wire messages in the call (it returns how
        many). Needs ``ring`` >= 1. Returns as :meth:`update_wire`."""
        if self._wire is None:
            raise ValueError("update_wire needs a bank made with ring >= 1")
        if n > self.count:
            raise ValueError(f"at most {self.count} streams, got {n}")
        k = call(self._states, self._status, self._points, self._rates_ptr, *self._wire_ptrs)
        self._n = n
        end = int(self._ends[k - 1]) if k else 0
        return self._slots[:k].copy(), self._out[:end].tobytes(), self._ends[:k].copy()

    def newest_samples(self, n: int) -> np.ndarray:
        """(n, dim) float32 copy: the newest sample each of streams 0..n-1 accepted (its state's
        ``prev``: what it compresses, e.g. the orientation a fusion stage in front gave it)."""
        rows = np.frombuffer(memoryview(self._states), np.uint8, n * STATE_SIZE).reshape(n, STATE_SIZE)
        return rows[:, _NEWEST_Y:_NEWEST_Y + 4 * self.dim].copy().view(np.float32)

    @property
    def status(self) -> np.ndarray:
        """(n,) uint8 the status of each stream advanced by the last update (a view, valid until
        the next call)."""
        return self._status[: self._n]

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

    def reset(self, k: int) -> None:
        """Start stream k afresh (its settings kept): its next sample is a first point."""
        _lib.fastsw_init(ctypes.addressof(self._states) + k * STATE_SIZE, ctypes.byref(self._settings[k]))

    def flush(self, k: int) -> tuple[int, int, np.ndarray] | None:
        """End stream k: (index, tick, y) of its last point (held: rate 0), or None."""
        point = Point()
        if _lib.fastsw_flush(ctypes.addressof(self._states) + k * STATE_SIZE, ctypes.byref(point)) != POINT:
            return None
        return point.index, point.t, np.array(point.y[: self.dim], np.float32)
