"""What the aggregator knows of one device: its segment points, counters and error windows.

A :class:`DeviceTrack` accepts decoded segment points and truth-tap batches, checks them
against the stream so far (new stream, sequence gap, duplicate, time going backwards),
keeps a bounded buffer of points, reconstructs the orientation at any time by SLERP, and
measures the angular error of the exact reconstruction (and of holding the last point) at
every truth sample once it is final.
"""
from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field

import numpy as np

from limbstream import quat, wire

RATE_WINDOW_S = 5.0
"""Sliding window of the data-rate figures, seconds (arrival time)."""


@dataclass
class ErrorWindow:
    """Angular errors (degrees) over a sliding window of samples, plus totals since the stream began."""

    size: int
    values: collections.deque = field(default_factory=collections.deque)
    total: float = 0.0
    count: int = 0

    def extend(self, errors: np.ndarray) -> None:
        self.values.extend(errors.tolist())
        while len(self.values) > self.size:
            self.values.popleft()
        self.total += float(np.sum(errors))
        self.count += len(errors)

    def summary(self) -> tuple[float, float, float]:
        """(mean, p99, max) over the window; NaN when empty."""
        if not self.values:
            return math.nan, math.nan, math.nan
        v = np.fromiter(self.values, float, len(self.values))
        return float(v.mean()), float(np.percentile(v, 99)), float(v.max())

    @property
    def mean_all(self) -> float:
        return self.total / self.count if self.count else math.nan


