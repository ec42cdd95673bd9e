"""Columnar state of every device of an aggregator, so each tick is a few NumPy calls for all
devices instead of a few per device (200 subjects x 10 IMUs in real time).

- :class:`PointStore`: the segment points of every device, one row per device slot.
- :class:`TruthQueue`: truth-tap samples waiting until their reconstruction is final.

(The windows of figures per device: :mod:`.rings`.)
"""
from __future__ import annotations

import numpy as np

from limbstream.kernel import reconstruct



MIN_WIDTH = 64
"""Points the rows of a store have room for at least (their arrays' width)."""


class PointStore:
    """Segment points per device slot: times ``t`` (slots, width) int64 us, orientations
    ``q`` (slots, width, 4) float32 and body rates ``w`` (slots, width, 3) float32 rad/s (zero for
    a point without a rate: held); row ``d`` holds ``n[d]`` points, oldest first, ``cap`` at most
    (then it forgets its oldest half). The arrays are as wide as the fullest row needs (from
    MIN_WIDTH up to ``cap``, doubling, and narrowed again when pruned): a tick's rows of a few
    dozen points then lie close together in memory (at 2,000 devices, 4 MiB instead of 72)."""

    def __init__(self, cap: int = 1024, slots: int = 64):
        self.cap = cap
        self.width = min(cap, MIN_WIDTH)
        self.t = np.zeros((slots, self.width), np.int64)
        self.q = np.zeros((slots, self.width, 4), np.float32)
        self.w = np.zeros((slots, self.width, 3), np.float32)
        self.n = np.zeros(slots, np.int64)
        self.size = 0
        self._c = reconstruct.PointRows(self.t, self.q, self.w, self.n)  # the C library's view of the rows

    def add_slot(self) -> int:
        """A new empty row; returns its slot."""
        if self.size == len(self.n):
            self._resize(2 * len(self.n), self.width)
        self.size += 1
        return self.size - 1

    def _resize(self, slots: int, width: int) -> None:
        """``slots`` rows of room for ``width`` points, touching no memory the rows do not use:
        fresh rows are zero pages the OS maps only when written (``np.zeros``), and only the
        columns in use are copied. (A concatenation writes every byte: at 2,000 devices that made
        this store and the truth store resident in full, 216 MiB, whatever was stored.)"""
        used = int(self.n[:self.size].max(initial=0))
        for name in ("t", "q", "w"):
            old = getattr(self, name)
            new = np.zeros((slots, width, *old.shape[2:]), old.dtype)
            new[:self.size, :used] = old[:self.size, :used]
            setattr(self, name, new)
        self.n = np.concatenate([self.n, np.zeros(slots - len(self.n), np.int64)])
        self.width = width
        self._c = reconstruct.PointRows(self.t, self.q, self.w, self.n)

    def _room(self, points: int) -> None:
        """Widen the rows to hold ``points`` (at most ``cap``)."""
        if points > self.width:
            width = self.width
            while width < points:
                width *= 2
            self._resize(len(self.n), min(width, self.cap))

    def reset(self, slot: int) -> None:
        self.n[slot] = 0

    def append(self, slot: int, t_us: int, q, omega=None) -> int:
        """Add a point (times must increase) with its body rate ``omega`` (3,) rad/s (None: held);
        returns how many old points were forgotten to make room."""
        forgotten = 0
        if self.n[slot] == self.cap:  # consumers stalled far behind: forget the oldest half
            forgotten = self.cap // 2
            self.shift(slot, forgotten)
        self._room(self.n[slot] + 1)
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
        if len(set(slots.tolist())) == len(slots) and (self.n[slots] < self.width).all():  # a point per row: a tick's usual
            position = self.n[slots]
            self.t[slots, position], self.q[slots, position], self.w[slots, position] = t_us, q, w
            self.n[slots] += 1
            return {}
        rows, counts = np.unique(slots, return_counts=True)
        full = self.n[rows] + counts > self.cap
        forgotten = {}
        if full.any():  # consumers stalled: these rows forget points on the way, one by one
            for slot in rows[full]:
                forgotten[int(slot)] = sum(self.append(slot, t_us[i], q[i], w[i]) for i in np.flatnonzero(slots == slot))
            keep = ~np.isin(slots, rows[full])
            slots, t_us, q, w = slots[keep], t_us[keep], q[keep], w[keep]
            rows, counts = rows[~full], counts[~full]
        self._room(int((self.n[rows] + counts).max(initial=0)))
        order = np.argsort(slots, kind="stable")  # rank of each point within its row, in order
        rank = np.empty(len(slots), np.int64)
        rank[order] = np.arange(len(slots)) - np.repeat(np.cumsum(counts) - counts, counts)
        position = self.n[slots] + rank
        self.t[slots, position], self.q[slots, position], self.w[slots, position] = t_us, q, w
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
        self._room(self.n[slot] + count)
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
        self._room(n + 1)
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
        flat, base = self.t.reshape(-1), slots * self.width
        for _ in range(int(n.max(initial=0)).bit_length()):
            mid = (lo + hi) >> 1
            go = (mid < hi) & (flat[base + np.minimum(mid, self.width - 1)] <= t_us)
            lo = np.where(go, mid + 1, lo)
            hi = np.where(go, hi, mid)
        return lo - 1

    def interpolate(self, slots: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(Q, 4) float64 SLERP reconstruction of row ``slots[i]`` at ``t_us[i]``; held before the
        first and after the last point; identity for an empty row."""
        return self._c.reconstruct(slots, t_us, reconstruct.EXACT)

    def predicted(self, slots: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(Q, 4) float64: what a receiver knowing only the points of row ``slots[i]`` at or before
        ``t_us[i]`` shows then: the newest of them extrapolated with its rate
        (:func:`limbstream.quat.predict`, the prediction the device's live rule bounds; rate 0
        holds it); identity for a row without such a point."""
        return self._c.reconstruct(slots, t_us, reconstruct.PREDICTED)

    def errors(self, slots: np.ndarray, t_us: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Angles (Q,) degrees between ``truth`` (Q, 4) and :meth:`interpolate`, and between it and
        :meth:`predicted`, of row ``slots[i]`` at ``t_us[i]``."""
        return self._c.errors(slots, t_us, truth)

    def reconstruct(self, slots: np.ndarray, t_us: np.ndarray, live: np.ndarray) -> np.ndarray:
        """(Q, 4) float64 orientation of row ``slots[i]`` at ``t_us[i]`` in a frame: exact
        (:meth:`interpolate`) where ``live[i]`` is False or a point at or after the time is known,
        else the live view: the newest point extrapolated with its rate (:meth:`predicted`)."""
        return self._c.reconstruct(slots, t_us, np.where(live, reconstruct.LIVE, reconstruct.EXACT))

    def prune(self, keep_from: np.ndarray, min_drop: int = 16) -> None:
        """Forget points before ``keep_from[slot]`` (keeping one before it) where that frees at least
        ``min_drop`` points; ``keep_from`` is (slots,) int64 us."""
        k = self.locate(np.arange(self.size), keep_from[: self.size])
        for slot in np.flatnonzero(k >= min_drop):
            self.shift(int(slot), int(k[slot]))
        fullest = int(self.n[:self.size].max(initial=0))
        if self.width > MIN_WIDTH and 4 * fullest <= self.width:  # the rows need much less room again
            self._resize(len(self.n), max(MIN_WIDTH, 2 * fullest))


class TruthQueue:
    """Truth-tap samples of every device waiting for the device's watermark to pass them, in
    arrival order. A device's new stream drops the samples of its old one (:meth:`drop`): they
    are never compared with the new one. Each sample's ``q`` is (8,): its true orientation, then
    the device's own (NaN where the tap does not carry it)."""

    def __init__(self, limit: int = 2_000_000):
        self.limit = limit
        self.slot = np.zeros(0, np.int64)
        self.t = np.zeros(0, np.int64)
        self.q = np.zeros((0, 8), np.float32)
        self._incoming: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (slot, t_us, q) per sample

    def __len__(self) -> int:
        return len(self.t) + sum(len(b[1]) for b in self._incoming)

    def put(self, slots: np.ndarray | int, t_us: np.ndarray, q: np.ndarray, own: np.ndarray | None = None) -> None:
        """Samples at device times ``t_us`` (k,) us, true orientations ``q`` (k, 4) and the devices'
        own ``own`` (k, 4) (None or NaN rows: not known), of devices ``slots`` (k,) (or one for all)."""
        both = np.full((len(t_us), 8), np.nan, np.float32)
        both[:, :4] = q
        if own is not None:
            both[:, 4:] = own
        self._incoming.append((np.broadcast_to(np.asarray(slots, np.int64), t_us.shape), t_us, both))

    def drop(self, slot: int) -> None:
        """Forget the samples of ``slot`` (its device began a new stream)."""
        self._merge()
        keep = self.slot != slot
        self.slot, self.t, self.q = self.slot[keep], self.t[keep], self.q[keep]

    def _merge(self) -> None:
        if self._incoming:
            self.slot = np.concatenate([self.slot, *(b[0] for b in self._incoming)])
            self.t = np.concatenate([self.t, *(b[1] for b in self._incoming)])
            self.q = np.concatenate([self.q, *(b[2] for b in self._incoming)])
            self._incoming = []

    def take_ready(self, watermark: np.ndarray) -> tuple[np.ndarray, ...]:
        """Remove and return (slot, t_us, q (k, 8) float32: true and own) of every sample at or before its slot's
        ``watermark``, and the slots of the samples dropped because more than ``limit`` wait
        (the oldest first, one entry per sample)."""
        self._merge()
        ready = self.t <= watermark[self.slot]
        out = self.slot[ready], self.t[ready], self.q[ready]
        keep = ~ready
        overflow = np.zeros(0, np.int64)
        if len(self.t) - len(out[1]) > self.limit:  # oldest entries first in each arrival order
            idx = np.flatnonzero(keep)
            overflow = self.slot[idx[: len(idx) - self.limit]]
            keep[idx[: len(idx) - self.limit]] = False
        if len(out[1]) or len(overflow):
            self.slot, self.t, self.q = self.slot[keep], self.t[keep], self.q[keep]
        return (*out, overflow)

    def oldest(self, slots: int) -> np.ndarray:
        """(slots,) time of each slot's oldest waiting sample (int64 max if none)."""
        self._merge()
        out = np.full(slots, np.iinfo(np.int64).max)
        if len(self.t):
            np.minimum.at(out, self.slot, self.t)
        return out
