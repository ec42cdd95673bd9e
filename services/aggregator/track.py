"""What the aggregator knows of one device besides its points: stream, counters, rates.

A :class:`DeviceTrack` checks each decoded segment point against the stream so far (new
stream, sequence gap, duplicate, time going backwards) before its point goes into the shared
:class:`~limbstream.services.aggregator.store.PointStore` row of the device (``slot``).
"""
from __future__ import annotations

import collections
import math
import operator
from collections.abc import Callable

import numpy as np

from limbstream import wire
from limbstream.services.aggregator.devices import COLUMNS, HISTORY, NO_TIME, DeviceTable

HISTORY_WAIT_S = 5.0
"""How long after a stream's first point its earlier points (history of a device the
aggregator joins late) may still be waited for, seconds. A stream whose first point is not its
start is settled sooner once the aggregator's own history query for it has completed
(:meth:`DeviceTrack.wants_history`); this bound covers a query that never completes."""

REFILL_MAX = 1024
"""Most points of one sequence gap that are remembered and may be filled later from the device's
cache (a larger jump is counted as a gap for good: no cache holds that much)."""

RATE_WINDOW_S = 5.0
"""Sliding window of the data-rate figures, seconds (arrival time)."""

HELD_RAW = 16
"""Truth batches of a stream whose first point has not arrived yet, kept per device until it
does (truth and points travel on different keys, so either may come first)."""

MAX_T_US = 2**53
"""Device timestamps must lie in [0, 2**53) us (year 2255): frame times and SLERP run in
float64, exact below 2**53. Others are dropped as ``time_range`` (a point near the int64 limit
once overflowed the frame grid and stopped the aggregator; tests/test_fuzz.py)."""


_tunables = operator.attrgetter(*wire.TUNABLES)  # a config's settings, in wire.TUNABLES order


class _Column:
    """A :class:`DeviceTrack` attribute kept in the track's row of its DeviceTable (column
    ``name``), so that a tick can read and write all devices' at once; with ``none``, the
    column's empty value reads as None."""

    def __init__(self, name: str, none: bool = False):
        self.name, self.none, self.empty = name, none, COLUMNS[name][1]

    def __get__(self, track: DeviceTrack, owner=None):
        value = getattr(track.table, self.name)[track.slot].item()
        return None if self.none and value == self.empty else value

    def __set__(self, track: DeviceTrack, value) -> None:
        getattr(track.table, self.name)[track.slot] = self.empty if value is None else value


class _Named(_Column):
    """A column holding the index of a name of ``names`` (its empty value reads as None)."""

    def __init__(self, name: str, names: tuple[str, ...]):
        super().__init__(name, none=True)
        self.names = names

    def __get__(self, track: DeviceTrack, owner=None):
        code = super().__get__(track, owner)
        return None if code is None else self.names[code]

    def __set__(self, track: DeviceTrack, value) -> None:
        super().__set__(track, None if value is None else self.names.index(value))


