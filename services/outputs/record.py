"""The recorder: everything of some subjects that crosses the router, into a recording
(:mod:`.recording`, MCAP).

Segment points and truth batches come through the outputs' subscription (advanced subscribers
with history: a recorder started after the devices still gets what their caches hold); pose
frames, joint angles and stats too; device config statuses are asked for every ``config_poll_s``
seconds and written when a device's settings or stream change (so a recording holds the layout a
subject's devices announce, which a layout file's frames are read back with). History can repeat a point already
received live: repeats are not written (``duplicates``). The recorder also counts what it can tell
is missing from sequence numbers (``missing``): segment points per device stream, pose frames and
joint angles per subject and kind, stats per subject.
"""
from __future__ import annotations

import collections
import json
import threading
import time
from dataclasses import dataclass, field

import zenoh

from limbstream import wire

from .recording import RecordingWriter, now_ns
from .subscription import Item, Subscription

FLUSH_S = 1.0
"""A chunk ends at least this often (seconds): what a killed recorder can lose."""


@dataclass
class SeqTracker:
    """Distinct sequence numbers of one stream: repeats and holes.

    ``window``: how far below the highest number seen repeats are still recognised."""

    window: int = 1 << 14
    seen: set = field(default_factory=set)
    low: int | None = None
    high: int | None = None
    distinct: int = 0

    def add(self, seq: int) -> bool:
        """False if ``seq`` was seen already (a repeat), else True."""
        if seq in self.seen:
            return False
        self.seen.add(seq)
        self.distinct += 1
        self.low = seq if self.low is None else min(self.low, seq)
        if self.high is None or seq > self.high:
            self.high = seq
            if len(self.seen) > 2 * self.window:
                self.seen = {s for s in self.seen if s > seq - self.window}
        return True

    @property
    def missing(self) -> int:
        return 0 if self.high is None else self.high - self.low + 1 - self.distinct


@dataclass
class RecorderStats:
    """Counters of a recorder run."""

    messages: collections.Counter = field(default_factory=collections.Counter)  # written, by kind
    duplicates: int = 0
    max_batch: int = 0  # most messages taken in one pass
    started: float = field(default_factory=time.monotonic)


