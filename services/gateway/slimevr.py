"""The SlimeVR gateway: a UDP server that speaks the SlimeVR tracker protocol
(:mod:`.slimevr_protocol`) and turns every tracker sensor into a limbstream device
(docs/protocol.md, "SlimeVR gateway").

One thread does everything: it waits on the socket until the next tick, decodes each datagram
and answers trackers as a SlimeVR server does (handshake, sensor info, feature flags, a heartbeat
and a ping every 0.5 s), and at each tick of the device rate runs fastSW for every device in one
:class:`limbstream.kernel.SegmenterBank` call, as the emulator does, publishing segment points,
the truth tap and liveliness with the emulator's device pieces (:mod:`..device_emulator.device_io`).

Timing: each packet is stamped on arrival (the gateway's clock, synchronised to the common time
base by :class:`SyncClient`, one clock for all). Trackers send at their own irregular rate; each
device samples its tracker on a uniform grid of its own, placed on the lower edge of its packets'
arrivals (:meth:`SlimeVRGateway._lock_phase`), at the newest instant at least ``delay`` (default
30 ms) in the past: the SLERP of the two packets around that instant, or the newest packet held
when none has arrived after it yet (counted: ``held``). A packet that arrives less than half a
period after an instant was delayed on its way (arrival jitter), not taken later: it is that
instant's sample, and the truth tap stamps it at that instant (the sample's own stamp). The truth
tap carries every packet, each other one at its arrival, so a device's errors are measured
against the tracker's own full-rate stream.

Devices: a sensor's segment comes from ``--assign`` (MAC[/SENSOR]=[SUBJECT/]SEGMENT), else from
the body position it reports in its sensor info (:data:`POSITION_SEGMENTS`); a sensor with
neither, or whose device is fed by another sensor, is listed (``unassigned``), not published.
The gateway's queryable (``limbstream/@gateway/<name>``, :meth:`SlimeVRGateway.answer_admin`)
lists the sensors and moves one to another device, or to none, at run time. A
tracker silent for ``timeout`` (1 s, as a SlimeVR server) goes offline: its devices end their
streams (FINAL) and drop their liveliness tokens; when it sends again, each starts a new stream.

Times are microseconds unless named otherwise.
"""
from __future__ import annotations

import bisect
import collections
import itertools
import json
import logging
import math
import random
import select
import socket
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import zenoh

from limbstream import kernel, quat, wire
from limbstream.device_emulator import device_io
from limbstream.device_emulator.device_clocks import ClockSettings, DeviceClocks, TimeBase
from limbstream.device_emulator.sync_client import SyncClient
from limbstream.services.gateway import assignments
from limbstream.services.gateway import slimevr_protocol as proto

log = logging.getLogger("limbstream.gateway.slimevr")

AXES = (math.cos(math.pi / 4), -math.sin(math.pi / 4), 0.0, 0.0)
"""-90 degrees about X (w, x, y, z): a tracker's axes (Z up) to limbstream's (Y up), as the
SlimeVR server turns them."""
AXES_T = quat.left_matrix(AXES).T
"""``q @ AXES_T``: (..., 4) quaternions in a tracker's axes turned into limbstream's (AXES * q)."""
RING = 64
"""Ticks of samples each device keeps: a segment point refers to the device's newest sample or the
one before, at most QUIET_TICKS ticks back."""
QUIET_TICKS = RING - 2
"""A device without a sample for this many ticks (its sensor stopped sending rotations) ends its
stream; its next rotation starts a new one."""
HISTORY = 16
"""Packets each device keeps for its grid samples."""
PHASE_GAIN = 0.02
"""Share of a late packet's offset from its device's grid instant the grid moves by."""
JITTER_WINDOW = 500
"""Packets over which a device's arrival jitter (offset from its grid instant) is reported."""
LATE_SHARE = 0.5
"""A packet that arrives less than this share of a period after its device's grid instant was
delayed on its way: it is that instant's sample (a tracker faster than the grid has its packets
in between: then the SLERP of the two around the instant)."""
EARLY_SHARE = 0.05
"""A packet that arrives less than this share of a period before its device's grid instant is that
instant's sample too: the grid moves later by PHASE_GAIN of each late packet's offset, so the
packet that set the lower edge can end up just before its instant."""
HOLD_PERIODS = 2
"""A device holds its newest packet this many grid periods at most, then takes no sample."""
RECV_BUDGET = 4096
"""Datagrams read at most between two checks of the tick clock."""
RATE_WINDOW_S = 5.0
"""Packets per second are counted over this window."""
TRUTH_MAX_AGE_S = 0.5
"""A device's truth samples wait at most this long for a full batch."""
QUERIES_PER_TICK = 10
RCVBUF = 4 << 20
"""Socket receive buffer asked for, bytes (the system may cap it: net.core.rmem_max)."""


def quaternions(qs: Sequence) -> np.ndarray:
    """(n, 4) float64 array of n (w, x, y, z) tuples (a few times quicker than np.array on
    tuples of floats)."""
    return np.fromiter(itertools.chain.from_iterable(qs), np.float64, 4 * len(qs)).reshape(-1, 4)