class DeviceTrack:
    """One device as seen by the aggregator. Its stream state lives in its row (``slot``) of the
    fusion's :class:`~.devices.DeviceTable` (the attributes below marked so); the rest here.

    Parameters
    ----------
    subject, segment : the device's key chunks.
    slot : its row in the aggregator's columnar stores.
    table : the columns of every device (its row exists).
    """

    online = _Column("online")                  # its liveliness token is present
    stream = _Column("stream", none=True)       # current stream id
    next_seq = _Column("next_seq", none=True)   # sequence number of the stream's next point
    first_seq = _Column("first_seq", none=True)  # sequence number of the first point received
    last_t_us = _Column("last_t", none=True)    # newest point's device time
    last_index = _Column("last_index")
    final = _Column("final")
    points = _Column("points")
    last_raw_t_us = _Column("last_raw_t", none=True)  # newest truth-tap sample time (later ones need later points)
    last_raw_index = _Column("last_raw_index")
    latest_t_us = _Column("latest_t", none=True)  # newest device time seen (point or raw)
    latest_arrival = _Column("latest_arrival")    # arrival clock when it came, s (NaN: none)
    orientations = _Named("orientations", wire.ORIENTATIONS)  # what its status says its orientations are

    def __init__(self, subject: str, segment: str, slot: int, table: DeviceTable):
        self.subject, self.segment, self.slot, self.table = subject, segment, slot, table
        self.id = wire.device_id(subject, segment)
        self.config: wire.DeviceConfig | None = None  # as the device last reported it
        self.clock: wire.ClockStatus | None = None    # its clock sync, as it last reported it
        self.link: wire.LinkStatus | None = None      # a bridged device's link, as its gateway last reported it
        self.fusion: wire.FusionStatus | None = None  # a raw-sample device's filter, as it last reported it
        self.dropped: collections.Counter = collections.Counter()
        self.restarts = 0
        self.generation = 0
        self._retired: collections.deque = collections.deque(maxlen=16)
        self.held_raw: collections.deque = collections.deque()  # truth batches of a stream to come
        self.reset_stream()

    @property
    def history(self) -> str:
        """The history query of a late-joined stream: none, asked, done."""
        return HISTORY[self.table.history[self.slot]]

    @history.setter
    def history(self, value: str) -> None:
        self.table.history[self.slot] = HISTORY.index(value)

    def reset_stream(self) -> None:
        """Forget the stream's counters (the caller resets the stores' rows)."""
        self.next_seq = self.first_seq = self.last_t_us = self.last_raw_t_us = self.latest_t_us = None
        self.first_arrival = 0.0
        self.first_t_us: int | None = None
        self.early: set[int] = set()          # points older than the first one, taken in later
        self.history = "none"
        self.points = 0
        self.last_index = self.last_raw_index = -1
        self.final = False
        self.gaps = 0
        self.gap_spans: collections.deque = collections.deque(maxlen=64)  # (t0, t1) us
        self.holes: dict[tuple[int, int], set[int]] = {}  # gap span -> its sequence numbers not filled yet
        self.table.arrivals.reset(self.slot)
        self.latest_arrival = math.nan

    def check_stream(self, stream: int) -> str:
        """'current', 'new' (the caller must reset the device's rows) or 'stale' (dropped)."""
        if stream == self.stream:
            return "current"
        if stream in self._retired:
            self.dropped["stale_stream"] += 1
            return "stale"
        if self.stream is not None:
            self._retired.append(self.stream)
            self.restarts += 1
        self.stream = stream
        self.generation += 1
        self.reset_stream()
        return "new"

    def accept_point(self, seq: int, index: int, t_us: int, flags: int, nbytes: int, now: float,
                     stored: Callable[[int], bool] = lambda t_us: False) -> str | None:
        """Sequence and time checks of a point of the current stream (sequence number ``seq``,
        sample ``index``, device time ``t_us`` us, ``flags``, ``nbytes`` on the wire, arrived at
        ``now``). Returns "append" (newest point), "insert" (an earlier point arriving
        late: of the stream's start, e.g. history, or of a gap, from the device's cache), "final" (the newest point repeated with FINAL: the
        stream ends, no new point), or None when it is dropped (counted by reason).
        ``stored(t_us)``: a point with that time is already kept."""
        if not 0 <= t_us < MAX_T_US:
            self.dropped["time_range"] += 1
            return None
        if self.next_seq is not None and seq < self.next_seq:
            if self._fills(seq, t_us, stored):
                self._count(t_us, nbytes, now)
                return "insert"
            if (seq < self.first_seq and seq not in self.early and t_us < self.first_t_us
                    and not self.settled(now) and not stored(t_us)):
                self.early.add(seq)
                self._count(t_us, nbytes, now)
                return "insert"
            self.dropped["duplicate"] += 1
            return None
        if (flags & wire.FLAG_FINAL and seq == self.next_seq and t_us == self.last_t_us
                and index == self.last_index):  # the newest point repeated as the stream's end marker
            self.next_seq, self.final = seq + 1, True
            self._count(t_us, nbytes, now)
            self.points -= 1
            return "final"
        if self.last_t_us is not None and (t_us <= self.last_t_us or index <= self.last_index):
            self.dropped["time_backwards"] += 1
            return None
        if self.next_seq is None:
            self.first_seq, self.first_arrival, self.first_t_us = seq, now, t_us
        elif seq > self.next_seq:
            self.gaps += seq - self.next_seq
            span = (self.last_t_us, t_us)
            if len(self.gap_spans) == self.gap_spans.maxlen:
                self.holes.pop(self.gap_spans[0], None)
            self.gap_spans.append(span)
            if seq - self.next_seq <= REFILL_MAX:
                self.holes[span] = set(range(self.next_seq, seq))
        self.next_seq = seq + 1
        self.last_t_us, self.last_index = t_us, index
        self.final = bool(flags & wire.FLAG_FINAL)
        self._count(t_us, nbytes, now)
        return "append"

    def _fills(self, seq: int, t_us: int, stored: Callable[[int], bool]) -> bool:
        """Whether a point (sequence number ``seq``, time ``t_us``) fills a gap of the stream (a point
        Zenoh reported missed, from the device's cache): the gap shrinks, and goes once filled."""
        for span, seqs in self.holes.items():
            if seq in seqs and span[0] < t_us < span[1] and not stored(t_us):
                seqs.discard(seq)
                self.gaps -= 1
                if not seqs:
                    del self.holes[span]
                    self.gap_spans.remove(span)
                return True
        return False

    def _count(self, t_us: int, nbytes: int, now: float) -> None:
        self.points += 1
        self.table.arrivals.add_one(self.slot, now, nbytes)
        self.see(t_us, now)

    def settled(self, now: float) -> bool:
        """True once the stream's start is complete (from sequence number 0), its history query
        has completed, or :data:`HISTORY_WAIT_S` passed since its first point: its points may
        then be used (and no earlier ones are taken in)."""
        if self.first_seq is None:
            return True
        return (len(self.early) >= self.first_seq or self.history == "done"
                or now - self.first_arrival >= HISTORY_WAIT_S)

    def wants_history(self) -> bool:
        """True for a stream whose first point received is not its start (the aggregator joined
        late) until the caller asks the device's cache for the earlier points (``history`` =
        "asked"); it calls :meth:`history_done` when the answer is complete."""
        return self.history == "none" and bool(self.first_seq) and len(self.early) < self.first_seq

    def history_done(self) -> None:
        """The history query of the current stream has completed: the stream is settled."""
        self.history = "done"

    def accept_raw(self, stream: int, first_index: int, count: int, t_first: int, t_last: int, now: float) -> bool | None:
        """A truth batch of ``stream`` (``count`` samples from sample ``first_index``, device times
        ``t_first`` .. ``t_last`` us) arrived at ``now``: True if it is taken, None if it is to be
        held until its stream's first point arrives (:meth:`hold_raw`), False if it is dropped
        (counted)."""
        if stream != self.stream:
            if stream in self._retired:
                self.dropped["raw_other_stream"] += 1
                return False
            return None
        if not 0 <= t_first <= t_last < MAX_T_US:  # (wrapped int64 fails too)
            self.dropped["raw_time_range"] += 1
            return False
        self.last_raw_index = max(self.last_raw_index, first_index + count - 1)
        self.last_raw_t_us = max(self.last_raw_t_us or 0, t_last)
        self.see(t_last, now)
        return True

    def hold_raw(self, batch: wire.RawBatch) -> None:
        """Keep a truth batch of a stream whose first point has not arrived (HELD_RAW at most: then
        the oldest is dropped, counted)."""
        if len(self.held_raw) == HELD_RAW:
            self.held_raw.popleft()
            self.dropped["raw_other_stream"] += 1
        self.held_raw.append(batch)

    def take_held_raw(self) -> list[wire.RawBatch]:
        """The held truth batches of the current stream (to take in now); others are dropped."""
        mine = [b for b in self.held_raw if b.stream == self.stream]
        if len(mine) < len(self.held_raw):
            self.dropped["raw_other_stream"] += len(self.held_raw) - len(mine)
        self.held_raw.clear()
        return mine

    def see(self, t_us: int, now: float) -> None:
        if self.latest_t_us is None or t_us >= self.latest_t_us:
            self.latest_t_us, self.latest_arrival = t_us, now

    def in_gap(self, t_us: np.ndarray) -> np.ndarray:
        """(F,) bool: each time (F,) us inside a span whose points were lost."""
        spans = np.array(self.gap_spans, np.int64).reshape(-1, 2)
        inside: np.ndarray = ((t_us[:, None] > spans[:, 0]) & (t_us[:, None] < spans[:, 1])).any(axis=1)
        return inside

    def stats(self) -> tuple[tuple, tuple]:
        """The fields of its stats entry (limbstream.wire.fields) that its row in the table does not
        hold: the values of :data:`NUMBERS` and of :data:`TEXTS`, in their order (None: null)."""
        config, clock, link, fusion = self.config, self.clock, self.link, self.fusion
        numbers = (self.gaps, sum(self.dropped.values()),
                   *((None,) * len(wire.TUNABLES) if config is None else _tunables(config)), self.restarts,
                   *((None, None, None) if clock is None else (clock.clock_offset_ms, clock.sync_rtt_ms, clock.synced)),
                   *((None,) * 4 if link is None else (link.battery_pct, link.signal_dbm, link.link_loss, link.link_pps)),
                   *((None, None) if fusion is None else (float(np.linalg.norm(fusion.gyro_bias_dps)), fusion.at_rest)))
        texts = (self.id, self.segment, self.subject, dict(self.dropped), None if clock is None else dict(clock.sync_bad),
                 None if link is None else link.tracker, None if fusion is None else fusion.fusion,
                 None if fusion is None else dict(fusion.raw_faults))
        return numbers, texts


