"""Replay: a recording's devices publish again — their segment points and truth batches, on
their keys, at the recorded receive times scaled by a speed — so an aggregator rebuilds the
same frames.

Each replayed device is a device of a device host (:mod:`limbstream.device.host`), as an
emulated one: an advanced publisher with a cache and miss detection for its segment points, one
for its truth batches, a liveliness token, and a config queryable per subject. Payloads go out as
recorded (the aggregator decodes and checks them like any device's).
With ``loop``, every later pass is a new stream of each device (stream id + pass) with its times
shifted past the previous pass (:data:`PASS_GAP_NS` after it).

Pose frames, joint angles, stats and config statuses of the recording are not published: the
aggregator makes its own. A config query is answered with the device's status (``wire.DeviceStatus``):
its settings as the recording last gave them up to the replayed moment (its recorded config
status, else the tunables of its stats row; its rest pose and what its orientations are, from
that status), its stream, samples and points as replayed. A
query that changes settings gets an error reply (:data:`FIXED`): the points were made with the
recorded settings.
"""
from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import zenoh

from limbstream import wire
from limbstream.body import Body
from limbstream.device.host import Device, DeviceHost, HostSettings, Refused

from .recording import Entry, Recording

PASS_GAP_NS = 1_000_000_000
"""With ``loop``, a pass starts this long (recorded time, ns) after the previous one's last message."""
FIXED = "replayed device: settings are fixed by the recording"
"""Error reply to a config query that would change a replayed device's settings."""
QUERY_POLL_S = 0.02
"""Config queries are answered within this long, seconds."""


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
class ReplayedDevice:
    """What a replayed device says in its status (see the module docstring)."""

    config: wire.DeviceConfig | None = None  # None: the recording has not given its settings (yet)
    clock: wire.ClockStatus | None = None
    rest_pose: str = wire.DEFAULT_REST_POSE
    orientations: str | None = None  # what the recorded device said its orientations are (wire.ORIENTATIONS)
    body: Body | None = None  # the wearer's dimensions the recorded device announced (None: none)
    from_status: bool = False  # config taken from a recorded status (stats rows then no longer count)
    stream: int = 0
    samples: int = 0
    points: int = 0


@dataclass
class ReplayStats:
    """Counters of a replay."""

    published: collections.Counter = field(default_factory=collections.Counter)  # by kind
    passes: int = 0
    # refused by the contract, by kind and reason: points and truth are published as recorded all the
    # same, config statuses and stats are not used
    undecodable: collections.Counter = field(default_factory=collections.Counter)
    skipped: collections.Counter = field(default_factory=collections.Counter)  # keys outside the grammar
    recorded_s: float = 0.0  # recorded time covered so far (receive times), s


