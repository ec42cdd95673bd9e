"""Which device each SlimeVR sensor feeds, and the gateway's queryable that lists the sensors and
moves one at run time (docs/protocol.md, "SlimeVR gateway").

A sensor's device comes from a run-time assignment (kept in the assignments file, if any:
:mod:`.assignments`), else from ``--assign`` (MAC[/SENSOR]=[SUBJECT/]SEGMENT), else from the body
position it reports in its sensor info (:data:`~.slimevr_protocol.POSITION_SEGMENTS`, the first segment of
its subject's layout that may carry it). A sensor
with none of these, or whose device another sensor feeds, is listed with the reason, not published.
"""
from __future__ import annotations

import json
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zenoh

from limbstream import wire
from limbstream.device.host import QUERIES_PER_TICK, Device, DeviceHost
from limbstream.services.gateway import assignments
from limbstream.services.gateway import slimevr_protocol as proto
from limbstream.services.gateway.slimevr_sessions import Sensor, TrackerSessions

if TYPE_CHECKING:
    from limbstream.services.gateway.slimevr import GatewaySettings

log = logging.getLogger("limbstream.gateway.slimevr")


class Assignments:
    """The sensors' devices.

    Parameters
    ----------
    settings : the gateway's (subject, --assign, assignments file, name, max devices).
    sessions : the trackers heard of.
    host : the gateway's devices (a device is made on its first assignment).
    end_stream : ends a device's stream (its sensor changes).
    reroute : the sensors feeding devices changed (the datagrams read in C are routed by sensor).

    Raises ValueError (one sentence) when the assignments file is bad.
    """

    def __init__(self, settings: GatewaySettings, sessions: TrackerSessions, host: DeviceHost[Sensor],
                 end_stream: Callable[[Device[Sensor]], None], reroute: Callable[[], None]):
        self.settings, self.sessions, self.host = settings, sessions, host
        self.end_stream, self.reroute = end_stream, reroute
        # run-time assignments, as settings.assign; None: none
        kept = assignments.load(settings.assignments_file) if settings.assignments_file else {}
        self.assigned: dict[tuple, tuple | None] = {k: t and (t[0] or settings.subject, t[1]) for k, t in kept.items()}
        self._queryable: Any = None

    def declare(self, session: zenoh.Session) -> None:
        """The gateway's queryable, ``limbstream/@gateway/<name>``."""
        self._queryable = session.declare_queryable(wire.gateway_key(self.settings.name), zenoh.handlers.FifoChannel(256))

    def undeclare(self) -> None:
        if self._queryable is not None:
            self._queryable.undeclare()
            self._queryable = None

    def _device(self, subject: str, segment: str) -> Device[Sensor] | None:
        """The device of (subject, segment), made on first use; None when the gateway is full."""
        d = self.host.by_id.get(wire.device_id(subject, segment))
        if d is None and len(self.host.devices) < self.settings.max_devices:
            d = self.host.add(subject, segment)  # (a run-time assignment may name a subject not served yet)
        return d

    def place(self, sensor: Sensor) -> None:
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
            segment = proto.position_segment(sensor.position, self.settings.segments)
            if target is None and segment is not None:
                target = (self.settings.subject, segment)
        if target is None:
            sensor.why = (f"body position {sensor.position} has no segment in the layout" if sensor.position
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
        if d.source is not None and d.source is not sensor:
            if d.source.tracker.online:
                return f"{d.id} is fed by {d.source.name}"
            d.source.device = None
            d.source.why = f"{d.id} taken over by {sensor.name}"
            if d.online:
                self.end_stream(d)
        d.source, sensor.device = sensor, d
        self.reroute()
        log.info("%s -> %s", sensor.name, d.id)
        return None

    def _unfeed(self, sensor: Sensor, why: str) -> None:
        """The sensor feeds no device any more: its device's stream ends."""
        d = sensor.device
        if d is None:
            return
        if d.online:
            self.end_stream(d)
        d.source, sensor.device, sensor.why = None, None, why
        self.reroute()
        log.info("%s -> none (%s)", sensor.name, why)

    def assign(self, a: wire.Assignment) -> str | None:
        """Move a sensor the gateway has heard of to device (subject, segment), or to none
        (``segment`` None); the reason it is refused (one sentence), else None. The old device's
        stream ends (FINAL, token dropped); the new device starts a stream at the sensor's next
        rotation. Remembered over --assign and body positions while the gateway runs, and in its
        assignments file if it has one."""
        tracker = self.sessions.named(a.tracker)
        sensor = tracker.sensors.get(a.sensor) if tracker is not None else None
        if tracker is None or sensor is None:
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
        other = self.host.by_id.get(wire.device_id(*target))
        if other is not None and other.source is not None and other.source.tracker.online:
            return f"{other.id} is fed by {other.source.name}: unassign it first"
        if other is None and len(self.host.devices) == self.settings.max_devices:  # (a device keeps its slot)
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
                for t in sorted(self.sessions.trackers.values(), key=lambda t: t.name)
                for s in sorted(t.sensors.values(), key=lambda s: s.sensor)]

    def answer_queries(self) -> None:
        """Answer the gateway's queryable (queries waiting in its channel, at most
        QUERIES_PER_TICK): no payload lists the sensors; an assignment is applied, then they are
        listed. A bad or refused one gets an error reply ``{"error": sentence}``."""
        if self._queryable is None:
            return
        for _ in range(QUERIES_PER_TICK):
            query = self._queryable.try_recv()
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
