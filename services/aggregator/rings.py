"""Sliding windows of figures per device, summarised for the stats (degrees or milliseconds).

- :class:`ErrorRings`: one window per row (a device's angular errors against the truth tap).
- :class:`SubjectRings`: a value every device of a subject gets at once (the live latency of each
  live frame), kept once per subject instead of once per device.
"""
from __future__ import annotations

import numpy as np

from limbstream.kernel import reconstruct


class ErrorRings:
    """Per-row ring windows of values (float32), and totals since the row began (float64).
    A row holds ``min(count, window)`` values (the first ones until it wraps); rows that never
    held a value stay untouched zero pages (no memory resident for a window nobody fills)."""

    def __init__(self, window: int, rows: int = 64):
        self.window = window
        self.values = np.zeros((rows, window), np.float32)
        self.count = np.zeros(rows, np.int64)
        self.total = np.zeros(rows, np.float64)

    def ensure(self, rows: int) -> None:
        if rows > len(self.count):
            grow = max(rows - len(self.count), len(self.count))
            values = np.zeros((len(self.count) + grow, self.window), np.float32)
            used = np.flatnonzero(self.count > 0)
            values[used] = self.values[used]
            self.values = values
            self.count = np.concatenate([self.count, np.zeros(grow, np.int64)])
            self.total = np.concatenate([self.total, np.zeros(grow)])

    def reset(self, row: int) -> None:
        self.count[row] = 0
        self.total[row] = 0.0

    def add(self, rows: np.ndarray, values: np.ndarray) -> None:
        """Append values (E,) of rows (E,), in order within each row (in C: one pass)."""
        reconstruct.ring_append(self.values, self.count, self.total, rows, values)

    def summary(self, rows: np.ndarray, quantiles: tuple[float, ...] = ()) -> tuple[np.ndarray, ...]:
        """(mean, max, *quantiles) over each row's window, each (rows,), NaN for empty rows; a
        quantile ``p`` (0..1) is the lower order statistic, the mean summed in float64. In C
        (``reconstruct.ring_ranks``): full windows (every row in the long run), by a radix select
        (a few passes over its values, a third of a partition per rank), and windows asked only
        for their few largest (a high quantile and the max) by one pass through a heap; the other
        windows not yet full are sorted (NumPy's sort is the faster up to a thousand values or so).
        Empty rows (truth tap or live frames off) cost nothing."""
        n = np.minimum(self.count[rows], self.window)
        out = np.full((2 + len(quantiles), len(rows)), np.nan)
        have = np.flatnonzero(n > 0)
        if len(have) == 0:
            return tuple(out)
        k = n[have]
        ranks = np.stack([np.floor(p * (k - 1)).astype(np.int64) for p in quantiles] + [k - 1], axis=1)
        chosen = (k == self.window) | reconstruct.takes_top(k, ranks.min(axis=1))
        if chosen.any():
            c, kc = have[chosen], k[chosen]
            picked = reconstruct.ring_ranks(self.values, rows[c], kc, ranks[chosen])
            out[1, c] = picked[:, -1]
            out[2:, c] = picked[:, :-1].T
            width = int(kc.max())
            v = self.values[rows[c], :width]
            if (kc < width).any():
                v = np.where(np.arange(width) < kc[:, None], v, np.float32(0.0))
            out[0, c] = v.sum(axis=1, dtype=np.float64) / kc
        part, k = have[~chosen], k[~chosen]
        if len(part):
            r = np.arange(len(part))
            width = int(k.max())
            v = self.values[rows[part], :width]
            unused = np.arange(width) >= k[:, None]
            v[unused] = np.nan  # sorts last
            v.sort(axis=1)
            out[1, part] = v[r, k - 1]
            for i, p in enumerate(quantiles):
                out[2 + i, part] = v[r, np.floor(p * (k - 1)).astype(np.int64)]
            v[unused] = 0.0
            out[0, part] = v.sum(axis=1, dtype=np.float64) / k
        return tuple(out)


class SubjectRings:
    """Windows of a value that every device of a subject with data gets at once (the live latency
    of each of the subject's live frames), as if each device had its own :class:`ErrorRings` row.

    A device gets every value of its subject from its stream's first point on (once a device
    has a point it keeps one until its next stream), so its values are the newest of its
    subject's: one ring per subject, and per device the subject's count when its values began
    (``since``; -1: none yet). The same order statistics as one row per device, with a tenth of
    the sorting.
    """

    def __init__(self, window: int):
        self.rings = ErrorRings(window, rows=16)
        self.since = np.zeros(0, np.int64)

    def add_device(self) -> None:
        self.since = np.append(self.since, -1)

    def add_subject(self, subjects: int) -> None:
        self.rings.ensure(subjects)

    def reset(self, slot: int) -> None:
        """The device in ``slot`` began a new stream: no values yet."""
        self.since[slot] = -1

    def add(self, subjects: np.ndarray, values: np.ndarray, slots: np.ndarray, slot_subjects: np.ndarray) -> None:
        """One value per subject (F,) (each subject once); the devices ``slots`` (k,) of those
        subjects (``slot_subjects`` (k,)) that get it (those with data)."""
        starting = self.since[slots] < 0
        if starting.any():
            self.since[slots[starting]] = self.rings.count[slot_subjects[starting]]
        self.rings.add(subjects, values)

    def count(self, slots: np.ndarray, owner: np.ndarray) -> np.ndarray:
        """(k,) values each device ``slots`` (of subjects ``owner``, (k,)) got since its stream began."""
        since = self.since[slots]
        return np.where(since >= 0, self.rings.count[owner] - since, 0)

    def quantiles(self, slots: np.ndarray, owner: np.ndarray, quantiles: tuple[float, ...]) -> tuple[np.ndarray, ...]:
        """The lower order statistics ``quantiles`` (0..1) of the window of each device ``slots``
        (k,) of subjects ``owner`` (k,), each (k,), NaN for a device without values. A window is
        its subject's newest values, as many as the device got (the window at most): devices of
        one subject with as many share one sort (in the long run, every device of a subject)."""
        window = self.rings.window
        held = np.minimum(self.count(slots, owner), window)
        out = np.full((len(quantiles), len(slots)), np.nan)
        have = np.flatnonzero(held > 0)
        if len(have) == 0:
            return tuple(out)
        _, first, group = np.unique(owner[have] * (window + 1) + held[have], return_index=True, return_inverse=True)
        subject, k = owner[have][first], held[have][first]
        back = np.arange(int(k.max()))
        v = self.rings.values[subject[:, None], (self.rings.count[subject][:, None] - 1 - back) % window]
        v[back >= k[:, None]] = np.nan  # beyond the window: sorts last
        v.sort(axis=1)
        r = np.arange(len(k))
        for i, p in enumerate(quantiles):
            out[i, have] = v[r, np.floor(p * (k - 1)).astype(np.int64)][group.reshape(-1)]
        return tuple(out)