class Replayer:
    """Publishes ``recording``'s devices on ``session`` (see the module docstring)."""

    def __init__(self, session: zenoh.Session, recording: Recording, settings: ReplaySettings):
        self.session, self.recording, self.settings = session, recording, settings
        self.stats = ReplayStats()
        self.host: DeviceHost = DeviceHost(session, HostSettings(truth=settings.truth, cache=settings.cache,
                                                                 heartbeat_s=settings.heartbeat_s),
                                           self._refuse, self._status)
        self.host.declare()
        self._state: dict[str, ReplayedDevice] = collections.defaultdict(ReplayedDevice)  # by device id
        self._next_answer = 0.0

    @property
    def devices(self) -> set[str]:
        """The ids of the devices replayed so far."""
        return set(self.host.by_id)

    # ------------------------------------------------------------------ devices

    def _target(self, entry: Entry) -> Device | None:
        """The device ``entry`` goes out from (subject renamed; online from its first message), or
        None (counted) if its key is not a device key."""
        try:
            subject, segment, kind = wire.parse_device_key(entry.key)
            if kind != entry.kind:
                raise wire.WireError("key", f"{kind} key on the {entry.kind} channel")
            subject = wire.check_chunk(self.settings.subject_prefix + subject, "subject")
        except (wire.WireError, ValueError):
            self.stats.skipped[entry.kind] += 1
            return None
        d = self.host.by_id.get(wire.device_id(subject, segment))
        if d is None:
            d = self.host.add(subject, segment)
            self.host.online(d)
        return d

    def close(self) -> None:
        """Devices go offline: tokens, publishers and queryables undeclared."""
        self.host.close()

    # ------------------------------------------------------------------ config queries

    def _renamed(self, did: str) -> str | None:
        """A recorded device id with the subject prefix, or None if it is not one."""
        try:
            subject, segment = wire.split_device_id(did)
            return wire.device_id(self.settings.subject_prefix + subject, segment)
        except ValueError:
            return None

    def _absorb(self, entry: Entry) -> None:
        """A recorded config status or stats message: the settings its devices ran (not published)."""
        try:
            if entry.kind == "config":
                status = wire.decode_status(entry.payload)
                subject, segment, _ = wire.parse_device_key(entry.key)
                did = self._renamed(wire.device_id(subject, segment))
                if did is not None:
                    state = self._state[did]
                    state.config, state.clock, state.from_status = status.config, status.clock, True
                    state.rest_pose, state.orientations = status.rest_pose, status.orientations
                    state.body = status.body
                return
            for row in wire.decode_stats(entry.payload)["devices"]:
                did = self._renamed(row.get("device", ""))
                if did is not None and not self._state[did].from_status:
                    self._state[did].config = wire.DeviceConfig(
                        **{name: t.check(row[name]) for name, t in wire.TUNABLES.items()})
        except wire.WireError as exc:
            self.stats.undecodable[f"{entry.kind}_{exc.reason}"] += 1
        except (ValueError, KeyError, TypeError):  # a stats row without valid tunables
            self.stats.undecodable[f"{entry.kind}_row"] += 1

    def _replayed(self, d: Device, payload: bytes) -> None:
        """A segment point went out from device d: its stream, samples and points."""
        try:
            point = wire.decode_point(payload)
        except wire.WireError:
            return
        state = self._state[d.id]
        if point.stream != state.stream:
            state.stream, state.points = point.stream, 0
        state.samples, state.points = point.index + 1, state.points + 1

    def _refuse(self, d: Device, config: wire.DeviceConfig) -> None:
        raise Refused(FIXED)

    def _status(self, d: Device) -> wire.DeviceStatus:
        state = self._state[d.id]
        if state.config is None:
            raise Refused(f"replayed device {d.id}: the recording holds no settings of it (yet)")
        return wire.DeviceStatus(d.id, state.config, state.stream, state.samples, state.points, state.clock,
                                 state.rest_pose, orientations=state.orientations, body=state.body)

    def answer_queries(self) -> None:
        """Answer the config queries that arrived (status, or :data:`FIXED` for a change)."""
        self.host.answer_queries()

    def _wait(self, stop: threading.Event, seconds: float) -> bool:
        """Wait ``seconds`` (True if ``stop`` was set meanwhile), answering config queries every
        :data:`QUERY_POLL_S` at most."""
        end = time.monotonic() + seconds
        while True:
            now = time.monotonic()
            if now >= self._next_answer:
                self.answer_queries()
                self._next_answer = now + QUERY_POLL_S
            left = end - now
            if left <= 0:
                return stop.is_set()
            if stop.wait(min(left, max(self._next_answer - now, 0.0))):
                return True

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
        kinds = (wire.SEG, wire.RAW, wire.CONFIG, wire.STATS) if s.truth else (wire.SEG, wire.CONFIG, wire.STATS)
        start = time.monotonic()
        offset_ns = 0  # recorded time of the passes before this one
        next_progress = start + progress_s
        while not stop.is_set():
            t0 = last = None
            n_pass = self.stats.passes
            for entry in self.recording.entries(kinds):
                if entry.kind in ("config", "stats"):  # taken when read: they do not set the pace
                    if n_pass == 0:
                        self._absorb(entry)
                    continue
                if t0 is None:
                    t0 = entry.log_ns
                last = max(last or entry.log_ns, entry.log_ns)
                due = start + (offset_ns + entry.log_ns - t0) / 1e9 / s.speed
                if self._wait(stop, due - time.monotonic()):
                    break
                d = self._target(entry)
                if d is None:
                    continue
                if n_pass == 0:
                    self._check(entry)
                payload = self._payload(entry, n_pass, offset_ns // 1000)
                if entry.kind == "seg":
                    self.host.publish(d, payload)
                    self._replayed(d, payload)
                else:
                    self.host.publish_raw(d, payload)
                self.stats.published[entry.kind] += 1
                self.stats.recorded_s = (offset_ns + entry.log_ns - t0) / 1e9
                if on_progress is not None and time.monotonic() >= next_progress:
                    on_progress(self.progress(time.monotonic() - start))
                    next_progress += progress_s
            self.stats.passes += 1
            if t0 is None or not s.loop:
                break
            offset_ns += last - t0 + PASS_GAP_NS  # the next pass starts a second after this one
        self._wait(stop, s.hold_s)
        self.close()
        return self.stats

    def progress(self, elapsed_s: float) -> str:
        total = sum(self.stats.published.values())
        return (f"replaying {self.stats.recorded_s:8.1f} s of recording in {elapsed_s:7.1f} s "
                f"(x{self.settings.speed:g}, pass {self.stats.passes + 1})  {total:,} messages  "
                f"{len(self.devices)} devices")
