"""Devices on serial links bridged to Zenoh: to the rest of limbstream each is a device like an
emulated one (docs/protocol.md, "Key expressions"), on the process's device host
(:mod:`limbstream.device.host`): its segment points on ``limbstream/<subject>/<segment>/seg``
(advanced publisher: cache, miss detection), a liveliness token, its subject's config queryable,
and with a motion source feeding it, the truth tap of those samples.

What a device does with a sample is its firmware's: the points are the firmware's messages,
published as they come (the gateway never re-encodes them). Its samples come from its own IMU, or
from a motion feed the gateway sends it over the link. A config query is checked against the
contract here and again by the firmware, and answered once the firmware has acked it. A link that
ends is a device gone offline: its token is dropped; so does a device silent for longer than
``silence_s`` (its heartbeat comes every second: a hung firmware). When the link comes back (a
new one from ``connect``) the device starts a new stream.
"""
from __future__ import annotations

import logging
import queue
import random
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import zenoh

from limbstream import wire
from limbstream.body import Body
from limbstream.device.host import Device, DeviceHost, HostSettings, Refused
from limbstream.device.readings import RawSensors
from limbstream.pacing import PacedLoop
from limbstream.services.gateway.serial_port import LinkClosed, SerialLink
from limbstream.wire import serial_link as link

log = logging.getLogger("limbstream.gateway.serial")
SILENCE_S = 10.0
"""A device not heard from for this long is offline (10 heartbeats missed)."""


@dataclass
class Feeding:
    """What the gateway feeds the device when it stands in for the IMU.

    Attributes
    ----------
    feed : a motion feed (limbstream.device.feeds): ``sample(k) -> (S, 4)``, ``length``,
        ``orientations``; with ``raw``, a :class:`~limbstream.device.readings.RawFeed` (``sample``:
        the truth).
    column : the device's segment in the feed's samples.
    raw : raw sensors: the device is sent what its sensor reads (RAW frames, ``raw.per`` per
        device sample) after its pipeline's settings (FUSION, ``fusion``); None: orientations.
    slot : the device's sensor among ``raw``'s.
    fusion : its pipeline's settings (:func:`limbstream.kernel.fusion.imu_settings`, its own
        start heading).
    """

    feed: object
    column: int
    raw: RawSensors | None = None
    slot: int = 0
    fusion: object = None


@dataclass
class GatewayCounters:
    """The gateway's side of the link (the device reports its own in its status)."""

    samples: int = 0          # samples fed, all streams
    points: int = 0           # points published, all streams
    links: int = 0            # links opened (1 + reconnects)
    bad: dict[str, int] = field(default_factory=lambda: dict.fromkeys(link.BAD_REASONS, 0))


def serial_host(session: zenoh.Session, settings: HostSettings) -> DeviceHost:
    """The device host of serial devices: each answers its config queries through its link
    (:meth:`SerialGateway.configure`, :meth:`SerialGateway.status`), an offline one with its error."""
    return DeviceHost(session, settings, lambda d, config: d.source.configure(config), lambda d: d.source.status(),
                      offline_answers=True)