NUMBERS: tuple[str, ...] = ("gaps", "dropped", *wire.TUNABLES, "restarts", "clock_offset_ms", "sync_rtt_ms", "synced",
                            "battery_pct", "signal_dbm", "link_loss", "link_pps", "gyro_bias_dps", "at_rest")
"""The number fields of a device's stats entry that its track gives (:meth:`DeviceTrack.stats`)."""
TEXTS: tuple[str, ...] = ("device", "segment", "subject", "dropped_by_reason", "sync_bad", "tracker", "fusion",
                          "raw_faults")
"""The other fields of a device's stats entry that its track gives."""


def stream_figures(table: DeviceTable, slots: np.ndarray, now: float) -> dict[str, np.ndarray]:
    """The stats fields of devices ``slots`` (k,) that their rows of ``table`` give, at arrival
    clock ``now`` (s), by name, each (k,) (NaN: null): liveliness, samples, points, ICR, data
    rates over RATE_WINDOW_S, watermark lag, stream, end."""
    points, nbytes, oldest = table.arrivals.window(slots, now - RATE_WINDOW_S)
    span = np.where((points > 0) & (table.points[slots] == points), np.maximum(now - oldest, 1.0), RATE_WINDOW_S)
    samples = np.maximum(table.last_index[slots], table.last_raw_index[slots]) + 1
    latest, last = table.latest_t[slots], table.last_t[slots]
    device_now = latest + (now - table.latest_arrival[slots]) * 1e6
    lag = np.where(table.final[slots], 0.0, np.maximum(0.0, (device_now - last) / 1e6))
    return {"online": table.online[slots], "samples": samples, "points": table.points[slots],
            "icr": np.where(samples > 0, table.points[slots] / np.maximum(samples, 1), np.nan),
            "msgs_per_s": points / span, "bytes_per_s": nbytes / span,
            "watermark_lag_s": np.where((latest != NO_TIME) & (last != NO_TIME), lag, np.nan),
            "stream": np.where(table.stream[slots] >= 0, table.stream[slots], np.nan), "final": table.final[slots]}