@dataclass(frozen=True)
class GatewaySettings:
    """What one gateway runs.

    Attributes
    ----------
    subject : the subject of sensors placed by their body position.
    name : the gateway's name: its queryable is ``limbstream/@gateway/<name>``.
    assign : {(tracker, sensor or None: every sensor): (subject, segment)}; tracker is its MAC
        (``AA:BB:CC:DD:EE:FF``) or, without one, ``ip:port``.
    fs : device sample rate (the grid), Hz.
    delay_ms : the grid samples trackers this long in the past (so a packet after the instant
        has usually arrived).
    config : initial fastSW settings of every device.
    truth : publish the truth tap (every packet).
    raw_batch : samples per truth-tap message at most.
    cache, heartbeat_s : the segment point publisher's cache and miss-detection heartbeat.
    timeout_s : a tracker silent this long goes offline.
    max_devices : devices the gateway can serve (bank size).
    clock : time sync (one clock: the gateway's).
    assignments_file : where run-time assignments are kept (:mod:`.assignments`): loaded at start,
        rewritten after each change; None: they last while the gateway runs.
    """

    subject: str
    name: str = "slimevr"
    assign: dict = field(default_factory=dict)
    fs: float = 50.0
    delay_ms: float = 30.0
    config: wire.DeviceConfig = wire.DeviceConfig()
    truth: bool = True
    raw_batch: int = 25
    cache: int = 512
    heartbeat_s: float = 0.5
    timeout_s: float = proto.TRACKER_TIMEOUT_S
    max_devices: int = 256
    clock: ClockSettings = field(default_factory=ClockSettings)
    assignments_file: str | None = None


@dataclass(slots=True)
class Tracker:
    """One tracker (a UDP address) and its link figures."""

    address: tuple
    name: str
    last_number: int = -1
    last_seen: float = 0.0             # monotonic s
    connected: float = 0.0             # monotonic s of its last handshake
    online: bool = True
    packets: int = 0                   # numbered packets taken
    lost: int = 0                      # missing packet numbers
    battery_pct: float | None = None
    signal_dbm: float | None = None
    ping_id: int = 0
    ping_sent: float = 0.0
    rtt_ms: float | None = None
    arrivals: collections.deque = field(default_factory=collections.deque)  # monotonic s of recent packets
    sensors: dict = field(default_factory=dict)  # sensor id -> Sensor

    def pps(self, now: float) -> float:
        """Packets per second over the last RATE_WINDOW_S (or since it connected, at least 1 s)."""
        while self.arrivals and self.arrivals[0] < now - RATE_WINDOW_S:
            self.arrivals.popleft()
        return len(self.arrivals) / max(1.0, min(RATE_WINDOW_S, now - self.connected))

    def loss(self) -> float | None:
        total = self.packets + self.lost
        return self.lost / total if total else None


@dataclass(slots=True)
class Sensor:
    """One sensor of a tracker."""

    tracker: Tracker
    sensor: int
    position: int | None = None
    device: Device | None = None
    why: str = "no body position and no --assign"  # why it has no device

    @property
    def name(self) -> str:
        return f"{self.tracker.name}/{self.sensor}"


@dataclass(slots=True)
class Device:
    """One limbstream device (a bank slot) and the sensor feeding it."""

    subject: str
    segment: str
    slot: int
    config: wire.DeviceConfig
    sensor: Sensor | None = None
    publisher: object = None
    raw_pub: object = None
    token: object = None
    online: bool = False
    streams: int = 0
    points: int = 0
    last: bytes | None = None
    hist_t: collections.deque = field(default_factory=lambda: collections.deque(maxlen=HISTORY))
    hist_q: collections.deque = field(default_factory=lambda: collections.deque(maxlen=HISTORY))
    truth_t: list = field(default_factory=list)  # common-time stamps of packets not yet on the tap
    truth_q: list = field(default_factory=list)
    truth_a: list = field(default_factory=list)  # and their arrivals (gateway clock)
    truth_since: float = 0.0                     # monotonic s of the oldest of them
    raw_index: int = 0                           # index of the next truth sample in the stream
    held: int = 0                                # grid samples held (no packet after the instant yet)
    quiet: int = 0                               # ticks since its last grid sample
    last_t: int = 0                              # common-time stamp of its last grid sample
    instant: float | None = None                 # its grid instant of the last tick (None: none yet)
    anchor: float | None = None                  # arrival of its stream's first packet: where its grid starts
    shift: float = 0.0                           # correction of its grid since the last tick
    no_rise: int = 0                             # packets before its grid may move later again
    jitter: collections.deque = field(default_factory=lambda: collections.deque(maxlen=JITTER_WINDOW))  # us

    @property
    def id(self) -> str:
        return wire.device_id(self.subject, self.segment)


