"""Columnar state of every device of an aggregator, so each tick is a few NumPy calls for all
devices instead of a few per device (200 subjects x 10 IMUs in real time).

- :class:`PointStore`: the segment points of every device, one row per device slot.
- :class:`TruthQueue`: truth-tap samples waiting until their reconstruction is final.

(The windows of figures per device: :mod:`.rings`.)
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

    def append_many(self, slots: np.ndarray, t_us: np.ndarray, q: np.ndarray, w: np.ndarray) -> dict[int, int]:
        """Add the points of many rows at once, as :meth:`append` one by one in the given order:
        rows ``slots`` (P,), times (P,) increasing within a row and after its newest point,
        orientations ``q`` (P, 4) and body rates ``w`` (P, 3) rad/s. Returns {slot: points
        forgotten to make room} of the rows that had to forget some."""
        order = np.argsort(slots, kind="stable")
        s = slots[order]
        starts = np.flatnonzero(np.r_[True, s[1:] != s[:-1]])
        counts = np.diff(np.r_[starts, len(s)])
        rows = s[starts]
        full = self.n[rows] + counts > self.cap
        forgotten = {}
        for slot in rows[full]:  # consumers stalled: these rows forget points on the way, one by one
            mine = np.flatnonzero(slots == slot)
            forgotten[int(slot)] = sum(self.append(slot, t_us[i], q[i], w[i]) for i in mine)
        if full.any():
            keep = ~np.isin(s, rows[full])
            order, s = order[keep], s[keep]
            rows, counts = rows[~full], counts[~full]
        position = self.n[s] + np.arange(len(s)) - np.repeat(np.cumsum(counts) - counts, counts)
        self.t[s, position] = t_us[order]
        self.q[s, position] = q[order]
        self.w[s, position] = w[order]
        self.n[rows] += counts
        return {slot: n for slot, n in forgotten.items() if n}

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
        """(Q,) index of the last point at or before each query time in its row (-1: none); a
        binary search of all rows at once."""
        n = self.n[slots]
        lo, hi = np.zeros(len(slots), np.int64), n.copy()
        flat, base = self.t.reshape(-1), slots * self.cap
        for _ in range(int(n.max(initial=0)).bit_length()):
            mid = (lo + hi) >> 1
            go = (mid < hi) & (flat[base + np.minimum(mid, self.cap - 1)] <= t_us)
            lo = np.where(go, mid + 1, lo)
            hi = np.where(go, hi, mid)
        return lo - 1

    def interpolate(self, slots: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(Q, 4) float64 SLERP reconstruction of row ``slots[i]`` at ``t_us[i]``; held before the
        first and after the last point; identity for an empty row."""
        out = np.tile(IDENTITY, (len(slots), 1))
        have = self.n[slots] > 0
        if have.any():
            out[have] = self._slerp(slots[have], t_us[have], self.locate(slots[have], t_us[have]))
        return out

    def _slerp(self, slots: np.ndarray, t_us: np.ndarray, k: np.ndarray) -> np.ndarray:
        """SLERP between the points around each time of non-empty rows (``k``: :meth:`locate`)."""
        n = self.n[slots]
        k = np.clip(k, 0, np.maximum(n - 2, 0))
        k1 = np.minimum(k + 1, n - 1)
        t0, t1 = self.t[slots, k], self.t[slots, k1]
        span = (t1 - t0).astype(np.float64)
        u = np.clip((t_us - t0) / np.where(span > 0, span, 1.0), 0.0, 1.0)
        q0 = self.q[slots, k].astype(np.float64)
        q1 = self.q[slots, k1].astype(np.float64)
        q0 /= np.linalg.norm(q0, axis=1, keepdims=True)
        q1 /= np.linalg.norm(q1, axis=1, keepdims=True)
        return quat.slerp(q0, q1, u)

    def _predict(self, slots: np.ndarray, t_us: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Point ``k`` of each row extrapolated with its rate to each time (quat.predict)."""
        dt = (t_us - self.t[slots, k]) / 1e6
        return quat.predict(self.q[slots, k].astype(np.float64), self.w[slots, k].astype(np.float64), dt)

    def predicted(self, slots: np.ndarray, t_us: np.ndarray, k: np.ndarray | None = None) -> np.ndarray:
        """(Q, 4) float64: what a receiver knowing only the points of row ``slots[i]`` at or before
        ``t_us[i]`` shows then: the newest of them extrapolated with its rate
        (:func:`limbstream.quat.predict`, the prediction the device's live rule bounds; rate 0
        holds it); identity for a row without such a point. ``k``: :meth:`locate`, if known."""
        out = np.tile(IDENTITY, (len(slots), 1))
        k = self.locate(slots, t_us) if k is None else k
        have = k >= 0
        if have.any():
            out[have] = self._predict(slots[have], t_us[have], k[have])
        return out

    def exact_and_predicted(self, slots: np.ndarray, t_us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`interpolate`, :meth:`predicted`) at the same times, each (Q, 4), one search."""
        k = self.locate(slots, t_us)
        exact = np.tile(IDENTITY, (len(slots), 1))
        have = self.n[slots] > 0
        if have.any():
            exact[have] = self._slerp(slots[have], t_us[have], k[have])
        return exact, self.predicted(slots, t_us, k)

    def reconstruct(self, slots: np.ndarray, t_us: np.ndarray, live: np.ndarray) -> np.ndarray:
        """(Q, 4) float64 orientation of row ``slots[i]`` at ``t_us[i]`` in a frame: exact
        (:meth:`interpolate`) where ``live[i]`` is False or a point at or after the time is known,
        else the live view: the newest point extrapolated with its rate (:meth:`predicted`)."""
        out = np.tile(IDENTITY, (len(slots), 1))
        n = self.n[slots]
        newest = np.maximum(n - 1, 0)
        ahead = live & (n > 0) & (t_us > self.t[slots, newest])
        inside = (n > 0) & ~ahead
        if inside.any():
            s, t = slots[inside], t_us[inside]
            out[inside] = self._slerp(s, t, self.locate(s, t))
        if ahead.any():
            out[ahead] = self._predict(slots[ahead], t_us[ahead], newest[ahead])
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