class SerialGateway:
    """One device on a serial link, as ``<subject>/<segment>`` of ``host`` (:func:`serial_host`).

    Parameters
    ----------
    host : the device host (its settings: the rate fed, the tunables given to the device at every
        (re)start, the truth tap of fed samples, the recovery cache).
    connect : opens the link (a :class:`SerialLink`), None if it cannot now.
    subject, segment : the device's name.
    feeding : the samples it is fed (None: they come from elsewhere; no truth tap then).
    rest_pose : what identity orientations mean (wire.REST_POSES).
    body : its wearer's dimensions, which the device announces (None: none, the default adult).
    silence_s : a device not heard from for this long is offline (its link is dropped and reopened).
    """

    def __init__(self, host: DeviceHost, connect: Callable[[], SerialLink | None], subject: str, segment: str,
                 feeding: Feeding | None = None, rest_pose: str = wire.DEFAULT_REST_POSE, silence_s: float = SILENCE_S,
                 body: Body | None = None):
        self.host, self.connect = host, connect
        self.device: Device = host.add(wire.check_chunk(subject, "subject"), wire.check_chunk(segment, "segment"), self)
        self.device.config = self.device.config.validate()
        self.feeding, self.rest_pose, self.silence_s, self.body = feeding, rest_pose, silence_s, body
        self.period_us = 1e6 / host.settings.fs
        self.counters = GatewayCounters()
        self.link: SerialLink | None = None
        self.stream = 0
        self.sample = 0                # samples fed in the current stream
        self.last_status: link.LinkStatus | None = None
        self.ended = False
        self._tap: list[tuple[int, np.ndarray]] = []

    @property
    def id(self) -> str:
        return self.device.id

    # ------------------------------------------------------------------ link

    def open(self) -> bool:
        """Open the link, give the device its config and a new stream, come online. False if the
        link cannot be opened now (or the device refuses: logged)."""
        try:
            port = self.connect()
        except OSError as exc:
            log.warning("%s: cannot open the link: %s", self.id, exc)
            return False
        if port is None:
            return False
        try:
            identity = port.identify()
            if identity.link_version != link.LINK_VERSION:
                raise LinkClosed(f"device speaks link version {identity.link_version}, not {link.LINK_VERSION}")
            ack = port.configure(self.device.config)
            if not ack.ok:
                raise LinkClosed(f"device refused its config: {ack.error}")
            if self.feeding is not None and self.feeding.raw is not None and not port.fusion(self.feeding.fusion).ok:
                raise LinkClosed("device refused its fusion settings")
            stream = random.getrandbits(16)
            if not port.start(stream).ok:
                raise LinkClosed("device refused to start a stream")
        except (LinkClosed, TimeoutError) as exc:
            log.warning("%s: %s", self.id, exc)
            self._drop(port)
            return False
        self.link, self.stream, self.sample = port, stream, 0
        self._tap.clear()
        self.counters.links += 1
        self.device.streams += 1
        self.device.points, self.device.last = 0, None
        self.host.online(self.device)
        log.info("%s: online (%s), stream %d", self.id, identity.text, stream)
        return True

    def _drop(self, port: SerialLink) -> None:
        for reason, n in port.bad.items():
            self.counters.bad[reason] += n
        port.close()

    def offline(self) -> None:
        """The link ended: the device goes offline (token dropped) until :meth:`open` again."""
        if self.link is not None:
            self._drop(self.link)
            self.link = None
        self.host.offline(self.device)
        log.warning("%s: link lost, device offline", self.id)

    @property
    def online(self) -> bool:
        return self.link is not None and not self.link.closed.is_set()

    # ------------------------------------------------------------------ samples and points

    def feed(self, k: int, t_us: int) -> None:
        """Feed the device sample k of its motion, stamped ``t_us`` (us since the epoch, the
        common time base); its kernel tick is its own clock's, k sample periods."""
        f = self.feeding
        if f is None or self.ended or self.link is None:
            return
        if f.feed.length is not None and k >= f.feed.length:
            self.end()
            return
        q = f.feed.sample(k)[f.column]
        try:
            if f.raw is not None:
                self._feed_raw(f.raw, k, f.slot, t_us)
            else:  # its tick: as an emulated device's clock
                self.link.sample(int(round(self.sample * self.period_us)), t_us, q)
        except LinkClosed:
            return  # pump() sees the link closed
        self.sample += 1
        self.counters.samples += 1
        if self.host.settings.truth:
            self._tap.append((t_us, q))
            if len(self._tap) >= self.host.settings.raw_batch:
                self.flush_tap()

    def _feed_raw(self, raw: RawSensors, k: int, slot: int, t_us: int) -> None:
        """Send the device the raw samples its sensor reads over its device sample k, stamped
        from ``t_us`` on, ticked on its clock as an emulated device's."""
        assert self.link is not None
        gyr, acc = raw.read(k, np.array([slot]))
        step = self.period_us / raw.per
        for i in range(raw.per):
            j = self.sample * raw.per + i
            self.link.raw(int(round(j * step)), int(round(t_us + i * step)), gyr[i, 0], acc[i, 0])

    def flush_tap(self) -> None:
        """Publish the fed samples not yet on the truth tap."""
        if not self._tap:
            return
        t_us = np.array([t for t, _ in self._tap], np.int64)
        q = np.array([q for _, q in self._tap], np.float32)
        self.host.publish_raw(self.device, wire.RawBatch(self.stream, self.sample - len(self._tap), t_us, q,
                                                         t_us.copy()))
        self._tap.clear()

    def end(self) -> None:
        """End the stream (finite source): the device's FINAL point, the rest of the truth tap."""
        if self.ended:
            return
        self.ended = True
        self.flush_tap()
        if self.link is not None:
            try:
                self.link.end()
            except (LinkClosed, TimeoutError) as exc:
                log.warning("%s: end of stream not acked: %s", self.id, exc)
        self.pump()

    def pump(self) -> None:
        """Publish the points the device has sent; note its heartbeats; a closed link goes offline."""
        if self.link is None:
            return
        while True:
            try:
                kind, message = self.link.inbox.get_nowait()
            except queue.Empty:
                if time.monotonic() - self.link.last_heard > self.silence_s:
                    log.warning("%s: silent for %g s", self.id, self.silence_s)
                    self.offline()
                return
            if kind == "point":
                self.host.publish(self.device, message)
                self.counters.points += 1
            elif kind == "status":
                self.last_status = message
            else:
                self.offline()
                return

    # ------------------------------------------------------------------ config queries (the host's callbacks)

    def configure(self, config: wire.DeviceConfig) -> None:
        """Give the device ``config`` over its link; Refused when it is offline, wire.WireError
        when the firmware refuses."""
        try:
            if self.link is None:
                raise LinkClosed("device offline")
            ack = self.link.configure(config)
        except (LinkClosed, TimeoutError) as exc:
            raise Refused(str(exc)) from None
        if not ack.ok:
            raise wire.WireError("config", ack.error or "refused")
        self.device.config = config

    def status(self) -> wire.DeviceStatus:
        """The device's status, its counters as the firmware reports them; Refused when offline."""
        try:
            if self.link is None:
                raise LinkClosed("device offline")
            status = self.link.status()
            fusion = self._fusion_status()
        except (LinkClosed, TimeoutError) as exc:
            raise Refused(str(exc)) from None
        fed = "sensors" if self.feeding is None else self.feeding.feed.orientations  # wire.ORIENTATIONS
        return wire.DeviceStatus(self.id, self.device.config, status.stream, status.samples, status.points, None,
                                 self.rest_pose, fusion=fusion, orientations=fed, body=self.body)

    def _fusion_status(self) -> wire.FusionStatus | None:
        """The filter of a device fed raw samples, as it reports it (FUSION_STATUS)."""
        if self.feeding is None or self.feeding.raw is None or self.link is None:
            return None
        f = self.link.fusion_status()
        bias = np.degrees(f.bias)
        return wire.FusionStatus(f.mode, (float(bias[0]), float(bias[1]), float(bias[2])), f.rest, dict(f.faults))

    def summary(self) -> str:
        c = self.counters
        device = self.last_status.bad if self.last_status is not None else {}
        bad = dict(c.bad)
        if self.link is not None:
            bad = {r: n + self.link.bad[r] for r, n in bad.items()}
        dropped = self.link.dropped if self.link is not None else 0
        return (f"{self.id}: {c.samples} samples fed, {c.points} points, {self.device.streams} streams, "
                f"{c.links} links, {dropped} messages dropped (inbox full); "
                f"bad frames from the device {bad}, at the device {device}")

    def close(self) -> None:
        """Drop the link (the host undeclares the device)."""
        if self.link is not None:
            self._drop(self.link)
            self.link = None


