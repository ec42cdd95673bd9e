"""The SlimeVR gateway: a UDP server that speaks the SlimeVR tracker protocol
(:mod:`.slimevr_protocol`) and turns every tracker sensor into a limbstream device
(docs/protocol.md, "SlimeVR gateway").

One thread does everything. At each tick of the device rate it reads the datagrams waiting:
rotations of sensors that feed devices, nearly all of the traffic, in C (:mod:`.slimevr_rx`:
counted on their tracker and put in their device's history, stamped by the kernel on arrival);
every other datagram is decoded here and answered as a SlimeVR server does (handshake, sensor
info, feature flags, a heartbeat and a ping every 0.5 s). Then every device takes its grid sample
(:class:`limbstream.kernel.grid.GridBank`, one C call) and fastSW runs for all of them in one
call of the device host's kernels (:class:`limbstream.device.bank.DeviceBank`), as for emulated
devices; the host publishes their segment points, truth tap and liveliness
(:mod:`limbstream.device.host`). Here is where the samples come from; tracker sessions:
:mod:`.slimevr_sessions`; sensor assignments and the gateway's queryable: :mod:`.slimevr_assign`;
the report: :mod:`.slimevr_report`.

Timing: each packet is stamped on arrival (by the kernel, on the gateway's clock, synchronised to
the common time base by :class:`SyncClient`, one clock for all; where the system gives no arrival
stamps, at its read, and the gateway then waits on the socket between ticks). Trackers send at
their own irregular rate; each device samples its tracker on a uniform grid of its own, placed on
the lower edge of its packets' arrivals (``firmware_c/host/lsw_grid.c``), at the newest instant at
least ``delay`` (default 30 ms) in the past: the SLERP of the two packets around that instant, or the newest packet held
when none has arrived after it yet (counted: ``held``). A packet that arrives less than half a
period after an instant was delayed on its way (arrival jitter), not taken later: it is that
instant's sample, and the truth tap stamps it at that instant (the sample's own stamp). The truth
tap carries every packet, each other one at its arrival, so a device's errors are measured
against the tracker's own full-rate stream.

Devices: a sensor's segment comes from ``--assign`` (MAC[/SENSOR]=[SUBJECT/]SEGMENT), else from
the body position it reports in its sensor info (:data:`POSITION_SEGMENTS`); a sensor with
neither, or whose device is fed by another sensor, is listed (``unassigned``), not published.
The gateway's queryable (``limbstream/@gateway/<name>``) lists the sensors and moves one to
another device, or to none, at run time. A tracker silent for ``timeout`` (1 s, as a SlimeVR server) goes offline: its devices end their
streams (FINAL) and drop their liveliness tokens; when it sends again, each starts a new stream.

Times are microseconds unless named otherwise.
"""
from __future__ import annotations

import collections
import logging
import math
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import zenoh

from limbstream import quat, wire
from limbstream.body import PAPER10, Body, Layout
from limbstream.device.bank import DeviceBank
from limbstream.device.clocks import ClockSettings, DeviceClocks, TimeBase
from limbstream.device.host import Device, DeviceHost, HostSettings
from limbstream.device.sync import SyncClient
from limbstream.kernel.grid import GridBank
from limbstream.pacing import PacedLoop
from limbstream.services.gateway import slimevr_protocol as proto
from limbstream.services.gateway.slimevr_assign import Assignments
from limbstream.services.gateway.slimevr_report import report
from limbstream.services.gateway.slimevr_rx import Receiver, ipv4
from limbstream.services.gateway.slimevr_sessions import Sensor, Tracker, TrackerSessions

log = logging.getLogger("limbstream.gateway.slimevr")

AXES = tuple(float(v) for v in quat.Z_UP_TO_Y_UP)
"""A tracker's axes (Z up) to limbstream's (Y up), as the SlimeVR server turns them (w, x, y, z)."""
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
TRUTH_MAX_AGE_S = 0.5
"""A device's truth samples wait at most this long for a full batch."""
RCVBUF = 4 << 20
"""Socket receive buffer asked for, bytes (the system may cap it: net.core.rmem_max): datagrams
wait in it between reads."""
READ_GAP_S = 0.002
"""With kernel arrival stamps and a receive buffer smaller than RCVBUF (capped by the system), the
socket is also read between ticks when datagrams wait, at most this often: the buffer then holds
a few ms of traffic instead of a tick's. With the whole buffer it is read at ticks only."""


