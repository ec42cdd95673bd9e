"""Columnar state of every device of an aggregator, so each tick is a few NumPy calls for all
devices instead of a few per device (200 subjects x 10 IMUs in real time).

- :class:`PointStore`: the segment points of every device, one row per device slot.
- :class:`TruthQueue`: truth-tap samples waiting until their reconstruction is final.
- :class:`ErrorRings`: per-device windows of angular errors (exact and live).
"""
from __future__ import annotations

import numpy as np

from limbstream import quat

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


class PointStore:
    """Segment points per device slot: times ``t`` (slots, cap) int64 us, orientations
    ``q`` (slots, cap, 4) float32 and body rates ``w`` (slots, cap, 3) float32 rad/s (zero for a
    point without a rate: held); row ``d`` holds ``n[d]`` points, oldest first."""

    def __init__(self, cap: int = 1024, slots: int = 64):
        self.cap = cap
        self.t = np.zeros((slots, cap), np.int64)
        self.q = np.zeros((slots, cap, 4), np.float32)
        self.w = np.zeros((slots, cap, 3), np.float32)
        self.n = np.zeros(slots, np.int64)
        self.size = 0

    def add_slot(self) -> int:
        """A new empty row; returns its slot."""
        if self.size == len(self.n):
            self._grow(2 * len(self.n))
        self.size += 1
        return self.size - 1

    def _grow(self, slots: int) -> None:
        """``slots`` rows, touching no memory the rows do not use: fresh rows are zero pages the
        OS maps only when written (``np.zeros``), and only the columns in use are copied. (A
        concatenation writes every byte: at 2,000 devices that made this store and the truth
        store resident in full, 216 MiB, whatever was stored.)"""
        used = int(self.n[:self.size].max(initial=0))
        for name in ("t", "q", "w"):
            old = getattr(self, name)
            new = np.zeros((slots, *old.shape[1:]), old.dtype)
            new[:self.size, :used] = old[:self.size, :used]
            setattr(self, name, new)
        self.n = np.concatenate([self.n, np.zeros(slots - len(self.n), np.int64)])

    def reset(self, slot: int) -> None:
        self.n[slot] = 0

    def append(self, slot: int, t_us: int, q, omega=None) -> int:
        """Add a point (times must increase) with its body rate ``omega`` (3,) rad/s (None: held);
        returns how many old points were forgotten to make room."""
        forgotten = 0
        if self.n[slot] == self.cap:  # consumers stalled far behind: forget the oldest half
            forgotten = self.cap // 2
            self.shift(slot, forgotten)
        k = self.n[slot]
        self.t[slot, k] = t_us
        self.q[slot, k] = q
        self.w[slot, k] = 0.0 if omega is None else omega
        self.n[slot] = k + 1
        return forgotten

    def extend(self, slot: int, t_us: np.ndarray, q: np.ndarray) -> int:
        """Add points (times increasing, after the row's newest) in one go; returns how many old
        points were forgotten to make room (the oldest half of the row, as often as needed)."""
        count = len(t_us)
        if count > self.cap:
            t_us, q = t_us[-self.cap:], q[-self.cap:]
            count = self.cap
        forgotten = 0
        while self.n[slot] + count > self.cap:
            drop = max(self.cap // 2, self.n[slot] + count - self.cap)
            drop = min(drop, int(self.n[slot]))
            self.shift(slot, drop)
            forgotten += drop
        k = self.n[slot]
        self.t[slot, k:k + count] = t_us
        self.q[slot, k:k + count] = q
        self.w[slot, k:k + count] = 0.0
        self.n[slot] = k + count
        return forgotten

    def contains(self, slot: int, t_us: int) -> bool:
        """True if row ``slot`` holds a point at ``t_us``."""
        return bool(np.any(self.t[slot, : self.n[slot]] == t_us))

    def insert(self, slot: int, t_us: int, q, omega=None) -> bool:
        """Add an older point (body rate ``omega``, None: held) in time order; False (not stored)
        if the row is full."""
        n = self.n[slot]
        if n == self.cap:
            return False
        k = int(np.searchsorted(self.t[slot, :n], t_us))
        self.t[slot, k + 1: n + 1] = self.t[slot, k:n].copy()
        self.q[slot, k + 1: n + 1] = self.q[slot, k:n].copy()
        self.w[slot, k + 1: n + 1] = self.w[slot, k:n].copy()
        self.t[slot, k] = t_us
        self.q[slot, k] = q
        self.w[slot, k] = 0.0 if omega is None else omega
        self.n[slot] = n + 1
        return True

    def shift(self, slot: int, k: int) -> None:
        """Forget the oldest ``k`` points of a row."""
        n = self.n[slot]
        self.t[slot, : n - k] = self.t[slot, k:n]
        self.q[slot, : n - k] = self.q[slot, k:n]
        self.w[slot, : n - k] = self.w[slot, k:n]
        self.n[slot] = n - k

    def last_t(self) -> np.ndarray:
        """(slots,) time of each row's newest point; int64 min where a row is empty."""
        rows = np.arange(self.size)
        n = self.n[: self.size]
        return np.where(n > 0, self.t[rows, np.maximum(n - 1, 0)], np.iinfo(np.int64).min)

    def first_t(self, slot: int) -> int | None:
        return int(self.t[slot, 0]) if self.n[slot] else None

    def locate(self, slots: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(Q,) index of the last point at or before each query time in its row (-1: none)."""
        if len(slots) == 0:
            return np.zeros(0, np.int64)
        n = self.n[slots]
        width = max(int(n.max()), 1)
        rows = self.t[slots, :width]
        valid = np.arange(width)[None, :] < n[:, None]
        return np.sum((rows <= t_us[:, None]) & valid, axis=1) - 1

    def interpolate(self, slots: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(Q, 4) float64 SLERP reconstruction of row ``slots[i]`` at ``t_us[i]``; held before the
        first and after the last point; identity for an empty row."""
        out = np.tile(IDENTITY, (len(slots), 1))
        have = self.n[slots] > 0
        slots, t_us = slots[have], t_us[have]
        if len(slots) == 0:
            return out
        n = self.n[slots]
        k = np.clip(self.locate(slots, t_us), 0, np.maximum(n - 2, 0))
        k1 = np.minimum(k + 1, n - 1)
        t0, t1 = self.t[slots, k], self.t[slots, k1]
        span = (t1 - t0).astype(np.float64)
        u = np.clip((t_us - t0) / np.where(span > 0, span, 1.0), 0.0, 1.0)
        q0 = self.q[slots, k].astype(np.float64)
        q1 = self.q[slots, k1].astype(np.float64)
        q0 /= np.linalg.norm(q0, axis=1, keepdims=True)
        q1 /= np.linalg.norm(q1, axis=1, keepdims=True)
        out[have] = quat.slerp(q0, q1, u)
        return out

    def predicted(self, slots: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(Q, 4) float64: what a receiver knowing only the points of row ``slots[i]`` at or before
        ``t_us[i]`` shows then: the newest of them extrapolated with its rate
        (:func:`limbstream.quat.predict`, the prediction the device's live rule bounds; rate 0
        holds it); identity for a row without such a point."""
        out = np.tile(IDENTITY, (len(slots), 1))
        k = self.locate(slots, t_us)
        have = k >= 0
        s, j = slots[have], k[have]
        if len(s):
            dt = (t_us[have] - self.t[s, j]) / 1e6
            out[have] = quat.predict(self.q[s, j].astype(np.float64), self.w[s, j].astype(np.float64), dt)
        return out

    def live(self, slots: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(Q, 4) float64 live view of row ``slots[i]`` at ``t_us[i]``: SLERP between points where
        a point at or after the time is known (exact), else :meth:`predicted` from the newest point."""
        n = self.n[slots]
        last = self.t[slots, np.maximum(n - 1, 0)]
        inside = (n > 0) & (t_us <= last)
        out = self.predicted(slots, t_us)
        if inside.any():
            out[inside] = self.interpolate(slots[inside], t_us[inside])
        return out

    def held(self, slots: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(Q, 4) float64: the newest point strictly before each time (first point if none)."""
        k = np.maximum(self.locate(slots, t_us - 1), 0)
        out = self.q[slots, k].astype(np.float64)
        out[self.n[slots] == 0] = IDENTITY
        return out

    def prune(self, keep_from: np.ndarray, min_drop: int = 16) -> None:
        """Forget points before ``keep_from[slot]`` (keeping one before it) where that frees at least
        ``min_drop`` points; ``keep_from`` is (slots,) int64 us."""
        k = self.locate(np.arange(self.size), keep_from[: self.size])
        for slot in np.flatnonzero(k >= min_drop):
            self.shift(int(slot), int(k[slot]))


class TruthQueue:
    """Truth-tap samples of every device waiting for the device's watermark to pass them.

    Each entry carries the slot's generation: a restarted stream bumps it, and entries of the
    old stream are dropped instead of being compared with the new one.
    """

    def __init__(self, limit: int = 2_000_000):
        self.limit = limit
        self.slot = np.zeros(0, np.int64)
        self.gen = np.zeros(0, np.int64)
        self.t = np.zeros(0, np.int64)
        self.q = np.zeros((0, 4), np.float32)
        self._incoming: list[tuple[int, int, np.ndarray, np.ndarray]] = []

    def __len__(self) -> int:
        return len(self.t) + sum(len(b[2]) for b in self._incoming)

    def put(self, slot: int, gen: int, t_us: np.ndarray, q: np.ndarray) -> None:
        self._incoming.append((slot, gen, t_us, q))

    def take_ready(self, watermark: np.ndarray, generation: np.ndarray) -> tuple[np.ndarray, ...]:
        """Remove and return (slot, t_us, q float64) of every sample at or before its slot's
        watermark; drops samples of replaced streams. Also returns (slots, count) overflowed."""
        if self._incoming:
            self.slot = np.concatenate([self.slot] + [np.full(len(b[2]), b[0]) for b in self._incoming])
            self.gen = np.concatenate([self.gen] + [np.full(len(b[2]), b[1]) for b in self._incoming])
            self.t = np.concatenate([self.t] + [b[2] for b in self._incoming])
            self.q = np.concatenate([self.q] + [b[3] for b in self._incoming])
            self._incoming = []
        current = self.gen == generation[self.slot]
        ready = current & (self.t <= watermark[self.slot])
        out = self.slot[ready], self.t[ready], self.q[ready].astype(np.float64)
        keep = current & ~ready
        overflow = np.zeros(0, np.int64)
        if keep.sum() > self.limit:  # oldest entries first in each arrival order
            idx = np.flatnonzero(keep)
            overflow = self.slot[idx[: len(idx) - self.limit]]
            keep[idx[: len(idx) - self.limit]] = False
        self.slot, self.gen, self.t, self.q = self.slot[keep], self.gen[keep], self.t[keep], self.q[keep]
        return (*out, overflow)

    def oldest(self, slots: int) -> np.ndarray:
        """(slots,) time of each slot's oldest waiting sample (int64 max if none)."""
        out = np.full(slots, np.iinfo(np.int64).max)
        if len(self.t):
            np.minimum.at(out, self.slot, self.t)
        for slot, _, t, _ in self._incoming:
            out[slot] = min(out[slot], int(t[0]))
        return out


class ErrorRings:
    """Per-slot ring windows of angular errors in degrees, and totals since the stream began.
    A row holds ``min(count, window)`` values (the first ones until it wraps); rows that never
    held a value stay untouched zero pages (no memory resident for a window nobody fills)."""

    def __init__(self, window: int, slots: int = 64):
        self.window = window
        self.values = np.zeros((slots, window), np.float32)
        self.count = np.zeros(slots, np.int64)
        self.total = np.zeros(slots, np.float64)

    def ensure(self, slots: int) -> None:
        if slots > len(self.count):
            grow = max(slots - len(self.count), len(self.count))
            values = np.zeros((len(self.count) + grow, self.window), np.float32)
            used = np.flatnonzero(self.count > 0)
            values[used] = self.values[used]
            self.values = values
            self.count = np.concatenate([self.count, np.zeros(grow, np.int64)])
            self.total = np.concatenate([self.total, np.zeros(grow)])

    def reset(self, slot: int) -> None:
        self.count[slot] = 0
        self.total[slot] = 0.0

    def add(self, slots: np.ndarray, errors: np.ndarray) -> None:
        """Append errors (E,) of rows slots (E,), in order within each row."""
        if len(slots) == 0:
            return
        order = np.argsort(slots, kind="stable")
        slots, errors = slots[order], errors[order]
        starts = np.flatnonzero(np.r_[True, slots[1:] != slots[:-1]])
        rank = np.arange(len(slots)) - np.repeat(starts, np.diff(np.r_[starts, len(slots)]))
        self.values[slots, (self.count[slots] + rank) % self.window] = errors
        np.add.at(self.count, slots, 1)
        np.add.at(self.total, slots, errors)

    def summary(self, slots: np.ndarray, quantiles: tuple[float, ...] = ()) -> tuple[np.ndarray, ...]:
        """(mean, max, *quantiles) over each row's window, each (slots,), NaN for empty rows; a
        quantile ``p`` (0..1) is the lower order statistic. One sort of the rows that hold values
        gives all of them; empty rows (truth tap or live frames off) cost nothing."""
        n = np.minimum(self.count[slots], self.window)
        out = np.full((2 + len(quantiles), len(slots)), np.nan)
        rows = np.flatnonzero(n > 0)
        if len(rows):
            k, r = n[rows], np.arange(len(rows))
            v = self.values[slots[rows]]
            v[np.arange(self.window) >= k[:, None]] = np.nan  # unused: sorts last
            v.sort(axis=1)
            out[0, rows] = np.nansum(v, axis=1, dtype=np.float64) / k  # (float64: the mean as the aggregator sums it)
            out[1, rows] = v[r, k - 1]
            for i, p in enumerate(quantiles):
                out[2 + i, rows] = v[r, np.floor(p * (k - 1)).astype(np.int64)]
        return tuple(out)
