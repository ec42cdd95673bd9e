"""Replay: a recording's devices publish again — their segment points and truth batches, on
their keys, at the recorded receive times scaled by a speed — so an aggregator rebuilds the
same frames.

Each replayed device is declared like an emulated one (device_emulator/emulator.py): an
advanced publisher with a cache and miss detection for its segment points (congestion control
BLOCK), one for its truth batches, and a liveliness token. Payloads go out as recorded (the
aggregator decodes and checks them like any device's). With ``loop``, every later pass is a new
stream of each device (stream id + pass) with its times shifted past the previous pass
(:data:`PASS_GAP_NS` after it).
Pose frames, stats and config statuses of the recording are not published: the aggregator
makes its own; replayed devices serve no config queryable.
"""
from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import zenoh
import zenoh.ext as zext

from limbstream import wire

from .recording import Entry, Recording

PASS_GAP_NS = 1_000_000_000
"""With ``loop``, a pass starts this long (recorded time, ns) after the previous one's last message."""


@dataclass(frozen=True)
class ReplaySettings:
    """How a recording is replayed.

    Attributes
    ----------
    speed : time scale: 1 = as recorded, 20 = twenty times faster.
    loop : start again after the end (each pass a new stream of every device), until stopped.
    subject_prefix : put before every subject name (``r-`` turns ``s01`` into ``r-s01``).
    truth : publish the truth batches too.
    cache : segment points each device keeps for recovery (advanced publisher cache).
    heartbeat_s : miss-detection heartbeat period, seconds.
    hold_s : devices stay online this long after the last message (recovery, late joiners), s.
    """

    speed: float = 1.0
    loop: bool = False
    subject_prefix: str = ""
    truth: bool = True
    cache: int = 512
    heartbeat_s: float = 0.5
    hold_s: float = 2.0


@dataclass
class ReplayStats:
    """Counters of a replay."""

    published: collections.Counter = field(default_factory=collections.Counter)  # by kind
    passes: int = 0
    undecodable: collections.Counter = field(default_factory=collections.Counter)  # published as recorded
    skipped: collections.Counter = field(default_factory=collections.Counter)  # keys outside the grammar
    recorded_s: float = 0.0  # recorded time covered so far (receive times), s