@dataclass(frozen=True)
class GatewaySettings:
    """What one gateway runs.

    Attributes
    ----------
    subject : the subject of sensors placed by their body position.
    name : the gateway's name: its queryable is ``limbstream/@gateway/<name>``.
    assign : {(tracker, sensor or None: every sensor): (subject, segment)}; tracker is its MAC
        (``AA:BB:CC:DD:EE:FF``) or, without one, ``ip:port``.
    host : what every device shares: the grid's rate, the initial config, the truth tap (every
        packet; ``raw_batch`` samples per message at most), the recovery cache.
    delay_ms : the grid samples trackers this long in the past (so a packet after the instant
        has usually arrived).
    timeout_s : a tracker silent this long goes offline.
    max_devices : devices the gateway can serve (bank size).
    clock : time sync (one clock: the gateway's).
    assignments_file : where run-time assignments are kept (:mod:`.assignments`): loaded at start,
        rewritten after each change; None: they last while the gateway runs.
    body : the wearer's dimensions every device announces (``gateway slimevr --height-m``,
        ``--body``); None: none (the default adult).
    layout : the body layout whose segments sensors feed by their body position
        (:func:`~.slimevr_protocol.position_segment`); None: the body's, else ``paper10``.
    """

    subject: str
    name: str = "slimevr"
    assign: dict = field(default_factory=dict)
    host: HostSettings = HostSettings()
    delay_ms: float = 30.0
    timeout_s: float = proto.TRACKER_TIMEOUT_S
    max_devices: int = 256
    clock: ClockSettings = field(default_factory=ClockSettings)
    assignments_file: str | None = None
    body: Body | None = None
    layout: Layout | None = None

    @property
    def segments(self) -> tuple[str, ...]:
        """The segments sensors feed by body position: their layout's (see ``layout``)."""
        layout = self.layout or (self.body.layout if self.body is not None else PAPER10)
        return layout.segment_names


