"""The columns every tick reads and writes: per device slot (its subject, liveliness, stream state,
newest times, live horizon, settled, the arrivals of its points) and per subject (the device slot
of each segment), so that a tick takes in and reads all devices in a few NumPy calls. A
:class:`~.track.DeviceTrack` reads and writes its own row through its attributes."""
from __future__ import annotations

import numpy as np

from limbstream.wire import SEGMENTS

NO_TIME = np.iinfo(np.int64).min
"""A time column's value where there is none (int64 min)."""
SEGMENT_INDEX = {name: i for i, name in enumerate(SEGMENTS)}
HISTORY = ("none", "asked", "done")
"""A stream's history query, by its code in the ``history`` column."""

COLUMNS: dict[str, tuple[type, object]] = {
    "owner": (np.int64, 0),             # subject index
    "online": (bool, False),            # liveliness token present
    "active": (bool, False),            # online and its stream not ended
    "stream": (np.int64, -1),           # current stream id (-1: none yet)
    "next_seq": (np.int64, -1),         # sequence number of the stream's next point (-1: no point yet)
    "first_seq": (np.int64, -1),        # sequence number of the stream's first point received (-1: none)
    "history": (np.int8, 0),            # the stream's history query (HISTORY)
    "last_t": (np.int64, NO_TIME),      # newest point's device time, us
    "last_index": (np.int64, -1),       # newest point's sample index
    "final": (bool, False),             # the stream ended (its last point carried FINAL)
    "points": (np.int64, 0),            # points taken in of the stream
    "last_raw_t": (np.int64, NO_TIME),  # newest truth sample time, us
    "last_raw_index": (np.int64, -1),   # newest truth sample's index
    "latest_t": (np.int64, NO_TIME),    # newest device time of a point or truth sample, us
    "latest_arrival": (np.float64, np.nan),  # arrival clock when latest_t arrived, s
    "horizon_us": (np.int64, 0),        # longest extrapolation of the newest point in a live frame
    "settled": (bool, True),            # DeviceTrack.settled, as last refreshed
    "orientations": (np.int8, -1),      # what its status says its orientations are (wire.ORIENTATIONS; -1: not said)
    "placed": (bool, False),            # its segment is in its subject's layout (else its points are dropped)
}
"""Every per-slot column: its type and the value of a fresh row (and of "none")."""


