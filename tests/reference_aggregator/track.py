"""What the aggregator knows of one device besides its points: stream, counters, rates.

A :class:`DeviceTrack` checks each decoded segment point against the stream so far (new
stream, sequence gap, duplicate, time going backwards) before its point goes into the shared
:class:`~limbstream.services.aggregator.store.PointStore` row of the device (``slot``).
"""
from __future__ import annotations

import collections
import math
from collections.abc import Callable

from limbstream import wire

HISTORY_WAIT_S = 5.0
"""How long after a stream's first point its earlier points (history of a device the
aggregator joins late) may still be waited for, seconds. A stream whose first point is not its
start is settled sooner once the aggregator's own history query for it has completed
(:meth:`DeviceTrack.wants_history`); this bound covers a query that never completes."""

RATE_WINDOW_S = 5.0
"""Sliding window of the data-rate figures, seconds (arrival time)."""

HELD_RAW = 16
"""Truth batches of a stream whose first point has not arrived yet, kept per device until it
does (truth and points travel on different keys, so either may come first)."""

MAX_T_US = 2**53
"""Device timestamps must lie in [0, 2**53) us (year 2255): frame times and SLERP run in
float64, exact below 2**53. Others are dropped as ``time_range`` (a point near the int64 limit
once overflowed the frame grid and stopped the aggregator; tests/test_fuzz.py)."""