class DeviceTrack:
    """One device as seen by the aggregator.

    Parameters
    ----------
    subject, segment : the device's key chunks.
    capacity : most segment points buffered (older ones are pruned once no frame needs them).
    error_window : samples in the angular-error windows.
    max_pending : most truth samples waiting for their reconstruction to become final.
    """

    def __init__(self, subject: str, segment: str, capacity: int = 4096, error_window: int = 3000,
                 max_pending: int = 6000):
        self.subject, self.segment = subject, segment
        self.id = wire.device_id(subject, segment)
        self.capacity, self.error_window, self.max_pending = capacity, error_window, max_pending
        self.online = False
        self.threshold = math.nan
        self.max_len: int | None = None
        self.dropped: collections.Counter = collections.Counter()
        self.restarts = 0
        self._retired: collections.deque = collections.deque(maxlen=16)
        self.stream: int | None = None
        self._reset_stream()

    # ------------------------------------------------------------------ stream state

    def _reset_stream(self) -> None:
        self.t = np.zeros(self.capacity, np.int64)      # point times, us (device clock)
        self.q = np.zeros((self.capacity, 4), np.float64)
        self.n = 0
        self.next_seq: int | None = None
        self.points = 0
        self.last_index = -1
        self.last_raw_index = -1
        self.final = False
        self.gaps = 0
        self.gap_spans: collections.deque = collections.deque(maxlen=64)  # (t0, t1) us
        self.arrivals: collections.deque = collections.deque()            # (arrival s, bytes)
        self.pending: collections.deque = collections.deque()             # RawBatch awaiting finality
        self.pending_samples = 0
        self.exact = ErrorWindow(self.error_window)
        self.live = ErrorWindow(self.error_window)
        self.latest_t_us: int | None = None      # newest device time seen (point or raw)
        self.latest_arrival = math.nan

    def _check_stream(self, stream: int) -> bool:
        """True if ``stream`` is the current stream (starting it or a new one if needed)."""
        if stream == self.stream:
            return True
        if stream in self._retired:
            self.dropped["stale_stream"] += 1
            return False
        if self.stream is not None:
            self._retired.append(self.stream)
            self.restarts += 1
        self.stream = stream
        self._reset_stream()
        return True

    # ------------------------------------------------------------------ input

    def add_point(self, p: wire.SegmentPoint, nbytes: int, now: float) -> bool:
        """Accept a decoded segment point; False (and counted by reason) if dropped."""
        if not self._check_stream(p.stream):
            return False
        if self.next_seq is not None and p.seq < self.next_seq:
            self.dropped["duplicate"] += 1
            return False
        if self.n and (p.t_us <= self.t[self.n - 1] or p.index <= self.last_index):
            self.dropped["time_backwards"] += 1
            return False
        if self.next_seq is not None and p.seq > self.next_seq:
            self.gaps += p.seq - self.next_seq
            self.gap_spans.append((int(self.t[self.n - 1]) if self.n else p.t_us, p.t_us))
        if self.n == self.capacity:  # frames stalled far behind: forget the oldest half
            self.dropped["buffer_full"] += self.n // 2
            self._shift(self.n // 2)
        self.t[self.n] = p.t_us
        self.q[self.n] = p.q
        self.n += 1
        self.next_seq = p.seq + 1
        self.points += 1
        self.last_index = p.index
        self.final = bool(p.flags & wire.FLAG_FINAL)
        self.arrivals.append((now, nbytes))
        self._see(p.t_us, now)
        return True

    def add_raw(self, batch: wire.RawBatch, now: float) -> bool:
        """Accept a truth-tap batch of the current stream; False (counted) otherwise."""
        if batch.stream != self.stream:
            self.dropped["raw_other_stream"] += 1
            return False
        self.pending.append(batch)
        self.pending_samples += len(batch.t_us)
        while self.pending_samples > self.max_pending:
            old = self.pending.popleft()
            self.pending_samples -= len(old.t_us)
            self.dropped["raw_overflow"] += len(old.t_us)
        self.last_raw_index = max(self.last_raw_index, batch.first_index + len(batch.t_us) - 1)
        self._see(int(batch.t_us[-1]), now)
        return True

    def _see(self, t_us: int, now: float) -> None:
        if self.latest_t_us is None or t_us >= self.latest_t_us:
            self.latest_t_us, self.latest_arrival = t_us, now

    # ------------------------------------------------------------------ reconstruction

    @property
    def watermark(self) -> int | None:
        """Time (us) up to which this device's reconstruction is final: its newest point."""
        return int(self.t[self.n - 1]) if self.n else None

    @property
    def first_t(self) -> int | None:
        return int(self.t[0]) if self.n else None

    def orientation_at(self, t_us: np.ndarray) -> np.ndarray:
        """(F, 4) SLERP reconstruction at times ``t_us`` (F,); held before the first / after the last point."""
        if self.n == 0:
            return np.tile([1.0, 0.0, 0.0, 0.0], (len(t_us), 1))
        return quat.interpolate(self.t[: self.n], self.q[: self.n], np.asarray(t_us, np.float64))

    def held_at(self, t_us: np.ndarray) -> np.ndarray:
        """(F, 4) the last point strictly before each time (what a receiver holds "now")."""
        k = np.clip(np.searchsorted(self.t[: self.n], t_us, side="left") - 1, 0, max(self.n - 1, 0))
        return self.q[k]

    def in_gap(self, t_us: np.ndarray) -> np.ndarray:
        """(F,) bool: times inside a span whose points were lost."""
        flags = np.zeros(len(t_us), bool)
        for t0, t1 in self.gap_spans:
            flags |= (t_us > t0) & (t_us < t1)
        return flags

    def evaluate_truth(self) -> int:
        """Angular error at every pending truth sample whose reconstruction is final. Returns how many."""
        wm = self.watermark
        if wm is None:
            return 0
        done = 0
        while self.pending:
            batch = self.pending[0]
            ready = batch.t_us <= wm
            if not ready.any():
                break
            t_ready = batch.t_us[ready]
            truth = batch.q[ready].astype(np.float64)
            self.exact.extend(quat.angle_deg(self.orientation_at(t_ready), truth))
            self.live.extend(quat.angle_deg(self.held_at(t_ready), truth))
            done += len(t_ready)
            if ready.all():
                self.pending.popleft()
                self.pending_samples -= len(batch.t_us)
            else:
                rest = ~ready
                self.pending[0] = wire.RawBatch(batch.stream, batch.first_index + int(ready.sum()),
                                                batch.t_us[rest], batch.q[rest])
                self.pending_samples -= int(ready.sum())
                break
        return done

    def prune(self, needed_from_us: int) -> None:
        """Forget points no frame or pending truth sample needs (keep one before ``needed_from_us``)."""
        if self.pending:
            needed_from_us = min(needed_from_us, int(self.pending[0].t_us[0]))
        k = int(np.searchsorted(self.t[: self.n], needed_from_us, side="right")) - 2
        if k > 0 and k > self.n // 4:
            self._shift(k)

    def _shift(self, k: int) -> None:
        self.t[: self.n - k] = self.t[k: self.n]
        self.q[: self.n - k] = self.q[k: self.n]
        self.n -= k

    # ------------------------------------------------------------------ figures

    def stats(self, now: float) -> dict:
        """The device entry of a stats message (wire.STATS_FIELDS and a few extras)."""
        while self.arrivals and self.arrivals[0][0] < now - RATE_WINDOW_S:
            self.arrivals.popleft()
        span = RATE_WINDOW_S
        if self.arrivals and self.points == len(self.arrivals):  # stream younger than the window
            span = max(now - self.arrivals[0][0], 1.0)
        samples = max(self.last_index, self.last_raw_index) + 1
        aad, p99, mx = self.exact.summary()
        live, _, _ = self.live.summary()
        lag = math.nan
        if self.latest_t_us is not None and self.n:
            device_now = self.latest_t_us + (now - self.latest_arrival) * 1e6
            lag = 0.0 if self.final else max(0.0, (device_now - self.t[self.n - 1]) / 1e6)
        return {
            "device": self.id, "segment": self.segment, "subject": self.subject, "online": self.online,
            "samples": samples, "points": self.points,
            "icr": self.points / samples if samples > 0 else math.nan,
            "msgs_per_s": len(self.arrivals) / span,
            "bytes_per_s": sum(b for _, b in self.arrivals) / span,
            "aad_deg": aad, "p99_deg": p99, "max_deg": mx, "live_err_deg": live,
            "aad_all_deg": self.exact.mean_all, "error_samples": self.exact.count,
            "watermark_lag_s": lag, "gaps": self.gaps, "dropped": sum(self.dropped.values()),
            "dropped_by_reason": dict(self.dropped), "threshold": self.threshold, "max_len": self.max_len,
            "stream": self.stream, "restarts": self.restarts, "final": self.final,
        }