class SlimeVRGateway:
    """Trackers in, devices out.

    Parameters
    ----------
    session : an open Zenoh session (client).
    sock : a bound UDP socket (made non-blocking here).
    settings : GatewaySettings.
    """

    def __init__(self, session: zenoh.Session, sock: socket.socket, settings: GatewaySettings):
        self.session, self.sock, self.settings = session, sock, settings
        sock.setblocking(False)
        try:  # room for bursts: a hundred trackers' packets while a tick runs
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF)
        except OSError:
            pass
        c = settings.config
        n = settings.max_devices
        self.bank = kernel.SegmenterBank(n, c.threshold, c.max_len, live_bound_deg=c.live_bound_deg, ring=RING)
        self.calls = np.zeros(n, np.int64)   # update calls of each slot since its reset (the kernel's index)
        self.n = np.zeros(n, np.int64)       # grid samples each slot has taken
        self.devices: dict[str, Device] = {}
        self.slots: list[Device] = []
        self.trackers: dict[tuple, Tracker] = {}
        self.dropped: collections.Counter = collections.Counter()  # datagrams dropped, by reason
        self.ignored: collections.Counter = collections.Counter()  # packets read but not used, by type
        self.unassigned_samples = 0
        self.period_us = 1e6 / settings.fs
        self.delay_us = settings.delay_ms * 1e3
        self.hold_us = HOLD_PERIODS * self.period_us
        self.late_us = LATE_SHARE * self.period_us
        self.early_us = EARLY_SHARE * self.period_us
        self.rise_after = math.ceil(self.delay_us / self.period_us) + 2  # packets between one's arrival and its instant
        self.ring_q = np.zeros((RING, n, 4), np.float32)
        self.base = TimeBase()
        self.clocks = DeviceClocks(1, ClockSettings(), self.period_us, self.base)
        self.sync = (SyncClient(session, self.clocks, settings.clock, ["slimevr-gateway"])
                     if settings.clock.sync else None)
        self.offset_us = 0.0       # common time base minus the gateway's clock, as stamped this tick
        self.ticks = self.late = 0
        self.busy_s = 0.0
        self.start_us = 0.0
        self._queries: list = []
        self._admin = None
        # run-time assignments, as settings.assign; None: none (ValueError: a bad assignments file)
        kept = assignments.load(settings.assignments_file) if settings.assignments_file else {}
        self.assigned: dict[tuple, tuple | None] = {k: t and (t[0] or settings.subject, t[1]) for k, t in kept.items()}
        self._subjects = sorted({settings.subject} | {s for s, _ in settings.assign.values()})

    # ------------------------------------------------------------------ devices

    def declare(self) -> None:
        """One config queryable per subject the gateway may serve (devices are declared as
        their trackers appear)."""
        for subject in self._subjects:
            self._serve_subject(subject)
        self._admin = self.session.declare_queryable(wire.gateway_key(self.settings.name),
                                                     zenoh.handlers.FifoChannel(256))

    def _serve_subject(self, subject: str) -> None:
        """Declare the config queryable of ``subject``'s devices, unless it is declared."""
        if all(s != subject for _, s in self._queries):
            self._queries.append((self.session.declare_queryable(wire.device_selector("config", subject),
                                                                 zenoh.handlers.FifoChannel(1024)), subject))

    def undeclare(self) -> None:
        for d in self.slots:
            if d.online:
                self._end_stream(d)
            for obj in (d.publisher, d.raw_pub):
                if obj is not None:
                    obj.undeclare()
        for queryable, _ in self._queries:
            queryable.undeclare()
        if self._admin is not None:
            self._admin.undeclare()
            self._admin = None
        if self.sync is not None:
            self.sync.close()

    def _device(self, subject: str, segment: str) -> Device | None:
        """The device of (subject, segment), made (publishers, a bank slot) on first use; None when
        the bank is full."""
        did = wire.device_id(subject, segment)
        d = self.devices.get(did)
        if d is None:
            if len(self.slots) == self.settings.max_devices:
                return None
            s = self.settings
            self._serve_subject(subject)  # a run-time assignment may name a subject not served yet
            d = Device(subject, segment, len(self.slots), s.config)
            d.publisher = device_io.point_publisher(self.session, subject, segment, s.cache, s.heartbeat_s)
            if s.truth:
                d.raw_pub = device_io.raw_publisher(self.session, subject, segment, s.heartbeat_s)
            self.devices[did] = d
            self.slots.append(d)
        return d

    def _place(self, sensor: Sensor) -> None:
        """Give the sensor its device (run-time assignment, else --assign, else body position),
        if it can have one."""
        if sensor.device is not None:
            return
        key = (sensor.tracker.name, sensor.sensor)
        if key in self.assigned:
            target = self.assigned[key]
            if target is None:
                sensor.why = "unassigned at run time"
                return
        else:
            a = self.settings.assign
            target = a.get(key) or a.get((sensor.tracker.name, None))
            if target is None and sensor.position in proto.POSITION_SEGMENTS:
                target = (self.settings.subject, proto.POSITION_SEGMENTS[sensor.position])
        if target is None:
            sensor.why = (f"body position {sensor.position} has no segment" if sensor.position
                          else "no body position and no --assign")
            return
        refused = self._feed(sensor, *target)
        if refused:
            sensor.why = refused

    def _feed(self, sensor: Sensor, subject: str, segment: str) -> str | None:
        """Make ``sensor`` (without a device) feed device (subject, segment); the reason it
        cannot (one sentence), else None. A device fed by a sensor of an offline tracker is
        taken over; its stream, if still open, ends (the new sensor starts a new one)."""
        d = self._device(subject, segment)
        if d is None:
            return f"gateway full ({self.settings.max_devices} devices)"
        if d.sensor is not None and d.sensor is not sensor:
            if d.sensor.tracker.online:
                return f"{d.id} is fed by {d.sensor.name}"
            d.sensor.device = None
            d.sensor.why = f"{d.id} taken over by {sensor.name}"
            if d.online:
                self._end_stream(d)
        d.sensor, sensor.device = sensor, d
        log.info("%s -> %s", sensor.name, d.id)
        return None

    def _unfeed(self, sensor: Sensor, why: str) -> None:
        """The sensor feeds no device any more: its device's stream ends."""
        d = sensor.device
        if d is None:
            return
        if d.online:
            self._end_stream(d)
        d.sensor, sensor.device, sensor.why = None, None, why
        log.info("%s -> none (%s)", sensor.name, why)

    def assign(self, a: wire.Assignment) -> str | None:
        """Move a sensor the gateway has heard of to device (subject, segment), or to none
        (``segment`` None); the reason it is refused (one sentence), else None. The old device's
        stream ends (FINAL, token dropped); the new device starts a stream at the sensor's next
        rotation. Remembered over --assign and body positions while the gateway runs, and in its
        assignments file if it has one."""
        tracker = next((t for t in self.trackers.values() if t.name == a.tracker), None)
        sensor = tracker.sensors.get(a.sensor) if tracker is not None else None
        if sensor is None:
            return f"no sensor {a.tracker}/{a.sensor} has reported to gateway {self.settings.name}"
        key = (tracker.name, a.sensor)
        if a.segment is None:
            self._unfeed(sensor, "unassigned at run time")
            self._remember(key, None)
            return None
        target = (a.subject or self.settings.subject, a.segment)
        d = sensor.device
        if d is not None and (d.subject, d.segment) == target:
            self._remember(key, target)
            return None
        other = self.devices.get(wire.device_id(*target))
        if other is not None and other.sensor is not None and other.sensor.tracker.online:
            return f"{other.id} is fed by {other.sensor.name}: unassign it first"
        if other is None and len(self.slots) == self.settings.max_devices:  # (a device keeps its slot)
            return f"gateway full ({self.settings.max_devices} devices): no room for {wire.device_id(*target)}"
        self._unfeed(sensor, "moved")
        self._feed(sensor, *target)  # cannot be refused after the checks above
        self._remember(key, target)
        return None

    def _remember(self, key: tuple, target: tuple | None) -> None:
        """Keep a run-time assignment (and write the assignments file, if any: a failure is logged,
        the assignment holds while the gateway runs)."""
        self.assigned[key] = target
        if self.settings.assignments_file:
            try:
                assignments.save(self.settings.assignments_file, self.assigned)
            except OSError as exc:
                log.error("cannot write assignments file %s: %s", self.settings.assignments_file, exc)

    def sensors(self) -> list[dict]:
        """Every sensor heard of: ``{tracker, sensor, online, position, device, why}`` (wire.gateway)."""
        return [{"tracker": t.name, "sensor": s.sensor, "online": t.online, "position": s.position,
                 "device": s.device.id if s.device else None, "why": None if s.device else s.why}
                for t in sorted(self.trackers.values(), key=lambda t: t.name)
                for s in sorted(t.sensors.values(), key=lambda s: s.sensor)]

    def answer_admin(self) -> None:
        """Answer the gateway's queryable (queries waiting in its channel, at most
        QUERIES_PER_TICK): no payload lists the sensors; an assignment is applied, then they are
        listed. A bad or refused one gets an error reply ``{"error": sentence}``."""
        if self._admin is None:
            return
        for _ in range(QUERIES_PER_TICK):
            query = self._admin.try_recv()
            if query is None:
                return
            payload = query.payload.to_bytes() if query.payload is not None else b""
            if payload:
                try:
                    refused = self.assign(wire.decode_assignment(payload))
                except wire.WireError as exc:
                    refused = str(exc)
                if refused:
                    log.info("assignment refused: %s", refused)
                    query.reply_err(json.dumps({"error": refused}))
                    continue
            query.reply(wire.gateway_key(self.settings.name),
                        wire.encode_sensors(self.settings.name, self.settings.subject, self.sensors()))

    # ------------------------------------------------------------------ streams

    def _start_stream(self, d: Device) -> None:
        """A new stream: fresh kernel state, stream id and numbering; liveliness token."""
        b, k = self.bank, d.slot
        b.reset(k)
        self.calls[k] = 0
        b.stream[k], b.seq[k], b.base[k] = random.getrandbits(16), 0, self.n[k]
        d.points, d.last, d.raw_index, d.held, d.quiet = 0, None, 0, 0, 0
        d.instant = d.anchor = None
        d.shift, d.no_rise = 0.0, 0
        d.hist_t.clear()
        d.hist_q.clear()
        d.truth_t, d.truth_q, d.truth_a = [], [], []
        d.streams += 1
        d.online = True
        d.token = device_io.alive_token(self.session, d.subject, d.segment)
        log.info("%s: stream %d from %s", d.id, b.stream[k], d.sensor.name if d.sensor else "?")

    def _end_stream(self, d: Device) -> None:
        """End the device's stream: its last point (FINAL; or the newest point repeated with FINAL),
        its truth, its token."""
        b, k = self.bank, d.slot
        last = b.flush(k)
        if last is not None:  # the kernel's newest sample, not yet a point: the device's last grid sample
            omega = (0.0, 0.0, 0.0) if b.live(k) else None
            point = wire.SegmentPoint(int(b.stream[k]), int(b.seq[k]), int(self.n[k] - 1 - b.base[k]), d.last_t,
                                      tuple(float(v) for v in last[2]), wire.FLAG_FINAL, omega)
            d.publisher.put(wire.encode_point(point))
        elif d.last is not None:
            point = wire.decode_point(d.last)
            d.publisher.put(wire.encode_point(wire.SegmentPoint(
                point.stream, int(b.seq[k]), point.index, point.t_us, point.q, wire.FLAG_FINAL, point.omega)))
        b.seq[k] = (int(b.seq[k]) + 1) & 0xFFFFFFFF
        self._flush_truth(d, len(d.truth_t))
        if d.token is not None:
            d.token.undeclare()
            d.token = None
        d.online = False
        log.info("%s: stream %d ended", d.id, b.stream[k])

    # ------------------------------------------------------------------ datagrams

    def _send(self, payload: bytes, address: tuple) -> None:
        try:
            self.sock.sendto(payload, address)
        except OSError:  # a full buffer or an unreachable tracker: it asks again
            self.dropped["send_failed"] += 1

    def receive(self, now: float) -> int:
        """Read and handle the datagrams waiting (at most RECV_BUDGET); returns how many."""
        count = 0
        recvfrom, handle = self.sock.recvfrom, self.handle
        while count < RECV_BUDGET:
            try:
                data, address = recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. an ICMP error of an earlier send, reported here
                self.dropped["socket_error"] += 1
                continue
            count += 1
            handle(data, address, time.time_ns() / 1e3, now)
        return count

    def handle(self, data: bytes, address: tuple, t_us: float, now: float) -> None:
        """One datagram from ``address``, arrived at the gateway's clock ``t_us`` (monotonic
        ``now``, s). Bad ones are counted by reason and dropped. A lone rotation packet, nearly
        all of a tracker's traffic, takes the short way (:func:`proto.decode_rotation`)."""
        try:
            rotation = proto.decode_rotation(data)
            dg = proto.decode(data) if rotation is None else None
        except proto.ProtocolError as exc:
            self.dropped[exc.reason] += 1
            return
        if dg is not None and dg.type == proto.HANDSHAKE:
            self._handshake(address, dg.messages[0], now)  # type: ignore[arg-type]
            return
        tracker = self.trackers.get(address)
        if tracker is None:
            self.dropped["no_handshake"] += 1
            return
        if not self._count(tracker, rotation[0] if dg is None else dg.number, now):
            return
        if dg is None:
            self._rotation(tracker, rotation[1], rotation[2], t_us, now)  # type: ignore[index]
            return
        for m in dg.messages:
            if isinstance(m, proto.Rotation):
                self._rotation(tracker, m.sensor, m.q, t_us, now)
            elif isinstance(m, proto.SensorInfo):
                self._sensor(tracker, m.sensor).position = m.position
                self._place(tracker.sensors[m.sensor])
                self._send(proto.sensor_info_answer(m.sensor, m.status), address)
            elif isinstance(m, proto.Battery):
                tracker.battery_pct = round(m.level * 100.0, 2) if math.isfinite(m.level) else None
            elif isinstance(m, proto.Signal):
                tracker.signal_dbm = m.dbm
            elif isinstance(m, proto.Pong):
                if m.ping_id == tracker.ping_id:
                    tracker.rtt_ms = (now - tracker.ping_sent) * 1e3
            elif isinstance(m, proto.Other):
                if m.type == proto.FEATURE_FLAGS:
                    self._send(proto.feature_flags(), address)
                elif not m.known:
                    self.dropped["unknown_type"] += 1
                else:
                    self.ignored[m.type] += 1
            else:  # a handshake inside a bundle is refused by the decoder
                self.dropped["misplaced"] += 1

    def _count(self, tracker: Tracker, number: int, now: float) -> bool:
        """Count packet ``number`` of the tracker, heard at monotonic ``now`` (s): its loss (a gap
        in the numbers), its rate, its liveliness; False (dropped) when it is out of order."""
        if number != 0:  # a pong echoes the server's number 0; every other packet counts up
            if number <= tracker.last_number:
                self.dropped["out_of_order"] += 1
                return False
            if 0 <= tracker.last_number and number - tracker.last_number < 1 << 16:
                tracker.lost += number - tracker.last_number - 1
            tracker.last_number = number
            tracker.packets += 1
        tracker.last_seen = now
        tracker.arrivals.append(now)
        if not tracker.online:
            tracker.online = True
            log.info("tracker %s is back", tracker.name)
        return True

    def _handshake(self, address: tuple, hs: proto.Handshake, now: float) -> None:
        """A tracker looking for a server: known by its MAC (possibly from a new address) or its
        address, or new. Answered every time (the tracker repeats it until it hears us)."""
        name = hs.mac or f"{address[0]}:{address[1]}"
        tracker = self.trackers.get(address)
        if tracker is None or tracker.name != name:
            tracker = next((t for t in self.trackers.values() if t.name == name), None)
            if tracker is not None:
                del self.trackers[tracker.address]
                tracker.address = address
            else:
                tracker = Tracker(address, name, connected=now)
                log.info("tracker %s connected from %s:%d (firmware %s, protocol %d)", name, address[0],
                         address[1], hs.firmware or "?", hs.protocol)
            self.trackers[address] = tracker
        tracker.last_number = -1  # a tracker keeps its numbering across reconnects: loss counts from here
        tracker.last_seen = now
        tracker.online = True
        self._send(proto.handshake_answer(), address)

    def _sensor(self, tracker: Tracker, sensor_id: int) -> Sensor:
        sensor = tracker.sensors.get(sensor_id)
        if sensor is None:
            sensor = tracker.sensors[sensor_id] = Sensor(tracker, sensor_id)
        return sensor

    def _rotation(self, tracker: Tracker, sensor_id: int, q: tuple, t_us: float, now: float) -> None:
        """Sensor ``sensor_id`` of the tracker is at ``q`` (w, x, y, z, the tracker's axes: turned
        into limbstream's per tick and per truth batch, vectorised), arrived at ``t_us``."""
        sensor = tracker.sensors.get(sensor_id)
        d = sensor.device if sensor is not None else None
        if d is None:  # a new sensor, or one without a device yet
            sensor = self._sensor(tracker, sensor_id)
            self._place(sensor)
            d = sensor.device
            if d is None:
                self.unassigned_samples += 1
                return
        if not d.online:
            self._start_stream(d)
        if d.hist_t and t_us <= d.hist_t[-1]:  # the host clock stepped back: keep times increasing
            t_us = d.hist_t[-1] + 1.0
        self._lock_phase(d, t_us)
        d.hist_t.append(t_us)
        d.hist_q.append(q)
        if self.settings.truth:
            if not d.truth_t:
                d.truth_since = now
            d.truth_t.append(round(t_us + self.offset_us))
            d.truth_q.append(q)
            d.truth_a.append(t_us)

    def _lock_phase(self, d: Device, t_us: float) -> None:
        """Keep the device's grid instants on its tracker's packets, at their earliest arrivals:
        the grid starts at the stream's first packet; a packet that arrives within a quarter
        period before an instant moves the grid back to it at once, one after an instant moves
        it PHASE_GAIN of the way, unless an early packet came within the last ``rise_after``
        packets (its own instant, a delay later, must not move past it) (the grid follows the
        tracker's clock drift along the lower edge
        of the arrival jitter, so a packet's arrival is at or after its instant and the point
        made at that instant counts as known at the packet). A tracker faster than the grid has
        packets in between, which do not count."""
        if d.instant is None:
            if d.anchor is None:
                d.anchor = t_us
            return
        period = self.period_us
        r = (t_us - d.instant - d.shift + period / 2) % period - period / 2
        if abs(r) < period / 4:
            d.jitter.append(abs(r))
            if r < 0:  # early: back at once, and no rise until this packet's own instant has passed
                d.shift += r
                d.no_rise = self.rise_after
            elif d.no_rise > 0:
                d.no_rise -= 1
            else:
                d.shift += PHASE_GAIN * r

    def _next_instant(self, d: Device, at_us: float) -> float | None:
        """The device's grid instant for the tick whose gateway instant is ``at_us``: one period
        after its last, moved by the correction since (at most a quarter period), kept within the
        period up to ``at_us`` (the tracker's clock drift makes it skip an instant, or wait a
        tick, once in a long while); None when it waits or has no packet yet."""
        period = self.period_us
        if d.instant is None:
            if d.anchor is None:
                return None
            d.instant = d.anchor + math.floor((at_us - d.anchor) / period) * period
            return d.instant
        d.instant += period + max(-period / 4, min(period / 4, d.shift))
        d.shift = 0.0
        if d.instant <= at_us - period:
            d.instant += period
        if d.instant > at_us:
            d.instant -= period
            return None
        return d.instant

    def _restamp_truth(self, d: Device, arrival: float, t_us: int) -> None:
        """The truth sample of the packet that arrived at ``arrival`` (if not on the tap yet) is
        stamped ``t_us``."""
        i = bisect.bisect_left(d.truth_a, arrival)  # arrivals increase (_rotation)
        if i < len(d.truth_a) and d.truth_a[i] == arrival:
            d.truth_t[i] = t_us

    def _flush_truth(self, d: Device, n: int) -> None:
        """Put the device's first ``n`` truth samples on its tap."""
        if not n or d.raw_pub is None:
            return
        t = np.maximum.accumulate(np.array(d.truth_t[:n], np.int64))
        q = (quaternions(d.truth_q[:n]) @ AXES_T).astype(np.float32)
        d.raw_pub.put(wire.encode_raw(wire.RawBatch(int(self.bank.stream[d.slot]), d.raw_index, t, q)))
        d.raw_index += len(t)
        del d.truth_t[:n], d.truth_q[:n], d.truth_a[:n]
        if d.truth_t:
            d.truth_since = time.monotonic()

    def _settled_truth(self, d: Device) -> int:
        """How many of the device's truth samples keep their stamps: those that arrived before
        its last grid instant plus LATE_SHARE of a period (a later one may still be an instant's)."""
        edge = (d.instant if d.instant is not None else -math.inf) + self.late_us
        return bisect.bisect_left(d.truth_a, edge)  # arrivals increase (_rotation)

    # ------------------------------------------------------------------ ticks

    def _bracket(self, d: Device, at_us: float) -> tuple | None:
        """The device's tracker at the gateway's time ``at_us`` as (q0, q1, u): the nearest packet
        that arrived less than EARLY_SHARE of a period before the instant or less than LATE_SHARE
        after it (delayed on its way: the instant's own sample, and its truth sample is stamped at
        the instant), else the packets
        around it and where it falls between them (SLERP), or the newest packet twice if none is
        newer yet (held: counted when it is older than a quarter period) for at most HOLD_PERIODS
        grid periods; None before its first packet and after that hold (a tracker gone quiet: no
        sample). Tracker axes."""
        ts = d.hist_t
        if not ts or ts[0] > at_us or ts[-1] < at_us - self.hold_us:
            return None
        j = bisect.bisect_right(ts, at_us)  # ts[:j] arrived at or before the instant, ts[j:] after it
        before = at_us - ts[j - 1] if j and at_us - ts[j - 1] < self.early_us else math.inf
        after = ts[j] - at_us if j < len(ts) and ts[j] - at_us < self.late_us else math.inf
        own = None if before == after == math.inf else j - 1 if before <= after else j
        if own is not None:
            self._restamp_truth(d, ts[own], int(round(at_us + self.offset_us)))
            return d.hist_q[own], d.hist_q[own], 0.0
        if j == len(ts):
            if at_us - ts[-1] > self.period_us / 4:
                d.held += 1
            return d.hist_q[-1], d.hist_q[-1], 0.0
        return d.hist_q[j - 1], d.hist_q[j], (at_us - ts[j - 1]) / (ts[j] - ts[j - 1])

    def step(self, k: int, now: float) -> None:
        """Tick k: every online device's grid sample, the kernel, segment points; truth older
        than TRUTH_MAX_AGE_S; silent trackers go offline."""
        at = self.start_us + k * self.period_us - self.delay_us  # the grid instant, gateway clock
        if self.sync is not None:
            self.offset_us = float(self.sync.stamp(np.zeros(1, np.int64), np.array([at]))[0]) - at
            if self.sync.steps:  # the time base stepped (a resync after the holdover): new streams, as emulated devices
                log.info("time base stepped: every stream restarts")
                for d in self.slots:
                    if d.online:
                        self._end_stream(d)
        samples: list[tuple] = []
        quiet, truth = [], []
        batch = self.settings.raw_batch
        for d in self.slots:
            if not d.online:
                continue
            at_d = self._next_instant(d, at)  # the device's own grid, locked to its tracker's packets
            pair = None if at_d is None else self._bracket(d, at_d)
            if pair is None:
                d.quiet += 1
                if d.quiet >= QUIET_TICKS:
                    quiet.append(d)
            else:
                d.last_t = int(round(at_d + self.offset_us))
                d.quiet = 0
                samples.append((d.slot, int(round(at_d)) & 0xFFFFFFFF, d.last_t, *pair))
            if d.truth_t and (len(d.truth_t) >= batch or now - d.truth_since >= TRUTH_MAX_AGE_S):
                truth.append(d)  # may be due (_settled_truth, once its points are out)
        self._update(samples)
        for d in quiet:
            log.info("%s: no rotation for %d ticks", d.id, d.quiet)
            self._end_stream(d)
        for d in truth:
            n = self._settled_truth(d) if d.online else 0
            if n >= batch or (n and now - d.truth_since >= TRUTH_MAX_AGE_S):
                self._flush_truth(d, n)
        self.ticks = k + 1

    def _update(self, samples: list[tuple]) -> None:
        """One kernel call for every device: the tick's grid samples, each (bank slot, tick: the
        device's grid instant, gateway clock, modulo 2**32; common-time stamp; q0, q1, u to
        SLERP, tracker axes), in one SLERP turned into limbstream's axes (NaN: no sample), their
        numbers and stamps in the bank's ring; the segment points it makes are published."""
        m = len(self.slots)
        rows = self.calls[:m] % RING
        self.bank.sample[rows, np.arange(m)] = -1
        y = np.full((m, 4), np.nan, np.float32)
        ticks = np.zeros(m, np.uint32)
        if samples:
            taken, tick, stamps, q0, q1, u = zip(*samples)
            slots = np.array(taken)
            self.bank.sample[rows[slots], slots] = self.n[slots]
            self.bank.t_us[rows[slots], slots] = stamps
            self.n[slots] += 1
            ticks[slots] = tick
            y[slots] = quat.slerp(quaternions(q0), quaternions(q1), np.array(u)) @ AXES_T
        points, payload, ends = self.bank.update_wire(ticks, y)
        self.calls[:m] += 1
        start = 0
        for slot, end in zip(points.tolist(), ends.tolist()):
            d = self.slots[slot]
            d.last = payload[start:end]
            d.publisher.put(d.last)
            d.points += 1
            start = end

    def keepalive(self, now: float) -> None:
        """Every KEEPALIVE_S: a heartbeat and a ping to each tracker; silent ones go offline."""
        for tracker in self.trackers.values():
            if tracker.online and now - tracker.last_seen > self.settings.timeout_s:
                tracker.online = False
                log.info("tracker %s timed out", tracker.name)
                for sensor in tracker.sensors.values():
                    if sensor.device is not None and sensor.device.online:
                        self._end_stream(sensor.device)
            self._send(proto.heartbeat(), tracker.address)
            tracker.ping_id = random.getrandbits(31)
            tracker.ping_sent = now
            self._send(proto.ping(tracker.ping_id), tracker.address)

    # ------------------------------------------------------------------ status

    def status(self, d: Device) -> wire.DeviceStatus:
        """The device's status: its config and stream counters, the gateway's clock sync, and its
        tracker's link."""
        b, k = self.bank, d.slot
        clock = self.sync.status(0) if self.sync is not None else wire.ClockStatus()
        link = None
        if d.sensor is not None:
            t = d.sensor.tracker
            loss = t.loss()
            link = wire.LinkStatus(d.sensor.name, t.battery_pct, t.signal_dbm,
                                   None if loss is None else round(loss, 6), round(t.pps(time.monotonic()), 3))
        return wire.DeviceStatus(d.id, d.config, int(b.stream[k]), int(self.n[k] - b.base[k]), d.points, clock,
                                 link=link)

    def _apply(self, d: Device, config: wire.DeviceConfig) -> None:
        self.bank.retune(d.slot, config.threshold, config.max_len, config.live_bound_deg)
        d.config = config

    def answer_queries(self) -> None:
        budget = QUERIES_PER_TICK
        for queryable, subject in self._queries:
            while budget > 0 and (query := queryable.try_recv()) is not None:
                budget -= 1
                targets = [d for d in self.slots if d.subject == subject and d.online
                           and zenoh.KeyExpr(wire.config_key(d.subject, d.segment)).intersects(query.key_expr)]
                device_io.answer_config(query, targets, self._apply, self.status)

    def report(self) -> dict:
        """Everything the gateway knows, for its log and its tests: trackers, sensors, devices,
        drops by reason."""
        now = time.monotonic()
        return {
            "trackers": {t.name: {"online": t.online, "packets": t.packets, "lost": t.lost,
                                  "pps": t.pps(now), "battery_pct": t.battery_pct, "signal_dbm": t.signal_dbm,
                                  "rtt_ms": t.rtt_ms,
                                  "sensors": {s.sensor: (s.device.id if s.device else None)
                                              for s in t.sensors.values()}}
                         for t in self.trackers.values()},
            "unassigned": {s.name: s.why for t in self.trackers.values() for s in t.sensors.values()
                           if s.device is None},
            "devices": {d.id: {"online": d.online, "streams": d.streams, "points": d.points,
                               "samples": int(self.n[d.slot] - self.bank.base[d.slot]), "held": d.held,
                               "jitter_p99_ms": (round(float(np.percentile(d.jitter, 99)) / 1e3, 3)
                                                 if d.jitter else None),
                               "sensor": d.sensor.name if d.sensor else None} for d in self.slots},
            "dropped": dict(self.dropped), "ignored": dict(self.ignored),
            "unassigned_samples": self.unassigned_samples, "ticks": self.ticks, "late": self.late,
        }

    # ------------------------------------------------------------------ loop

    def run(self, stop: threading.Event, on_report=None, report_s: float = 10.0) -> None:
        """Serve until ``stop``: datagrams as they come, a tick every 1/fs, keepalives every
        KEEPALIVE_S; ``on_report(report)`` every ``report_s``."""
        if not self._queries:
            self.declare()
        self.clocks.boot(self.base.now_us())
        if self.sync is not None:
            self.sync.start()
            self.sync.wait_first(stop)
        period = 1.0 / self.settings.fs
        start = time.monotonic()
        self.start_us = time.time_ns() / 1e3
        next_keepalive = next_report = start
        k = 0
        while not stop.is_set():
            deadline = start + k * period
            now = time.monotonic()
            if now < deadline:
                readable, _, _ = select.select([self.sock], [], [], deadline - now)
                now = time.monotonic()
                if readable:
                    began = time.thread_time()
                    self.receive(now)
                    self.busy_s += time.thread_time() - began
                if now < deadline:
                    continue
            elif now - deadline > period:
                self.late += 1
            began = time.thread_time()
            self.receive(now)
            self.step(k, now)
            k += 1
            if now >= next_keepalive:
                self.keepalive(now)
                next_keepalive = now + proto.KEEPALIVE_S
            self.answer_queries()
            self.answer_admin()
            if self.sync is not None:
                self.sync.poll()
            self.busy_s += time.thread_time() - began
            if on_report is not None and now >= next_report:
                on_report(self.report())
                next_report = now + report_s