def run(host: DeviceHost, gateways: list[SerialGateway], stop: threading.Event, speed: float = 1.0,
        duration_s: float | None = None, reconnect_s: float = 1.0) -> int:
    """Run gateways until ``stop`` (or ``duration_s`` of device time): each tick feeds every
    feeding gateway one sample (at the host's rate x ``speed``), then publishes what the devices
    sent and answers config queries; a device offline is reopened every ``reconnect_s``. Returns
    the ticks run. Gateways without feeding only bridge (ticks pace the polling)."""
    fs = host.settings.fs
    period_us = 1e6 / fs
    start_us = time.time() * 1e6
    retry_at = [0.0] * len(gateways)

    def tick(k: int, now: float) -> bool:
        for i, g in enumerate(gateways):
            if g.link is None and not g.ended and now >= retry_at[i]:
                if not g.open():
                    retry_at[i] = now + reconnect_s
            g.feed(k, int(round(start_us + k * period_us)))
            g.pump()
        host.answer_queries()
        return not all(g.ended for g in gateways)

    k = PacedLoop(1.0 / (fs * speed)).run(stop, tick, None if duration_s is None else int(round(duration_s * fs)))
    for g in gateways:
        g.end() if g.feeding is not None and g.feeding.feed.length is not None else g.flush_tap()
    if not stop.is_set() and all(g.ended for g in gateways):  # finite run: keep serving queries
        host.idle(stop, lambda: [g.pump() for g in gateways])
    return k