class DeviceTrack:
    """One device as seen by the aggregator.

    Parameters
    ----------
    subject, segment : the device's key chunks.
    slot : its row in the aggregator's columnar stores.
    """

    def __init__(self, subject: str, segment: str, slot: int):
        self.subject, self.segment, self.slot = subject, segment, slot
        self.id = wire.device_id(subject, segment)
        self.online = False
        self.config: wire.DeviceConfig | None = None  # as the device last reported it
        self.clock: wire.ClockStatus | None = None    # its clock sync, as it last reported it
        self.link: wire.LinkStatus | None = None      # a bridged device's link, as its gateway last reported it
        self.dropped: collections.Counter = collections.Counter()
        self.restarts = 0
        self.generation = 0
        self._retired: collections.deque = collections.deque(maxlen=16)
        self.stream: int | None = None
        self.held_raw: collections.deque = collections.deque()  # truth batches of a stream to come
        self.reset_stream()

    def reset_stream(self) -> None:
        """Forget the stream's counters (the caller resets the stores' rows)."""
        self.next_seq: int | None = None
        self.first_seq: int | None = None    # sequence number of the first point received
        self.first_arrival = 0.0
        self.first_t_us: int | None = None
        self.early: set[int] = set()          # points older than the first one, taken in later
        self.history = "none"                 # the history query of a late-joined stream: none, asked, done
        self.points = 0
        self.last_t_us: int | None = None   # newest point's device time
        self.last_index = -1
        self.last_raw_index = -1
        self.last_raw_t_us: int | None = None  # newest truth-tap sample time (later ones need later points)
        self.final = False
        self.gaps = 0
        self.gap_spans: collections.deque = collections.deque(maxlen=64)  # (t0, t1) us
        self.arrivals: collections.deque = collections.deque()            # (arrival s, bytes)
        self.latest_t_us: int | None = None  # newest device time seen (point or raw)
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

    def accept_point(self, p: wire.SegmentPoint, nbytes: int, now: float,
                     stored: Callable[[int], bool] = lambda t_us: False) -> str | None:
        """Sequence and time checks of a point of the current stream. Returns "append" (newest
        point), "insert" (an earlier point of the stream's start arriving late, e.g. history),
        "final" (the newest point repeated with FINAL: the stream ends, no new point), or None
        when it is dropped (counted by reason). ``stored(t_us)``: a point with that
        time is already kept."""
        if not 0 <= p.t_us < MAX_T_US:
            self.dropped["time_range"] += 1
            return None
        if self.next_seq is not None and p.seq < self.next_seq:
            if (p.seq < self.first_seq and p.seq not in self.early and p.t_us < self.first_t_us
                    and not self.settled(now) and not stored(p.t_us)):
                self.early.add(p.seq)
                self._count(p, nbytes, now)
                return "insert"
            self.dropped["duplicate"] += 1
            return None
        if (p.flags & wire.FLAG_FINAL and p.seq == self.next_seq and p.t_us == self.last_t_us
                and p.index == self.last_index):  # the newest point repeated as the stream's end marker
            self.next_seq, self.final = p.seq + 1, True
            self._count(p, nbytes, now)
            self.points -= 1
            return "final"
        if self.last_t_us is not None and (p.t_us <= self.last_t_us or p.index <= self.last_index):
            self.dropped["time_backwards"] += 1
            return None
        if self.next_seq is None:
            self.first_seq, self.first_arrival, self.first_t_us = p.seq, now, p.t_us
        elif p.seq > self.next_seq:
            self.gaps += p.seq - self.next_seq
            self.gap_spans.append((self.last_t_us, p.t_us))
        self.next_seq = p.seq + 1
        self.last_t_us, self.last_index = p.t_us, p.index
        self.final = bool(p.flags & wire.FLAG_FINAL)
        self._count(p, nbytes, now)
        return "append"

    def _count(self, p: wire.SegmentPoint, nbytes: int, now: float) -> None:
        self.points += 1
        self.arrivals.append((now, nbytes))
        self.see(p.t_us, now)

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

    def accept_raw(self, batch: wire.RawBatch, now: float) -> bool | None:
        """True if the batch is taken, None if it is held until its stream's first point
        arrives (:meth:`take_held_raw`), False if it is dropped (counted)."""
        if batch.stream != self.stream:
            if batch.stream in self._retired:
                self.dropped["raw_other_stream"] += 1
                return False
            if len(self.held_raw) == HELD_RAW:
                self.held_raw.popleft()
                self.dropped["raw_other_stream"] += 1
            self.held_raw.append(batch)
            return None
        if not 0 <= int(batch.t_us[0]) <= int(batch.t_us[-1]) < MAX_T_US:  # (wrapped int64 fails too)
            self.dropped["raw_time_range"] += 1
            return False
        self.last_raw_index = max(self.last_raw_index, batch.first_index + len(batch.t_us) - 1)
        self.last_raw_t_us = max(self.last_raw_t_us or 0, int(batch.t_us[-1]))
        self.see(int(batch.t_us[-1]), now)
        return True

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

    def in_gap(self, t_us) -> list[bool]:
        """Per time: inside a span whose points were lost."""
        return [any(t0 < t < t1 for t0, t1 in self.gap_spans) for t in t_us]

    def stats(self, now: float, errors: tuple[float, float, float, float, float, int],
              live_view: dict | None = None) -> dict:
        """The device entry of a stats message (the device fields of limbstream.wire.fields).

        ``errors``: (aad, p99, max, live mean, aad since the stream began, samples compared);
        ``live_view``: the live-view figures (live_p50_deg ... live_latency_p99_ms).
        """
        while self.arrivals and self.arrivals[0][0] < now - RATE_WINDOW_S:
            self.arrivals.popleft()
        span = RATE_WINDOW_S
        if self.arrivals and self.points == len(self.arrivals):  # stream younger than the window
            span = max(now - self.arrivals[0][0], 1.0)
        samples = max(self.last_index, self.last_raw_index) + 1
        aad, p99, mx, live, aad_all, compared = errors
        lag = math.nan
        if self.latest_t_us is not None and self.last_t_us is not None:
            device_now = self.latest_t_us + (now - self.latest_arrival) * 1e6
            lag = 0.0 if self.final else max(0.0, (device_now - self.last_t_us) / 1e6)
        return {
            "device": self.id, "segment": self.segment, "subject": self.subject, "online": self.online,
            "samples": samples, "points": self.points,
            "icr": self.points / samples if samples > 0 else math.nan,
            "msgs_per_s": len(self.arrivals) / span,
            "bytes_per_s": sum(b for _, b in self.arrivals) / span,
            "aad_deg": aad, "p99_deg": p99, "max_deg": mx, "live_err_deg": live,
            "aad_all_deg": aad_all, "error_samples": compared, **(live_view or {}),
            "watermark_lag_s": lag, "gaps": self.gaps, "dropped": sum(self.dropped.values()),
            "dropped_by_reason": dict(self.dropped),
            **{name: getattr(self.config, name, None) for name in wire.TUNABLES},
            "stream": self.stream, "restarts": self.restarts, "final": self.final,
            **(self.clock.as_dict() if self.clock is not None else {}),
            **(self.link.as_dict() if self.link is not None else {}),
        }
