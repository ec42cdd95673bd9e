"""The SlimeVR gateway: a UDP server that speaks the SlimeVR tracker protocol
(:mod:`.slimevr_protocol`) and turns every tracker sensor into a limbstream device
(docs/protocol.md, "SlimeVR gateway").

One thread does everything. At each tick of the device rate it reads the datagrams waiting:
rotations of sensors that feed devices, nearly all of the traffic, in C (:mod:`.slimevr_rx`:
counted on their tracker and put in their device's history, stamped by the kernel on arrival);
every other datagram is decoded here and answered as a SlimeVR server does (handshake, sensor
info, feature flags, a heartbeat and a ping every 0.5 s). Then every device takes its grid sample
(:class:`limbstream.kernel.grid.GridBank`, one C call) and fastSW runs for all of them in one
:class:`limbstream.kernel.SegmenterBank` call, as the emulator does, publishing segment points, the
truth tap and liveliness with the emulator's device pieces (:mod:`..device_emulator.device_io`).

Timing: each packet is stamped on arrival (by the kernel, on the gateway's clock, synchronised to
the common time base by :class:`SyncClient`, one clock for all; where the system gives no arrival
stamps, at its read, and the gateway then waits on the socket between ticks). Trackers send at
their own irregular rate; each device samples its tracker on a uniform grid of its own, placed on
the lower edge of its packets' arrivals (``firmware_c/src/lsw_grid.c``), at the newest instant at
least ``delay`` (default 30 ms) in the past: the SLERP of the two packets around that instant, or the newest packet held
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

import collections
import json
import logging
import math
import random
import select
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import zenoh

from limbstream import kernel, wire
from limbstream.kernel.grid import GridBank
from limbstream.device_emulator import device_io
from limbstream.device_emulator.device_clocks import ClockSettings, DeviceClocks, TimeBase
from limbstream.device_emulator.sync_client import SyncClient
from limbstream.services.gateway import assignments
from limbstream.services.gateway import slimevr_protocol as proto
from limbstream.services.gateway.slimevr_rx import Receiver, ipv4

log = logging.getLogger("limbstream.gateway.slimevr")

AXES = (math.cos(math.pi / 4), -math.sin(math.pi / 4), 0.0, 0.0)
"""-90 degrees about X (w, x, y, z): a tracker's axes (Z up) to limbstream's (Y up), as the
SlimeVR server turns them."""
RING = 64
"""Ticks of samples each device keeps: a segment point refers to the device's newest sample or the
one before, at most QUIET_TICKS ticks back."""
QUIET_TICKS = RING - 2
"""A device without a sample for this many ticks (its sensor stopped sending rotations) ends its
stream; its next rotation starts a new one."""
PHASE_GAIN = 0.02
"""Share of a late packet's offset from its device's grid instant the grid moves by."""
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
"""Datagrams read at most at once (at a tick; without kernel stamps, also as they come)."""
RATE_WINDOW_S = 5.0
"""Packets per second are counted over this window."""
TRUTH_MAX_AGE_S = 0.5
"""A device's truth samples wait at most this long for a full batch."""
QUERIES_PER_TICK = 10
RCVBUF = 4 << 20
"""Socket receive buffer asked for, bytes (the system may cap it: net.core.rmem_max): datagrams
wait in it between reads."""
READ_GAP_S = 0.002
"""With kernel arrival stamps and a receive buffer smaller than RCVBUF (capped by the system), the
socket is also read between ticks when datagrams wait, at most this often: the buffer then holds
a few ms of traffic instead of a tick's. With the whole buffer it is read at ticks only."""
RATE_MARK_S = 0.25
"""A tracker's packet count is noted at most this often for its packet rate."""


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
    """One tracker (a UDP address) and its link figures. Its packet counters are a C record
    (``link``), shared with the datagrams read in C (:mod:`.slimevr_rx`)."""

    address: tuple
    name: str
    connected: float = 0.0             # monotonic s of its last handshake
    battery_pct: float | None = None
    signal_dbm: float | None = None
    ping_id: int = 0
    ping_sent_us: float = 0.0          # gateway clock of its last ping
    rtt_ms: float | None = None
    link: kernel.SvrTracker = field(default_factory=lambda: kernel.SvrTracker(last_number=-1, online=1))
    marks: collections.deque = field(default_factory=collections.deque)  # (monotonic s, packets heard)
    sensors: dict = field(default_factory=dict)  # sensor id -> Sensor

    @property
    def online(self) -> bool:
        return bool(self.link.online)

    @online.setter
    def online(self, value: bool) -> None:
        self.link.online = int(value)

    @property
    def packets(self) -> int:
        """Numbered packets taken."""
        return self.link.packets

    @property
    def lost(self) -> int:
        """Packet numbers missing."""
        return self.link.lost

    def pps(self, now: float) -> float:
        """Packets per second over about the last RATE_WINDOW_S (or since it connected, at least 1 s)."""
        marks, heard = self.marks, self.link.arrived
        if not marks:
            marks.append((self.connected, 0))
        if now - marks[-1][0] >= RATE_MARK_S:
            marks.append((now, heard))
        while len(marks) > 1 and marks[1][0] <= now - RATE_WINDOW_S:
            marks.popleft()
        since, before = marks[0]
        return (heard - before) / max(1.0, now - since)

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
    grid: kernel.GridDevice | None = None        # its history, grid and truth samples (C record)
    raw_index: int = 0                           # index of the next truth sample in the stream

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
        self.rcvbuf = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)  # what the system gave (Linux: x2)
        if self.rcvbuf < RCVBUF:
            log.warning("UDP receive buffer %d bytes (asked for %d; net.core.rmem_max caps it): a stall of "
                        "the gateway may drop datagrams (counted: socket_full)", self.rcvbuf, RCVBUF)
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
        self.grid = GridBank(n, self.period_us, hold_us=HOLD_PERIODS * self.period_us,
                             late_us=LATE_SHARE * self.period_us, early_us=EARLY_SHARE * self.period_us,
                             phase_gain=PHASE_GAIN,
                             rise_after=math.ceil(self.delay_us / self.period_us) + 2,  # packets between one's arrival and its instant
                             axes=AXES, truth=settings.truth)
        # rotations of sensors that feed devices, read in C from an IPv4 socket (else handed in)
        self.rx = Receiver(sock if sock.family == socket.AF_INET else None, self.grid, n)
        self.base = TimeBase()
        self.clocks = DeviceClocks(1, ClockSettings(), self.period_us, self.base)
        self.sync = (SyncClient(session, self.clocks, settings.clock, ["slimevr-gateway"])
                     if settings.clock.sync else None)
        self.offset_us = 0.0       # common time base minus the gateway's clock, as stamped this tick (also grid's)
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
            d = Device(subject, segment, len(self.slots), s.config, grid=self.grid.devices[len(self.slots)])
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
        self._reroute()
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
        self._reroute()
        log.info("%s -> none (%s)", sensor.name, why)

    def _reroute(self) -> None:
        """Tell the C side which sensors feed which devices (after any change of them or of a
        tracker's address): their rotations are read there (:mod:`.slimevr_rx`)."""
        self.rx.route((t.link, ip, t.address[1], s.sensor, s.device.slot)
                      for t in self.trackers.values() if (ip := ipv4(t.address[0])) is not None
                      for s in t.sensors.values() if s.device is not None)

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
        self.grid.reset(k)
        self.calls[k] = 0
        b.stream[k], b.seq[k], b.base[k] = random.getrandbits(16), 0, self.n[k]
        d.points, d.last, d.raw_index = 0, None, 0
        d.streams += 1
        d.online = d.grid.online = True
        d.token = device_io.alive_token(self.session, d.subject, d.segment)
        log.info("%s: stream %d from %s", d.id, b.stream[k], d.sensor.name if d.sensor else "?")

    def _end_stream(self, d: Device) -> None:
        """End the device's stream: its last point (FINAL; or the newest point repeated with FINAL),
        its truth, its token."""
        b, k = self.bank, d.slot
        last = b.flush(k)
        if last is not None:  # the kernel's newest sample, not yet a point: the device's last grid sample
            omega = (0.0, 0.0, 0.0) if b.live(k) else None
            point = wire.SegmentPoint(int(b.stream[k]), int(b.seq[k]), int(self.n[k] - 1 - b.base[k]), d.grid.last_t,
                                      tuple(float(v) for v in last[2]), wire.FLAG_FINAL, omega)
            d.publisher.put(wire.encode_point(point))
        elif d.last is not None:
            point = wire.decode_point(d.last)
            d.publisher.put(wire.encode_point(wire.SegmentPoint(
                point.stream, int(b.seq[k]), point.index, point.t_us, point.q, wire.FLAG_FINAL, point.omega)))
        b.seq[k] = (int(b.seq[k]) + 1) & 0xFFFFFFFF
        self._flush_truth(d, d.grid.truth_len, time.monotonic())
        if d.token is not None:
            d.token.undeclare()
            d.token = None
        d.online = d.grid.online = False
        log.info("%s: stream %d ended", d.id, b.stream[k])

    # ------------------------------------------------------------------ datagrams

    def _send(self, payload: bytes, address: tuple) -> None:
        try:
            self.sock.sendto(payload, address)
        except OSError:  # a full buffer or an unreachable tracker: it asks again
            self.dropped["send_failed"] += 1

    def receive(self, now: float) -> int:
        """Read and handle the datagrams waiting (at most RECV_BUDGET); returns how many. From an
        IPv4 socket they are read in C, which handles the rotations of sensors that feed devices
        and hands every other datagram back, in order (:mod:`.slimevr_rx`)."""
        if self.rx.reads:
            count = 0
            while count < RECV_BUDGET:
                n, slow = self.rx.drain(now, RECV_BUDGET - count)
                count += n
                if slow is None:
                    break
                self._decode(*slow, now)
            if self.rx.errors:
                self.dropped["socket_error"] = self.rx.errors
            if self.rx.overflows:
                self.dropped["socket_full"] = self.rx.overflows
            return count
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
        ``now``, s): rotations of sensors that feed devices in C (as :meth:`receive` reads them),
        anything else decoded here."""
        ip = ipv4(address[0])
        if ip is None or not self.rx.datagram(data, ip, address[1], t_us, now):
            self._decode(data, address, t_us, now)

    def _decode(self, data: bytes, address: tuple, t_us: float, now: float) -> None:
        """A datagram the C side left to Python (:meth:`handle`). Bad ones are counted by reason
        and dropped."""
        try:
            dg = proto.decode(data)
        except proto.ProtocolError as exc:
            self.dropped[exc.reason] += 1
            return
        if dg.type == proto.HANDSHAKE:
            self._handshake(address, dg.messages[0], now)  # type: ignore[arg-type]
            return
        tracker = self.trackers.get(address)
        if tracker is None:
            self.dropped["no_handshake"] += 1
            return
        if not self._count(tracker, dg.number, now):
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
                    tracker.rtt_ms = (t_us - tracker.ping_sent_us) / 1e3  # (t_us: its arrival)
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
        link = tracker.link  # (shared with the C side, which counts the rotations it takes the same way)
        if number != 0:  # a pong echoes the server's number 0; every other packet counts up
            if number <= link.last_number:
                self.dropped["out_of_order"] += 1
                return False
            if 0 <= link.last_number and number - link.last_number < 1 << 16:
                link.lost += number - link.last_number - 1
            link.last_number = number
            link.packets += 1
        link.last_seen = now
        link.arrived += 1
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
            if tracker is not None:  # another tracker took this address: the one there left it
                self._offline(tracker, f"its address {address[0]}:{address[1]} is now {name}'s")
            tracker = next((t for t in self.trackers.values() if t.name == name), None)
            if tracker is not None:
                del self.trackers[tracker.address]
                tracker.address = address
            else:
                tracker = Tracker(address, name, connected=now)
                log.info("tracker %s connected from %s:%d (firmware %s, protocol %d)", name, address[0],
                         address[1], hs.firmware or "?", hs.protocol)
            self.trackers[address] = tracker
            self._reroute()
        tracker.link.last_number = -1  # a tracker keeps its numbering across reconnects: loss counts from here
        tracker.link.last_seen = now
        tracker.online = True
        self._send(proto.handshake_answer(), address)

    def _sensor(self, tracker: Tracker, sensor_id: int) -> Sensor:
        sensor = tracker.sensors.get(sensor_id)
        if sensor is None:
            sensor = tracker.sensors[sensor_id] = Sensor(tracker, sensor_id)
        return sensor

    def _rotation(self, tracker: Tracker, sensor_id: int, q: tuple, t_us: float, now: float) -> None:
        """Sensor ``sensor_id`` of the tracker is at ``q`` (w, x, y, z, the tracker's axes),
        arrived at ``t_us``: a rotation the C side did not take (a new sensor, a new stream)."""
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
        self.grid.push(d.slot, t_us, q, now)

    def _flush_truth(self, d: Device, n: int, now: float) -> None:
        """Put the device's first ``n`` truth samples on its tap (the rest wait from ``now``)."""
        if not n or d.raw_pub is None:
            return
        t, q = self.grid.take_truth(d.slot, n, now)
        d.raw_pub.put(wire.encode_raw(wire.RawBatch(int(self.bank.stream[d.slot]), d.raw_index, t, q)))
        d.raw_index += len(t)

    # ------------------------------------------------------------------ ticks

    def step(self, k: int, now: float) -> None:
        """Tick k: every online device's grid sample (:class:`GridBank`: on its own grid, locked
        to its tracker's packets), the kernel, segment points; truth due; devices whose tracker
        stopped sending rotations end their streams."""
        at = self.start_us + k * self.period_us - self.delay_us  # the grid instant, gateway clock
        if self.sync is not None:
            self.offset_us = float(self.sync.stamp(np.zeros(1, np.int64), np.array([at]))[0]) - at
            if self.sync.steps:  # the time base stepped (a resync after the holdover): new streams, as emulated devices
                log.info("time base stepped: every stream restarts")
                for d in self.slots:
                    if d.online:
                        self._end_stream(d)
        self.grid.offset_us = self.offset_us
        m = len(self.slots)
        self.grid.tick(m, at)
        self._update(m)
        for d in self.slots:
            if d.online and d.grid.quiet >= QUIET_TICKS:
                log.info("%s: no rotation for %d ticks", d.id, d.grid.quiet)
                self._end_stream(d)
        for slot, n in self.grid.truth_due(m, now, self.settings.raw_batch, TRUTH_MAX_AGE_S):
            self._flush_truth(self.slots[slot], n, now)
        self.ticks = k + 1

    def _update(self, m: int) -> None:
        """One kernel call for devices 0..m-1 with the tick's grid samples (the grid bank's
        ``have``, ``y``, ``tick_u32``, ``stamp``; NaN: no sample), their numbers and stamps in the
        bank's ring; the segment points it makes are published."""
        g = self.grid
        rows = self.calls[:m] % RING
        cols = np.arange(m)
        taken = g.have[:m].astype(bool)
        self.bank.sample[rows, cols] = np.where(taken, self.n[:m], -1)
        self.bank.t_us[rows[taken], cols[taken]] = g.stamp[:m][taken]
        self.n[:m] += taken
        ticks = np.where(taken, g.tick_u32[:m], 0).astype(np.uint32)
        points, payload, ends = self.bank.update_wire(ticks, g.y[:m])
        self.calls[:m] += 1
        start = 0
        for slot, end in zip(points.tolist(), ends.tolist()):
            d = self.slots[slot]
            d.last = payload[start:end]
            d.publisher.put(d.last)
            d.points += 1
            start = end

    def _offline(self, tracker: Tracker, why: str) -> None:
        """The tracker is gone (its devices end their streams; another sensor may take them over)."""
        tracker.online = False
        log.info("tracker %s offline: %s", tracker.name, why)
        for sensor in tracker.sensors.values():
            if sensor.device is not None and sensor.device.online:
                self._end_stream(sensor.device)

    def keepalive(self, now: float) -> None:
        """Every KEEPALIVE_S: a heartbeat and a ping to each tracker; silent ones go offline."""
        for tracker in self.trackers.values():
            if tracker.online and now - tracker.link.last_seen > self.settings.timeout_s:
                self._offline(tracker, "timed out")
            tracker.pps(now)  # a mark for its packet rate
            self._send(proto.heartbeat(), tracker.address)
            tracker.ping_id = random.getrandbits(31)
            tracker.ping_sent_us = time.time_ns() / 1e3
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
                               "samples": int(self.n[d.slot] - self.bank.base[d.slot]), "held": d.grid.held,
                               "truth_dropped": d.grid.truth_dropped,
                               "jitter_p99_ms": (round(float(np.percentile(jitter, 99)) / 1e3, 3)
                                                 if len(jitter := self.grid.jitter_us(d.slot)) else None),
                               "sensor": d.sensor.name if d.sensor else None} for d in self.slots},
            "dropped": dict(self.dropped), "ignored": dict(self.ignored),
            "unassigned_samples": self.unassigned_samples, "ticks": self.ticks, "late": self.late,
        }

    # ------------------------------------------------------------------ loop

    def run(self, stop: threading.Event, on_report=None, report_s: float = 10.0) -> None:
        """Serve until ``stop``: a tick every 1/fs, keepalives every KEEPALIVE_S; ``on_report(report)``
        every ``report_s``. Datagrams are read at each tick; when the kernel stamps their arrival
        and the whole buffer is there, at ticks only; with a capped buffer also between ticks, at
        most every READ_GAP_S; without kernel stamps as they come."""
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
        between = not self.rx.kernel_stamps or self.rcvbuf < RCVBUF  # read between ticks too
        k = 0
        while not stop.is_set():
            deadline = start + k * period
            now = time.monotonic()
            if now < deadline and not between:  # datagrams wait in the buffer with their arrival stamps
                time.sleep(deadline - now)
                continue
            if now < deadline:
                readable, _, _ = select.select([self.sock], [], [], deadline - now)
                now = time.monotonic()
                if readable:
                    began = time.thread_time()
                    self.receive(now)
                    self.busy_s += time.thread_time() - began
                    if self.rx.kernel_stamps:  # stamped on arrival: the next read at most READ_GAP_S later
                        time.sleep(max(0.0, min(deadline, now + READ_GAP_S) - time.monotonic()))
                continue
            if now - deadline > period:
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
