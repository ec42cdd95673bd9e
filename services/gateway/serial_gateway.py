"""A device on a serial link bridged to Zenoh: to the rest of limbstream it is a device like an
emulated one (docs/protocol.md, "Key expressions"): its segment points on
``limbstream/<subject>/<segment>/seg`` (advanced publisher: cache, miss detection), a liveliness
token, a config queryable, and with a motion source feeding it, the truth tap of those samples.

The points are the firmware's messages, published as they come (the gateway never re-encodes
them). A config query is checked against the contract here and again by the firmware, and
answered once the firmware has acked it. A link that ends is a device gone offline: its token
is dropped; so does a device silent for longer than ``silence_s`` (its heartbeat comes every
second: a hung firmware). When the link comes back (a new one from ``connect``) the device starts
a new stream.
"""
from __future__ import annotations

import json
import logging
import queue
import random
import threading
import time
from dataclasses import dataclass, field
from collections.abc import Callable

import numpy as np
import zenoh

from limbstream import wire
from limbstream.device_emulator import device_io
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
    feed : a motion feed (limbstream.device_emulator.feeds): ``sample(k) -> (S, 4)``, ``length``.
    column : the device's segment in the feed's samples.
    fs : sample rate, Hz.
    """

    feed: object
    column: int
    fs: float = 50.0


@dataclass
class GatewayCounters:
    """The gateway's side of the link (the device reports its own in its status)."""

    samples: int = 0          # samples fed, all streams
    points: int = 0           # points published, all streams
    streams: int = 0          # streams started
    links: int = 0            # links opened (1 + reconnects)
    bad: dict[str, int] = field(default_factory=lambda: dict.fromkeys(link.BAD_REASONS, 0))