class SlimeVRGateway:
    """Trackers in, devices out.

    Parameters
    ----------
    session : an open Zenoh session (client).
    sock : a bound UDP socket (made non-blocking here).
    settings : GatewaySettings.

    Raises ValueError (one sentence) when the assignments file is bad.
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
        n = settings.max_devices
        self.host: DeviceHost[Sensor] = DeviceHost(session, settings.host, self._configure, self._status)
        for subject in sorted({settings.subject} | {s for s, _ in settings.assign.values()}):
            self.host.serve(subject)
        self.bank = DeviceBank(self.host, n, RING)
        self.raw_index = np.zeros(n, np.int64)  # index of each device's next truth sample in its stream
        self.dropped: collections.Counter = collections.Counter()  # datagrams dropped, by reason
        self.ignored: collections.Counter = collections.Counter()  # packets read but not used, by type
        self.unassigned_samples = 0
        self.period_us = 1e6 / settings.host.fs
        self.delay_us = settings.delay_ms * 1e3
        self.grid = GridBank(n, self.period_us, hold_us=HOLD_PERIODS * self.period_us,
                             late_us=LATE_SHARE * self.period_us, early_us=EARLY_SHARE * self.period_us,
                             phase_gain=PHASE_GAIN,
                             rise_after=math.ceil(self.delay_us / self.period_us) + 2,  # packets between one's arrival and its instant
                             axes=AXES, truth=settings.host.truth)
        # rotations of sensors that feed devices, read in C from an IPv4 socket (else handed in)
        self.rx = Receiver(sock if sock.family == socket.AF_INET else None, self.grid, n)
        self.sessions = TrackerSessions(self._send, self.dropped, settings.timeout_s, self._gone, self._reroute)
        self.assignments = Assignments(settings, self.sessions, self.host, self._end_stream, self._reroute)
        self.base = TimeBase()
        self.clocks = DeviceClocks(1, ClockSettings(), self.period_us, self.base)
        self.sync = (SyncClient(session, self.clocks, settings.clock, ["slimevr-gateway"])
                     if settings.clock.sync else None)
        self.offset_us = 0.0       # common time base minus the gateway's clock, as stamped this tick (also grid's)
        self.loop = PacedLoop(1.0 / settings.host.fs, clock=time.monotonic, work_clock=time.thread_time)
        self.ticks = 0
        self.start_us = 0.0

    # ------------------------------------------------------------------ devices

    def declare(self) -> None:
        """The config queryable of every subject the gateway may serve (devices are declared as
        their trackers appear) and the gateway's own queryable."""
        self.host.declare()
        self.assignments.declare(self.session)

    def undeclare(self) -> None:
        """Every open stream ends (FINAL); devices and queryables go; the time exchange stops."""
        for d in self.host.devices:
            if d.online:
                self._end_stream(d)
        self.host.close()
        self.assignments.undeclare()
        if self.sync is not None:
            self.sync.close()

    def _reroute(self) -> None:
        """Tell the C side which sensors feed which devices (after any change of them or of a
        tracker's address): their rotations are read there (:mod:`.slimevr_rx`)."""
        self.rx.route((t.link, ip, t.address[1], s.sensor, s.device.slot)
                      for t in self.sessions.trackers.values() if (ip := ipv4(t.address[0])) is not None
                      for s in t.sensors.values() if s.device is not None)

    def _gone(self, tracker: Tracker) -> None:
        """The tracker went offline: its devices end their streams (another sensor may take them over)."""
        for sensor in tracker.sensors.values():
            if sensor.device is not None and sensor.device.online:
                self._end_stream(sensor.device)

    def _start_stream(self, d: Device[Sensor]) -> None:
        """A new stream: fresh kernel state and grid, stream id and numbering; liveliness token."""
        self.bank.start_stream(d, reset=True)
        self.grid.reset(d.slot)
        self.raw_index[d.slot] = 0
        self.host.online(d)
        self.grid.devices[d.slot].online = True
        log.info("%s: stream %d from %s", d.id, self.bank.kernel.stream[d.slot], d.source.name if d.source else "?")

    def _end_stream(self, d: Device[Sensor]) -> None:
        """End the device's stream: its last point (FINAL; or the newest point repeated with FINAL),
        its truth, its token."""
        self.bank.end_stream(d)
        self._flush_truth(d, self.grid.devices[d.slot].truth_len, time.monotonic())
        self.host.offline(d)
        self.grid.devices[d.slot].online = False
        log.info("%s: stream %d ended", d.id, self.bank.kernel.stream[d.slot])

    def _status(self, d: Device[Sensor]) -> wire.DeviceStatus:
        """The device's status: its config and stream counters, the gateway's clock sync, and its
        tracker's link."""
        clock = self.sync.status(0) if self.sync is not None else wire.ClockStatus()
        link = None
        if d.source is not None:
            t = d.source.tracker
            loss = t.loss()
            link = wire.LinkStatus(d.source.name, t.battery_pct, t.signal_dbm,
                                   None if loss is None else round(loss, 6), round(t.pps(time.monotonic()), 3))
        return self.bank.status(d, clock, link=link, orientations="sensors", body=self.settings.body)

    def _configure(self, d: Device[Sensor], config: wire.DeviceConfig) -> None:
        self.bank.configure(d, config)

    def report(self) -> dict:
        """Everything the gateway knows (:mod:`.slimevr_report`)."""
        return report(self)

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
            self.sessions.handshake(address, dg.messages[0], now)  # type: ignore[arg-type]
            return
        tracker = self.sessions.trackers.get(address)
        if tracker is None:
            self.dropped["no_handshake"] += 1
            return
        if not self.sessions.count(tracker, dg.number, now):
            return
        for m in dg.messages:
            if isinstance(m, proto.Rotation):
                self._rotation(tracker, m.sensor, m.q, t_us, now)
            elif isinstance(m, proto.SensorInfo):
                self.sessions.sensor(tracker, m.sensor).position = m.position
                self.assignments.place(tracker.sensors[m.sensor])
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

    def _rotation(self, tracker: Tracker, sensor_id: int, q: tuple, t_us: float, now: float) -> None:
        """Sensor ``sensor_id`` of the tracker is at ``q`` (w, x, y, z, the tracker's axes),
        arrived at ``t_us``: a rotation the C side did not take (a new sensor, a new stream)."""
        sensor = tracker.sensors.get(sensor_id)
        d = sensor.device if sensor is not None else None
        if d is None:  # a new sensor, or one without a device yet
            sensor = self.sessions.sensor(tracker, sensor_id)
            self.assignments.place(sensor)
            d = sensor.device
            if d is None:
                self.unassigned_samples += 1
                return
        if not d.online:
            self._start_stream(d)
        self.grid.push(d.slot, t_us, q, now)

    def _flush_truth(self, d: Device[Sensor], n: int, now: float) -> None:
        """Put the device's first ``n`` truth samples on its tap (the rest wait from ``now``)."""
        if not n or not self.settings.host.truth:
            return
        t, q = self.grid.take_truth(d.slot, n, now)
        self.host.publish_raw(d, wire.RawBatch(int(self.bank.kernel.stream[d.slot]), int(self.raw_index[d.slot]), t, q))
        self.raw_index[d.slot] += len(t)

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
                for d in self.host.devices:
                    if d.online:
                        self._end_stream(d)
        self.grid.offset_us = self.offset_us
        m = len(self.host.devices)
        g = self.grid
        g.tick(m, at)
        taken = np.flatnonzero(g.have[:m])
        self.bank.update(np.where(g.have[:m], g.tick_u32[:m], 0).astype(np.uint32), g.y[:m], taken, g.stamp[taken])
        for d in self.host.devices:
            if d.online and g.devices[d.slot].quiet >= QUIET_TICKS:
                log.info("%s: no rotation for %d ticks", d.id, g.devices[d.slot].quiet)
                self._end_stream(d)
        for slot, n in g.truth_due(m, now, self.settings.host.raw_batch, TRUTH_MAX_AGE_S):
            self._flush_truth(self.host.devices[slot], n, now)
        self.ticks = k + 1

    # ------------------------------------------------------------------ loop

    def run(self, stop: threading.Event, on_report: Callable[[dict], object] | None = None,
            report_s: float = 10.0) -> None:
        """Serve until ``stop``: a tick every 1/fs, keepalives every KEEPALIVE_S; ``on_report(report)``
        every ``report_s``. Datagrams are read at each tick; when the kernel stamps their arrival
        and the whole buffer is there, at ticks only; with a capped buffer also between ticks, at
        most every READ_GAP_S; without kernel stamps as they come."""
        if not self.host.declared:
            self.declare()
        self.clocks.boot(self.base.now_us())
        if self.sync is not None:
            self.sync.start()
            self.sync.wait_first(stop)
        self.start_us = time.time_ns() / 1e3
        due = {"keepalive": 0.0, "report": 0.0}

        def tick(k: int, now: float) -> None:
            self.receive(now)
            self.step(k, now)
            if now >= due["keepalive"]:
                self.sessions.keepalive(now)
                due["keepalive"] = now + proto.KEEPALIVE_S
            self.host.answer_queries()
            self.assignments.answer_queries()
            if self.sync is not None:
                self.sync.poll()
            if on_report is not None and now >= due["report"]:
                on_report(self.report())
                due["report"] = now + report_s

        # with kernel arrival stamps and the whole buffer, datagrams wait in it until the tick
        between = not self.rx.kernel_stamps or self.rcvbuf < RCVBUF
        self.loop.run(stop, tick, between=self._between if between else None)

    def _between(self, deadline: float) -> None:
        """Until ``deadline``: read datagrams as they come (without kernel stamps), or at most
        every READ_GAP_S (stamped on arrival, a capped buffer)."""
        readable, _, _ = select.select([self.sock], [], [], max(0.0, deadline - time.monotonic()))
        if readable:
            began = time.thread_time()
            now = time.monotonic()
            self.receive(now)
            self.loop.stats.busy_s += time.thread_time() - began
            if self.rx.kernel_stamps:  # stamped on arrival: the next read at most READ_GAP_S later
                time.sleep(max(0.0, min(deadline, now + READ_GAP_S) - time.monotonic()))
