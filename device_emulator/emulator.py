"""Emulated IMU devices: each samples its subject's motion in real time, runs the C fastSW
kernel with its own state, and publishes only its segment points over Zenoh.

All devices of one process advance together, one tick per sample period, through one
:class:`limbstream.kernel.SegmenterBank` call; a device whose feed ends (``--once``, clips
of different lengths) publishes its last point as FINAL then, and nothing after it. Per
device: an advanced publisher for segment points (cache for recovery, miss detection), a
liveliness token, a share of one config queryable per subject, and optionally the truth
tap (raw sample batches).
Zenoh callbacks are not used: queries go to a FIFO channel read between ticks.
"""
from __future__ import annotations

import json
import logging
import math
import random
import threading
import time
from dataclasses import dataclass

import numpy as np
import zenoh
import zenoh.ext as zext

from limbstream import kernel, wire

log = logging.getLogger("limbstream.emulator")


@dataclass(frozen=True)
class EmulatorSettings:
    """What one emulator process runs.

    Attributes
    ----------
    fs : device sample rate, Hz.
    speed : time scale: 1 = real time, 10 = ten times faster (device clocks run faster too).
    config : initial fastSW settings of every device (limbstream.wire.TUNABLES).
    truth : publish raw samples on the truth tap.
    raw_batch : samples per truth-tap message.
    cache : segment points each device keeps for recovery (advanced publisher cache).
    heartbeat_s : miss-detection heartbeat period, seconds.
    """

    fs: float = 50.0
    speed: float = 1.0
    config: wire.DeviceConfig = wire.DeviceConfig()
    truth: bool = True
    raw_batch: int = 25
    cache: int = 512
    heartbeat_s: float = 0.5


@dataclass
class Device:
    """Book-keeping of one emulated device (the kernel state lives in the bank)."""

    subject: str
    segment: str
    slot: int
    stream: int
    publisher: object = None
    token: object = None
    seq: int = 0
    points: int = 0
    config: wire.DeviceConfig = wire.DeviceConfig()
    raw_next: int = 0  # first sample index not yet on the truth tap
    length: int | None = None  # samples in the device's stream (its feed's), None: endless

    @property
    def id(self) -> str:
        return wire.device_id(self.subject, self.segment)

    def status(self, samples: int) -> wire.DeviceStatus:
        """The device's own view: config and counters (the config queryable's reply);
        ``samples``: ticks so far (all devices of an emulator sample together until their stream ends)."""
        samples = samples if self.length is None else min(samples, self.length)
        return wire.DeviceStatus(self.id, self.config, self.stream, samples, self.points)


@dataclass
class TickStats:
    """Pacing counters of the tick loop."""

    ticks: int = 0
    late: int = 0
    max_late_s: float = 0.0
    busy_s: float = 0.0