class SerialGateway:
    """One device on a serial link, as ``<subject>/<segment>``.

    Parameters
    ----------
    session : an open Zenoh session (client).
    connect : opens the link (a :class:`SerialLink`), None if it cannot now.
    subject, segment : the device's name.
    config : the tunables it is given at every (re)start.
    feeding : the samples it is fed (None: they come from elsewhere; no truth tap then).
    truth : publish the truth tap of fed samples; raw_batch samples per message.
    cache, heartbeat_s : the advanced publisher's recovery cache and miss-detection heartbeat.
    rest_pose : what identity orientations mean (wire.REST_POSES).
    silence_s : a device not heard from for this long is offline (its link is dropped and reopened).
    """

    def __init__(self, session: zenoh.Session, connect: Callable[[], SerialLink | None], subject: str, segment: str,
                 config: wire.DeviceConfig | None = None, feeding: Feeding | None = None, truth: bool = True,
                 raw_batch: int = 25, cache: int = 512, heartbeat_s: float = 0.5, rest_pose: str = wire.DEFAULT_REST_POSE,
                 silence_s: float = SILENCE_S):
        self.session, self.connect = session, connect
        self.subject, self.segment = wire.check_chunk(subject, "subject"), wire.check_chunk(segment, "segment")
        self.config, self.feeding, self.rest_pose = (config or wire.DeviceConfig()).validate(), feeding, rest_pose
        self.truth, self.raw_batch = truth and feeding is not None, raw_batch
        self.counters = GatewayCounters()
        self.silence_s = silence_s
        self.link: SerialLink | None = None
        self.stream = 0
        self.sample = 0                # samples fed in the current stream
        self.last_status: link.LinkStatus | None = None
        self.ended = False
        self._tap: list[tuple[int, np.ndarray]] = []
        self.publisher = device_io.point_publisher(session, subject, segment, cache, heartbeat_s)
        self.raw_publisher = device_io.raw_publisher(session, subject, segment, heartbeat_s) if self.truth else None
        self.queries = session.declare_queryable(wire.config_key(subject, segment), zenoh.handlers.FifoChannel(256))
        self.token = None

    @property
    def id(self) -> str:
        return wire.device_id(self.subject, self.segment)

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
            ack = port.configure(self.config)
            if not ack.ok:
                raise LinkClosed(f"device refused its config: {ack.error}")
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
        self.counters.streams += 1
        self.token = device_io.alive_token(self.session, self.subject, self.segment)
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
        if self.token is not None:
            self.token.undeclare()
            self.token = None
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
        tick = int(round(self.sample * (1e6 / f.fs)))  # as an emulated device's clock
        try:
            self.link.sample(tick, t_us, q)
        except LinkClosed:
            return  # pump() sees the link closed
        self.sample += 1
        self.counters.samples += 1
        if self.truth:
            self._tap.append((t_us, q))
            if len(self._tap) >= self.raw_batch:
                self.flush_tap()

    def flush_tap(self) -> None:
        """Publish the fed samples not yet on the truth tap."""
        if not self._tap or self.raw_publisher is None:
            return
        t_us = np.array([t for t, _ in self._tap], np.int64)
        q = np.array([q for _, q in self._tap], np.float32)
        self.raw_publisher.put(wire.encode_raw(wire.RawBatch(self.stream, self.sample - len(self._tap), t_us, q,
                                                             t_us.copy())))
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
                self.publisher.put(message)
                self.counters.points += 1
            elif kind == "status":
                self.last_status = message
            else:
                self.offline()
                return

    # ------------------------------------------------------------------ config queries

    def answer_queries(self, budget: int = 10) -> None:
        """Apply and answer config queries that arrived (never inside a Zenoh callback)."""
        while budget > 0 and (query := self.queries.try_recv()) is not None:
            budget -= 1
            self._answer(query)

    def _answer(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            if self.link is None:
                raise LinkClosed("device offline")
            if payload:
                config = wire.decode_config(payload, self.config)
                ack = self.link.configure(config)
                if not ack.ok:
                    raise wire.WireError("config", ack.error or "refused")
                self.config = config
                log.info("%s: %s", self.id, config)
            status = self.link.status()
        except (wire.WireError, LinkClosed, TimeoutError) as exc:
            query.reply_err(json.dumps({"error": str(exc)}))
            return
        query.reply(wire.config_key(self.subject, self.segment), wire.encode_status(wire.DeviceStatus(
            self.id, self.config, status.stream, status.samples, status.points, None, self.rest_pose)))

    def summary(self) -> str:
        c = self.counters
        device = self.last_status.bad if self.last_status is not None else {}
        bad = dict(c.bad)
        if self.link is not None:
            bad = {r: n + self.link.bad[r] for r, n in bad.items()}
        dropped = self.link.dropped if self.link is not None else 0
        return (f"{self.id}: {c.samples} samples fed, {c.points} points, {c.streams} streams, {c.links} links, "
                f"{dropped} messages dropped (inbox full); "
                f"bad frames from the device {bad}, at the device {device}")

    def close(self) -> None:
        if self.link is not None:
            self._drop(self.link)
            self.link = None
        for obj in (self.token, self.publisher, self.raw_publisher, self.queries):
            if obj is not None:
                obj.undeclare()
        self.token = None


def run(gateways: list[SerialGateway], stop: threading.Event, fs: float = 50.0, speed: float = 1.0,
        duration_s: float | None = None, reconnect_s: float = 1.0) -> int:
    """Run gateways until ``stop`` (or ``duration_s`` of device time): each tick feeds every
    feeding gateway one sample (at ``fs`` x ``speed``), then publishes what the devices sent and
    answers config queries; a device offline is reopened every ``reconnect_s``. Returns the
    ticks run. Gateways without feeding only bridge (ticks pace the polling)."""
    period = 1.0 / (fs * speed)
    period_us = 1e6 / fs
    start, start_us = time.perf_counter(), time.time() * 1e6
    retry_at = dict.fromkeys(range(len(gateways)), 0.0)
    k = 0
    n_ticks = None if duration_s is None else int(round(duration_s * fs))
    while not stop.is_set() and (n_ticks is None or k < n_ticks):
        now = time.perf_counter()
        if now < start + k * period:
            stop.wait(start + k * period - now)
            continue
        for i, g in enumerate(gateways):
            if g.link is None and not g.ended and now >= retry_at[i]:
                if not g.open():
                    retry_at[i] = now + reconnect_s
            g.feed(k, int(round(start_us + k * period_us)))
            g.pump()
            g.answer_queries()
        k += 1
        if all(g.ended for g in gateways):
            break
    for g in gateways:
        g.end() if g.feeding is not None and g.feeding.feed.length is not None else g.flush_tap()
    while not stop.is_set() and all(g.ended for g in gateways):  # finite run: keep serving queries
        for g in gateways:
            g.pump()
            g.answer_queries()
        stop.wait(0.05)
    return k