class Replayer:
    """Publishes ``recording``'s devices on ``session`` (see the module docstring)."""

    def __init__(self, session: zenoh.Session, recording: Recording, settings: ReplaySettings):
        self.session, self.recording, self.settings = session, recording, settings
        self.stats = ReplayStats()
        self._publishers: dict[tuple[str, str], object] = {}  # (key, kind) -> advanced publisher
        self._tokens: dict[str, object] = {}  # alive key -> liveliness token
        self.devices: set[str] = set()

    # ------------------------------------------------------------------ devices

    def _target(self, entry: Entry) -> str | None:
        """The key ``entry`` goes out on (subject renamed), or None (counted) if it is not a device key."""
        try:
            subject, segment, kind = wire.parse_device_key(entry.key)
            if kind != entry.kind:
                raise wire.WireError("key", f"{kind} key on the {entry.kind} channel")
            subject = wire.check_chunk(self.settings.subject_prefix + subject, "subject")
        except (wire.WireError, ValueError):
            self.stats.skipped[entry.kind] += 1
            return None
        key = wire.device_key(subject, segment, entry.kind)
        if (key, entry.kind) not in self._publishers:
            self._declare(subject, segment, entry.kind, key)
        return key

    def _declare(self, subject: str, segment: str, kind: str, key: str) -> None:
        s = self.settings
        if kind == "seg":
            pub = zext.declare_advanced_publisher(
                self.session, key, cache=zext.CacheConfig(max_samples=s.cache),
                sample_miss_detection=zext.MissDetectionConfig(heartbeat=s.heartbeat_s), publisher_detection=True,
                congestion_control=zenoh.CongestionControl.BLOCK)
        else:
            pub = zext.declare_advanced_publisher(
                self.session, key, cache=zext.CacheConfig(max_samples=64),
                sample_miss_detection=zext.MissDetectionConfig(heartbeat=s.heartbeat_s), publisher_detection=True)
        self._publishers[(key, kind)] = pub
        alive = wire.alive_key(subject, segment)
        if alive not in self._tokens:
            self._tokens[alive] = self.session.liveliness().declare_token(alive)
            self.devices.add(wire.device_id(subject, segment))

    def close(self) -> None:
        """Devices go offline: tokens and publishers undeclared."""
        for entity in list(self._tokens.values()) + list(self._publishers.values()):
            entity.undeclare()
        self._tokens.clear()
        self._publishers.clear()

    # ------------------------------------------------------------------ passes

    def _payload(self, entry: Entry, n_pass: int, shift_us: int) -> bytes:
        """The recorded payload; in a later pass, a new stream (id + pass) shifted by ``shift_us``."""
        if n_pass == 0:
            return entry.payload
        try:
            if entry.kind == "seg":
                p = wire.decode_point(entry.payload)
                return wire.encode_point(replace(p, stream=(p.stream + n_pass) & 0xFFFF, t_us=p.t_us + shift_us))
            b = wire.decode_raw(entry.payload)
            return wire.encode_raw(replace(b, stream=(b.stream + n_pass) & 0xFFFF, t_us=b.t_us + shift_us))
        except wire.WireError:
            return entry.payload

    def _check(self, entry: Entry) -> None:
        """Count a payload the aggregator will refuse (it is published all the same, as recorded)."""
        try:
            (wire.decode_point if entry.kind == "seg" else wire.decode_raw)(entry.payload)
        except wire.WireError as exc:
            self.stats.undecodable[f"{entry.kind}_{exc.reason}"] += 1

    def run(self, stop: threading.Event, on_progress: Callable[[str], None] | None = None,
            progress_s: float = 5.0) -> ReplayStats:
        """Publish pass after pass (one without ``loop``) until the end or ``stop``; then hold the
        devices online for ``hold_s`` and take them offline."""
        s = self.settings
        kinds = ("seg", "raw") if s.truth else ("seg",)
        start = time.monotonic()
        offset_ns = 0  # recorded time of the passes before this one
        next_progress = start + progress_s
        while not stop.is_set():
            t0 = last = None
            n_pass = self.stats.passes
            for entry in self.recording.entries(kinds):
                if t0 is None:
                    t0 = entry.log_ns
                last = max(last or entry.log_ns, entry.log_ns)
                due = start + (offset_ns + entry.log_ns - t0) / 1e9 / s.speed
                wait = due - time.monotonic()
                if wait > 0 and stop.wait(wait):
                    break
                key = self._target(entry)
                if key is None:
                    continue
                if n_pass == 0:
                    self._check(entry)
                self._publishers[(key, entry.kind)].put(self._payload(entry, n_pass, offset_ns // 1000))
                self.stats.published[entry.kind] += 1
                self.stats.recorded_s = (offset_ns + entry.log_ns - t0) / 1e9
                if on_progress is not None and time.monotonic() >= next_progress:
                    on_progress(self.progress(time.monotonic() - start))
                    next_progress += progress_s
            self.stats.passes += 1
            if t0 is None or not s.loop:
                break
            offset_ns += last - t0 + PASS_GAP_NS  # the next pass starts a second after this one
        stop.wait(s.hold_s)
        self.close()
        return self.stats

    def progress(self, elapsed_s: float) -> str:
        total = sum(self.stats.published.values())
        return (f"replaying {self.stats.recorded_s:8.1f} s of recording in {elapsed_s:7.1f} s "
                f"(x{self.settings.speed:g}, pass {self.stats.passes + 1})  {total:,} messages  "
                f"{len(self.devices)} devices")