class Emulator:
    """Devices of several subjects in one process.

    Parameters
    ----------
    session : an open Zenoh session (client).
    feeds : {subject: feed}, a feed has ``segments``, ``sample(k) -> (S, 4) float32`` and
        ``length`` (samples, or None for endless).
    settings : EmulatorSettings.
    """

    def __init__(self, session: zenoh.Session, feeds: dict, settings: EmulatorSettings):
        self.session, self.feeds, self.settings = session, feeds, settings
        self.devices: list[Device] = []
        # longer feeds take the lower slots: the devices still streaming at any tick are a prefix of the bank
        by_length = sorted(feeds, key=lambda subject: -(feeds[subject].length or math.inf))
        self._by_length = [feeds[subject] for subject in by_length]
        self._ending: dict[int, list[Device]] = {}  # last sample index -> devices whose stream ends there
        for subject in by_length:
            length = feeds[subject].length
            for segment in feeds[subject].segments:
                d = Device(subject, segment, len(self.devices), random.getrandbits(16),
                           config=settings.config, length=length)
                self.devices.append(d)
                if length is not None:
                    self._ending.setdefault(length - 1, []).append(d)
        self.bank = kernel.SegmenterBank(len(self.devices), settings.config.threshold, settings.config.max_len)
        self.length = max((f.length or 0) for f in feeds.values()) if all(f.length for f in feeds.values()) else None
        self.tick_stats = TickStats()
        batch = settings.raw_batch
        self._ring_t = np.zeros(batch, np.int64)                         # last `batch` sample times
        self._ring_q = np.zeros((batch, len(self.devices), 4), np.float32)  # and samples of every device
        self.start_us = 0
        self.samples = 0
        self.finished = threading.Event()
        self._declared = False

    # ------------------------------------------------------------------ zenoh objects

    def declare(self) -> None:
        """Publishers, liveliness tokens and config queryables."""
        s = self.settings
        for d in self.devices:
            d.publisher = zext.declare_advanced_publisher(
                self.session, wire.seg_key(d.subject, d.segment),
                cache=zext.CacheConfig(max_samples=s.cache),
                sample_miss_detection=zext.MissDetectionConfig(heartbeat=s.heartbeat_s),
                publisher_detection=True,
                congestion_control=zenoh.CongestionControl.BLOCK,  # never drop a point under load
            )
            d.token = self.session.liveliness().declare_token(wire.alive_key(d.subject, d.segment))
        # the truth tap is recoverable too (cache: 64 batches, 32 s at 50 Hz), so a router restart or a
        # cut link costs no evaluation samples and the live AAD matches a fault-free run
        self._raw_pubs = (
            {d.slot: zext.declare_advanced_publisher(
                self.session, wire.raw_key(d.subject, d.segment), cache=zext.CacheConfig(max_samples=64),
                sample_miss_detection=zext.MissDetectionConfig(heartbeat=s.heartbeat_s), publisher_detection=True)
             for d in self.devices}
            if s.truth else {}
        )
        self._queries = [
            (self.session.declare_queryable(wire.device_selector("config", subject), zenoh.handlers.FifoChannel(1024)),
             {zenoh.KeyExpr(wire.config_key(d.subject, d.segment)): d for d in self.devices if d.subject == subject})
            for subject in self.feeds
        ]
        self._declared = True

    def undeclare(self) -> None:
        """Drop tokens and publishers (devices go offline)."""
        for d in self.devices:
            for obj in (d.token, d.publisher):
                if obj is not None:
                    obj.undeclare()
            d.token = d.publisher = None

    # ------------------------------------------------------------------ config

    def _answer_queries(self) -> None:
        """Apply config queries that arrived since the last tick (never inside a callback)."""
        for queryable, devices in self._queries:
            while (query := queryable.try_recv()) is not None:
                self._answer(query, devices)

    def _answer(self, query: zenoh.Query, devices: dict) -> None:
        """Apply and answer one query on a subject's queryable; ``devices``: its {config key: Device}."""
        targets = [d for key, d in devices.items() if key.intersects(query.key_expr)]
        payload = query.payload.to_bytes() if query.payload is not None else b""
        for d in targets:
            if payload:
                try:
                    config = wire.decode_config(payload, d.config)
                except wire.WireError as exc:
                    query.reply_err(json.dumps({"error": str(exc)}))
                    return
                self.bank.retune(d.slot, config.threshold, config.max_len)
                d.config = config
                log.info("%s: %s", d.id, config)
            query.reply(wire.config_key(d.subject, d.segment), wire.encode_status(d.status(self.samples)))

    # ------------------------------------------------------------------ ticks

    def _publish_points(self, k: int, status: np.ndarray, index: np.ndarray, y: np.ndarray) -> None:
        period_us = 1e6 / self.settings.fs
        for slot in np.flatnonzero(status == kernel.POINT):
            self._publish_point(self.devices[slot], int(index[slot]), y[slot], period_us, 0)

    def _publish_point(self, d: Device, index: int, y: np.ndarray, period_us: float, flags: int) -> None:
        point = wire.SegmentPoint(d.stream, d.seq, index, self.start_us + round(index * period_us),
                                  tuple(float(v) for v in y), flags)
        d.publisher.put(wire.encode_point(point))
        d.seq = (d.seq + 1) & 0xFFFFFFFF
        d.points += 1

    def _tap(self, k: int, t_us: int, samples: np.ndarray) -> None:
        """Truth tap: keep the last raw_batch samples of every streaming device (the first
        len(samples) slots) in a ring; each publishes its batch when full, staggered over
        devices so each tick sends a few."""
        batch = self.settings.raw_batch
        self._ring_t[k % batch] = t_us
        self._ring_q[k % batch, : len(samples)] = samples
        for slot in range(-(k % batch) % batch, len(samples), batch):  # (k + slot) % batch == 0
            self._flush_tap(self.devices[slot], k)

    def _flush_tap(self, d: Device, k: int) -> None:
        """Publish device d's samples d.raw_next .. k (at most raw_batch, all still in the ring)."""
        if k < d.raw_next:
            return
        rows = np.arange(d.raw_next, k + 1) % self.settings.raw_batch
        payload = wire.encode_raw(wire.RawBatch(d.stream, d.raw_next, self._ring_t[rows], self._ring_q[rows, d.slot]))
        self._raw_pubs[d.slot].put(payload)
        d.raw_next = k + 1

    def step(self, k: int) -> None:
        """Sample k of every device whose stream has not ended: kernel, segment points, truth
        tap; the end of the streams whose last sample this is; config."""
        t_us = self.start_us + round(k * 1e6 / self.settings.fs)
        live = [feed for feed in self._by_length if feed.length is None or k < feed.length]
        samples = np.concatenate([feed.sample(k) for feed in live])
        ticks = np.full(len(samples), (t_us - self.start_us) & 0xFFFFFFFF, np.uint32)
        status, index, y = self.bank.update(ticks, samples)  # the first len(samples) slots
        self.samples = k + 1
        self._publish_points(k, status, index, y)
        if self.settings.truth:
            self._tap(k, t_us, samples)
        for d in self._ending.get(k, ()):
            self._end(d)
        self._answer_queries()

    def _end(self, d: Device) -> None:
        """End device d's stream after its last sample: flush its last point (FINAL) and its truth tap."""
        last = self.bank.flush(d.slot)
        if last is not None:
            self._publish_point(d, last[0], last[2], 1e6 / self.settings.fs, wire.FLAG_FINAL)
        if self.settings.truth:
            self._flush_tap(d, self.samples - 1)

    def finish(self) -> None:
        """End of a finite run: end every stream that has not ended yet."""
        for d in self.devices:
            if d.length is None or d.length > self.samples:
                self._end(d)
        self.finished.set()

    def run(self, stop: threading.Event, duration_s: float | None = None) -> TickStats:
        """Tick in real time (scaled by speed) until ``stop``, the end of a finite source,
        or ``duration_s`` seconds of device time. Keeps serving queries after a finite end."""
        if not self._declared:
            self.declare()
        s = self.settings
        period = 1.0 / (s.fs * s.speed)
        for feed in self.feeds.values():  # generate every feed's first chunk before the clock starts
            feed.sample(0)
        self.start_us = int(time.time() * 1e6)
        n_ticks = self.length
        if duration_s is not None:
            n_ticks = min(n_ticks or 1 << 62, int(round(duration_s * s.fs)))
        start = time.perf_counter()
        k = 0
        while not stop.is_set() and (n_ticks is None or k < n_ticks):
            deadline = start + k * period
            now = time.perf_counter()
            if now < deadline:
                stop.wait(deadline - now)
                if stop.is_set():
                    break
            elif now - deadline > period:
                self.tick_stats.late += 1
                self.tick_stats.max_late_s = max(self.tick_stats.max_late_s, now - deadline)
            began = time.perf_counter()
            self.step(k)
            self.tick_stats.busy_s += time.perf_counter() - began
            self.tick_stats.ticks += 1
            k += 1
        if n_ticks is not None and k >= n_ticks:
            self.finish()
            while not stop.wait(0.05):  # keep serving config queries and the recovery cache
                self._answer_queries()
        return self.tick_stats