class Recorder:
    """Subscribes to ``subjects`` and writes what comes into ``writer``.

    Parameters
    ----------
    session : an open Zenoh session (left open).
    writer : where messages go (closed by :meth:`close`).
    subjects : subject pattern (:func:`wire.subject_pattern`).
    truth : record truth-tap batches too.
    history : segment points per device asked for when joining.
    config_poll_s : how often device config statuses are asked for (0: never).
    """

    def __init__(self, session: zenoh.Session, writer: RecordingWriter, subjects: str = "*", truth: bool = True,
                 history: int = 512, config_poll_s: float = 5.0):
        self.session, self.writer, self.subjects = session, writer, subjects
        self.config_poll_s = config_poll_s
        kinds = (wire.SEG, wire.POSE, wire.ANGLES, wire.STATS) + ((wire.RAW,) if truth else ())
        self.subscription = Subscription(session, subjects, kinds, capacity=1 << 18, history=history)
        self.stats = RecorderStats()
        self._points: dict[tuple[str, int], SeqTracker] = {}
        self._seqs: dict[tuple[str, int], SeqTracker] = {}  # pose and angles (key, kind), stats (key, -1)
        self._configs: dict[str, tuple] = {}  # config key -> (config, stream) last written
        self._replies: list = []
        self._next_poll = time.monotonic() + 1.0
        self._next_flush = time.monotonic() + FLUSH_S

    # ------------------------------------------------------------------ one pass

    def step(self, timeout: float = 0.1) -> int:
        """Write what arrived (waiting at most ``timeout`` s for the first message), answer
        the config poll, flush when due. Returns messages taken."""
        first = self.subscription.get(timeout)
        items = self.subscription.drain(50_000)
        if first is not None:
            items.insert(0, first)
        for item in items:
            self._write(item)
        self.stats.max_batch = max(self.stats.max_batch, len(items))
        self._configs_step()
        if time.monotonic() >= self._next_flush:
            self.writer.flush()
            self._next_flush = time.monotonic() + FLUSH_S
        return len(items)

    def _write(self, item: Item) -> None:
        kind, value = item.kind, item.value
        if kind == "seg":
            tracker = self._points.get((item.key, value.stream))
            if tracker is None:
                tracker = self._points[(item.key, value.stream)] = SeqTracker()
            if not tracker.add(value.seq):
                self.stats.duplicates += 1
                return
        elif kind == "pose":
            self._count_seq((item.key, value.kind), value.seq)
            if value.kind == wire.KIND_EXACT:
                self.writer.add_skeleton(item.subject, value, item.received_ns)
        elif kind == "stats":
            self._count_seq((item.key, -1), value.get("seq"))
        elif kind == "angles":
            self._count_seq((item.key, value.kind), value.seq)
        self.writer.add(kind, item.key, item.payload, item.received_ns)
        self.stats.messages[kind] += 1

    def _count_seq(self, stream: tuple[str, int], seq: int | None) -> None:
        if seq is None:
            return
        tracker = self._seqs.get(stream)
        if tracker is None or (tracker.high is not None and seq < tracker.high - 1000):  # a restarted sender
            tracker = self._seqs[stream] = SeqTracker(window=4096)
        tracker.add(seq)

    def _configs_step(self) -> None:
        """Ask for device statuses when due; write those whose settings or stream changed."""
        now = time.monotonic()
        if self.config_poll_s > 0 and now >= self._next_poll:
            self._next_poll = now + self.config_poll_s
            self._replies.append(self.session.get(wire.device_selector(wire.CONFIG, self.subjects),
                                                  zenoh.handlers.FifoChannel(1 << 14), timeout=2.0))
        still_open = []
        for replies in self._replies:
            try:
                while (reply := replies.try_recv()) is not None:
                    if reply.ok is not None:
                        self._on_status(str(reply.ok.key_expr), reply.ok.payload.to_bytes())
                still_open.append(replies)
            except zenoh.ZError:  # the query is complete
                pass
        self._replies = still_open

    def _on_status(self, key: str, payload: bytes) -> None:
        try:
            subject, _, _ = wire.parse_device_key(key)
            status = wire.decode_status(payload)
        except wire.WireError:
            self.subscription.errors["config_reply"] += 1
            return
        self.subscription.layouts.learn(subject, status)  # a layout file's frames are read with it
        state = (status.config, status.stream)
        if self._configs.get(key) != state:
            self._configs[key] = state
            self.writer.add("config", key, payload, now_ns())
            self.stats.messages["config"] += 1

    # ------------------------------------------------------------------ figures

    @property
    def written(self) -> int:
        return sum(self.stats.messages.values())

    def missing(self) -> dict[str, int]:
        """What sequence numbers say is missing: segment points, pose frames, joint angles, stats."""
        subject_kinds: collections.Counter = collections.Counter()
        for (key, _), tracker in self._seqs.items():
            subject_kinds[key.rsplit("/", 1)[-1]] += tracker.missing  # the key's kind: pose, angles, stats
        return {"seg": sum(t.missing for t in self._points.values()),
                **{kind: subject_kinds[kind] for kind in (wire.POSE, wire.ANGLES, wire.STATS)}}

    def progress(self) -> str:
        """One line: duration, messages, MB, rate."""
        elapsed = time.monotonic() - self.stats.started
        lost = sum(self.subscription.errors.values())
        return (f"recording {elapsed:7.1f} s  {self.written:,} messages  {self.writer.size / 1e6:,.1f} MB  "
                f"{self.written / max(elapsed, 1e-9):,.0f} msg/s" + (f"  {lost:,} dropped" if lost else ""))

    def summary(self) -> dict:
        """Counters for the final report (JSON-ready)."""
        return {"file": str(self.writer.path), "seconds": round(time.monotonic() - self.stats.started, 3),
                "messages": dict(self.stats.messages), "bytes": self.writer.size,
                "duplicates": self.stats.duplicates, "max_batch": self.stats.max_batch, "missing": self.missing(),
                "dropped": dict(self.subscription.errors)}

    def run(self, stop: threading.Event, duration_s: float | None = None, on_progress=None,
            progress_s: float = 1.0) -> None:
        """Record until ``stop`` is set or ``duration_s`` seconds passed; ``on_progress(line)``
        every ``progress_s`` seconds."""
        end = None if duration_s is None else self.stats.started + duration_s
        next_progress = time.monotonic() + progress_s
        while not stop.is_set() and (end is None or time.monotonic() < end):
            self.step(0.05)
            if on_progress is not None and time.monotonic() >= next_progress:
                on_progress(self.progress())
                next_progress += progress_s
        self.step(0.0)  # what is already in the channel

    def close(self) -> None:
        """Stop subscribing and close the file properly (indexes, summary)."""
        self.subscription.close()
        self.writer.close()


def summary_line(summary: dict) -> str:
    return "record: " + json.dumps(summary, separators=(", ", ": "))