class ArrivalWindows:
    """Per device slot, when its points arrived: one entry per arrival clock value (a drain) that
    brought some, (arrival s, points, bytes), oldest first, in a ring per slot that grows when a
    slot's entries fill it; entries older than the window are dropped when it is read."""

    def __init__(self, entries: int = 32):
        self.time = np.zeros((0, entries))
        self.points = np.zeros((0, entries), np.int64)
        self.bytes = np.zeros((0, entries), np.int64)
        self.head = np.zeros(0, np.int64)
        self.size = np.zeros(0, np.int64)

    def add_slot(self) -> None:
        for name in ("time", "points", "bytes"):
            old = getattr(self, name)
            setattr(self, name, np.concatenate([old, np.zeros((1, old.shape[1]), old.dtype)]))
        self.head, self.size = np.append(self.head, 0), np.append(self.size, 0)

    def reset(self, slot: int) -> None:
        self.size[slot] = 0

    def add(self, slots: np.ndarray, now: float, points: np.ndarray, nbytes: np.ndarray) -> None:
        """Points (k,) and their bytes (k,) of devices ``slots`` (k, each once) arrived at ``now``."""
        width = self.time.shape[1]
        newest = (self.head[slots] + self.size[slots] - 1) % width
        same = (self.size[slots] > 0) & (self.time[slots, newest] == now)
        s, at = slots[same], newest[same]
        self.points[s, at] += points[same]
        self.bytes[s, at] += nbytes[same]
        s = slots[~same]
        if len(s) and (self.size[s] == width).any():
            self._widen(2 * width)
            width *= 2
        at = (self.head[s] + self.size[s]) % width
        self.time[s, at], self.points[s, at], self.bytes[s, at] = now, points[~same], nbytes[~same]
        self.size[s] += 1

    def add_one(self, slot: int, now: float, nbytes: int) -> None:
        """One point of ``nbytes`` of device ``slot`` arrived at ``now`` (:meth:`add` of one)."""
        width, size, head = self.time.shape[1], int(self.size[slot]), int(self.head[slot])
        newest = (head + size - 1) % width
        if size and self.time[slot, newest] == now:
            self.points[slot, newest] += 1
            self.bytes[slot, newest] += nbytes
            return
        if size == width:
            self._widen(2 * width)
            width, head = 2 * width, 0
        at = (head + size) % width
        self.time[slot, at], self.points[slot, at], self.bytes[slot, at] = now, 1, nbytes
        self.size[slot] = size + 1

    def _widen(self, width: int) -> None:
        """Room for ``width`` entries per slot, each ring unrolled from its head."""
        old = self.time.shape[1]
        order = (self.head[:, None] + np.arange(old)) % old
        rows = np.arange(len(self.head))[:, None]
        for name in ("time", "points", "bytes"):
            a = getattr(self, name)
            new = np.zeros((len(a), width), a.dtype)
            new[:, :old] = a[rows, order]
            setattr(self, name, new)
        self.head[:] = 0

    def window(self, slots: np.ndarray, since: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Drop the entries of ``slots`` (k,) that arrived before ``since`` (s); then per slot the
        points and bytes of the rest and the arrival of the oldest of them (NaN: none), each (k,)."""
        width = self.time.shape[1]
        at = (self.head[slots, None] + np.arange(width)) % width
        rows = slots[:, None]
        held = np.arange(width) < self.size[slots, None]
        gone = np.cumprod(held & (self.time[rows, at] < since), axis=1).sum(axis=1)  # the oldest: a prefix
        self.head[slots] = (self.head[slots] + gone) % width
        self.size[slots] -= gone
        kept = held & (np.arange(width) >= gone[:, None])
        oldest = np.where(self.size[slots] > 0, self.time[slots, self.head[slots]], np.nan)
        return (np.where(kept, self.points[rows, at], 0).sum(axis=1), np.where(kept, self.bytes[rows, at], 0).sum(axis=1),
                oldest)


class DeviceTable:
    """Per device slot (rows in the order devices were first seen; the point store's rows), the
    columns of :data:`COLUMNS` (each (slots,)) and its points' arrivals (``arrivals``); per subject,
    over the segment ``columns`` (C names: wire.SEGMENTS first, then each other segment name of a
    subject's layout as it appears), ``seg_slots`` (subjects, C) int64: the device slot of each
    segment, -1 where the subject has no such device or its layout lacks the segment, and
    ``in_layout`` (subjects, C) bool: the segment is in the subject's layout."""

    owner: np.ndarray
    online: np.ndarray
    active: np.ndarray
    stream: np.ndarray
    next_seq: np.ndarray
    first_seq: np.ndarray
    history: np.ndarray
    last_t: np.ndarray
    last_index: np.ndarray
    final: np.ndarray
    points: np.ndarray
    last_raw_t: np.ndarray
    last_raw_index: np.ndarray
    latest_t: np.ndarray
    latest_arrival: np.ndarray
    horizon_us: np.ndarray
    settled: np.ndarray
    orientations: np.ndarray
    placed: np.ndarray

    def __init__(self) -> None:
        self.columns: list[str] = list(SEGMENTS)
        self.column_index = dict(SEGMENT_INDEX)
        self.seg_slots = np.full((0, len(SEGMENTS)), -1, np.int64)
        self.in_layout = np.zeros((0, len(SEGMENTS)), bool)
        for name, (dtype, _) in COLUMNS.items():
            setattr(self, name, np.zeros(0, dtype))
        self.arrivals = ArrivalWindows()

    def __len__(self) -> int:
        return len(self.owner)

    def add_subject(self) -> int:
        """A new subject without devices (its layout: none yet, :meth:`set_layout`); returns its index."""
        self.seg_slots = np.vstack([self.seg_slots, np.full((1, len(self.columns)), -1, np.int64)])
        self.in_layout = np.vstack([self.in_layout, np.zeros((1, len(self.columns)), bool)])
        return len(self.seg_slots) - 1

    def add_device(self, subject: int, horizon_us: int) -> int:
        """A new device of ``subject`` (offline, no data yet, not placed: :meth:`set_layout`);
        returns its slot."""
        slot = len(self.owner)
        for name, (dtype, fresh) in COLUMNS.items():
            setattr(self, name, np.append(getattr(self, name), np.array(fresh, dtype)))
        self.owner[slot], self.horizon_us[slot] = subject, horizon_us
        self.arrivals.add_slot()
        return slot

    def columns_of(self, segments: tuple[str, ...]) -> np.ndarray:
        """(S,) the columns of segment names ``segments``, in their order; a name without one gets
        a new column (appended: the columns of the others stay)."""
        new = [name for name in segments if name not in self.column_index]
        if new:
            for name in new:
                self.column_index[name] = len(self.columns)
                self.columns.append(name)
            more = len(new)
            self.seg_slots = np.hstack([self.seg_slots, np.full((len(self.seg_slots), more), -1, np.int64)])
            self.in_layout = np.hstack([self.in_layout, np.zeros((len(self.in_layout), more), bool)])
        return np.array([self.column_index[name] for name in segments], np.int64)

    def set_layout(self, subject: int, segments: tuple[str, ...], devices: dict[str, int]) -> np.ndarray:
        """The subject's layout is of ``segments`` (names), its devices ``devices`` (segment ->
        slot): those on a segment of it are placed, the others not. Returns the layout's columns (S,)."""
        cols = self.columns_of(segments)
        self.in_layout[subject] = False
        self.in_layout[subject, cols] = True
        self.seg_slots[subject] = -1
        for segment, slot in devices.items():
            column = self.column_index.get(segment)
            self.placed[slot] = column is not None and bool(self.in_layout[subject, column])
            if self.placed[slot]:
                self.seg_slots[subject, column] = slot
        return cols
