"""The SlimeVR gateway's tracker sessions (docs/protocol.md, "SlimeVR gateway"): every tracker
(a UDP address, known by its MAC when it gives one), its sensors and its link figures; the
handshake, a heartbeat and a ping every KEEPALIVE_S, packet counting (loss, rate, liveliness), a
tracker that moves to another address and one whose address another tracker takes."""
from __future__ import annotations

import collections
import logging
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from limbstream import kernel
from limbstream.device.host import Device
from limbstream.services.gateway import slimevr_protocol as proto

log = logging.getLogger("limbstream.gateway.slimevr")

RATE_WINDOW_S = 5.0
"""Packets per second are counted over this window."""
RATE_MARK_S = 0.25
"""A tracker's packet count is noted at most this often for its packet rate."""


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
    """One sensor of a tracker, and the device it feeds (if any)."""

    tracker: Tracker
    sensor: int
    position: int | None = None
    device: Device[Sensor] | None = None
    why: str = "no body position and no --assign"  # why it has no device

    @property
    def name(self) -> str:
        return f"{self.tracker.name}/{self.sensor}"


class TrackerSessions:
    """The trackers a gateway has heard from, by address.

    Parameters
    ----------
    send : ``send(payload, address)``: a datagram to a tracker.
    dropped : the gateway's counter of datagrams dropped, by reason.
    timeout_s : a tracker silent this long goes offline.
    gone : ``gone(tracker)``: a tracker went offline (its devices end their streams).
    moved : a tracker's address changed (the datagrams read in C are routed by address).
    """

    def __init__(self, send: Callable[[bytes, tuple], None], dropped: collections.Counter, timeout_s: float,
                 gone: Callable[[Tracker], None], moved: Callable[[], None]):
        self.send, self.dropped, self.timeout_s, self.gone, self.moved = send, dropped, timeout_s, gone, moved
        self.trackers: dict[tuple, Tracker] = {}

    def named(self, name: str) -> Tracker | None:
        """The tracker called ``name`` (its MAC, or ip:port), if heard of."""
        return next((t for t in self.trackers.values() if t.name == name), None)

    def sensor(self, tracker: Tracker, sensor_id: int) -> Sensor:
        """The tracker's sensor ``sensor_id``, made on first use."""
        sensor = tracker.sensors.get(sensor_id)
        if sensor is None:
            sensor = tracker.sensors[sensor_id] = Sensor(tracker, sensor_id)
        return sensor

    def handshake(self, address: tuple, hs: proto.Handshake, now: float) -> None:
        """A tracker looking for a server: known by its MAC (possibly from a new address) or its
        address, or new. Answered every time (the tracker repeats it until it hears us)."""
        name = hs.mac or f"{address[0]}:{address[1]}"
        tracker = self.trackers.get(address)
        if tracker is None or tracker.name != name:
            if tracker is not None:  # another tracker took this address: the one there left it
                self.offline(tracker, f"its address {address[0]}:{address[1]} is now {name}'s")
            tracker = self.named(name)
            if tracker is not None:
                del self.trackers[tracker.address]
                tracker.address = address
            else:
                tracker = Tracker(address, name, connected=now)
                log.info("tracker %s connected from %s:%d (firmware %s, protocol %d)", name, address[0],
                         address[1], hs.firmware or "?", hs.protocol)
            self.trackers[address] = tracker
            self.moved()
        tracker.link.last_number = -1  # a tracker keeps its numbering across reconnects: loss counts from here
        tracker.link.last_seen = now
        tracker.online = True
        self.send(proto.handshake_answer(), address)

    def count(self, tracker: Tracker, number: int, now: float) -> bool:
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

    def offline(self, tracker: Tracker, why: str) -> None:
        """The tracker is gone (its devices end their streams; another sensor may take them over)."""
        tracker.online = False
        log.info("tracker %s offline: %s", tracker.name, why)
        self.gone(tracker)

    def keepalive(self, now: float) -> None:
        """Every KEEPALIVE_S: a heartbeat and a ping to each tracker; silent ones go offline."""
        for tracker in self.trackers.values():
            if tracker.online and now - tracker.link.last_seen > self.timeout_s:
                self.offline(tracker, "timed out")
            tracker.pps(now)  # a mark for its packet rate
            self.send(proto.heartbeat(), tracker.address)
            tracker.ping_id = random.getrandbits(31)
            tracker.ping_sent_us = time.time_ns() / 1e3
            self.send(proto.ping(tracker.ping_id), tracker.address)
