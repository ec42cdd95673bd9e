"""Emulated IMU devices: each samples its subject's motion on its own clock, runs the C fastSW
kernel with its own state, and publishes only its segment points over Zenoh, stamped on the
common time base (device_emulator/sync_client.py).

All devices of one process advance together, one tick at a time, through one
:class:`limbstream.kernel.SegmenterBank` call, which also returns the segment points emitted as
their wire messages, encoded in C (published as they are). With clocks of their own (``--clock-*``), each
device samples on its own clock's grid: ticks come at ``rate * (1 + max drift)`` and a device
whose next sample is not due yet gives the kernel no sample that tick (a NaN row, rejected
without touching its state; the kernel's index, which counts calls, is mapped back to the
device's sample number); its sample is the motion at the sample's true instant (SLERP between
the feed's samples). A device whose feed ends (``--once``, clips of different lengths)
publishes its last point as FINAL then, and nothing after it. Per device: an advanced publisher
for segment points (cache for recovery, miss detection), a liveliness token, a share of one
config queryable per subject, optionally the truth tap (raw sample batches with each sample's
reference time), and its time exchange. A device whose time base steps (its first sync after
starting unsynced, or a resync after its holdover that moved more than 128 ms) starts a new
stream. Zenoh callbacks are not used: queries go to a FIFO channel read between ticks.
"""
from __future__ import annotations

import logging
import math
import random
import threading
import time
from dataclasses import dataclass, field, replace

import numpy as np
import zenoh

from limbstream.device_emulator import device_io
from limbstream.device_emulator.device_clocks import ClockSettings, DeviceClocks, TimeBase
from limbstream.device_emulator.sync_client import SyncClient
from limbstream import kernel, quat, wire
from limbstream.calibration import SensorModel

log = logging.getLogger("limbstream.emulator")
QUERIES_PER_TICK = 10
"""Config queries a tick answers at most (each answers one subject's devices: 10 replies)."""

RING_MIN = 4
"""Ticks of samples kept at least (segment points refer to the last one or two)."""


@dataclass(frozen=True)
class EmulatorSettings:
    """What one emulator process runs.

    Attributes
    ----------
    fs : device sample rate, Hz (of each device's own clock).
    speed : time scale: 1 = real time, 10 = ten times faster (device clocks run faster too).
    config : initial fastSW settings of every device (limbstream.wire.TUNABLES).
    truth : publish raw samples on the truth tap.
    raw_batch : samples per truth-tap message.
    cache : segment points each device keeps for recovery (advanced publisher cache).
    heartbeat_s : miss-detection heartbeat period, seconds.
    clock : the devices' clocks and their sync.
    anchor_us : the instant the scaled time base agrees with the host clock (with speed != 1 the
        time service must use the same); None: the emulator's start.
    clock_id : distinguishes this process's clock draws from other processes' (first subject).
    sensors : the sensors' errors (mounting, heading, drift; limbstream.calibration): on, each
        device compresses what its sensor reports while its truth tap carries the segment's true
        orientation.
    """

    fs: float = 50.0
    speed: float = 1.0
    config: wire.DeviceConfig = wire.DeviceConfig()
    truth: bool = True
    raw_batch: int = 25
    cache: int = 512
    heartbeat_s: float = 0.5
    clock: ClockSettings = field(default_factory=ClockSettings)
    sensors: SensorModel = field(default_factory=SensorModel)
    anchor_us: float | None = None
    clock_id: int = 0


@dataclass
class Device:
    """Book-keeping of one emulated device (the kernel state and the wire fields of its points,
    stream id, next sequence number and base, live in the bank: ``bank.stream[slot]`` ...)."""

    subject: str
    segment: str
    slot: int
    publisher: object = None
    token: object = None
    points: int = 0
    config: wire.DeviceConfig = wire.DeviceConfig()
    raw_next: int = 0  # first tick whose sample is not yet on the truth tap
    length: int | None = None  # feed samples of its clip, None: endless
    restarts: int = 0  # streams started after the first (time base steps)
    last: bytes | None = None  # the newest segment point published in the current stream

    @property
    def id(self) -> str:
        return wire.device_id(self.subject, self.segment)


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
        self._feed_slots: list[tuple[int, int]] = []  # (first slot, last slot + 1) of each feed, in slot order
        for subject in by_length:
            first = len(self.devices)
            for segment in feeds[subject].segments:
                self.devices.append(Device(subject, segment, len(self.devices), config=settings.config,
                                           length=feeds[subject].length))
            self._feed_slots.append((first, len(self.devices)))
        n = len(self.devices)
        ring = max(settings.raw_batch, RING_MIN)
        # the bank encodes the points: it holds each device's stream id, sequence number, base and
        # the ring of sample numbers and stamps they refer to
        self.bank = kernel.SegmenterBank(n, settings.config.threshold, settings.config.max_len,
                                         live_bound_deg=settings.config.live_bound_deg, ring=ring)
        self.bank.stream[:n] = [random.getrandbits(16) for _ in range(n)]
        self.period_us = 1e6 / settings.fs
        c = settings.clock
        self.base = TimeBase(settings.speed, settings.anchor_us)
        self.clocks = DeviceClocks(n, c, self.period_us, self.base, seed=settings.clock_id)
        self.modelled = c.modelled
        # ticks come often enough that no clock needs two samples in one
        self.tick_us = self.period_us / (1.0 + self.clocks.max_drift)
        self.sync = SyncClient(session, self.clocks, c, [d.id for d in self.devices]) if c.sync else None
        self.n = np.zeros(n, np.int64)  # samples each device has taken
        self.ended = np.zeros(n, bool)  # its stream ended (finite feed)
        self._m: int | None = None       # see _streaming
        self._rows: dict[tuple[int, int], np.ndarray] = {}  # see _row
        # last sample each device may take (a finite feed ends when its clip's true time does)
        ends = np.array([(d.length - 1) if d.length else -1 for d in self.devices], np.float64)
        last = np.floor(((ends * self.period_us) * (1.0 + self.clocks.drift) - self.clocks.phase_us) / self.period_us)
        self.n_last = np.where(ends >= 0, last, np.inf)
        self.tick_stats = TickStats()
        self.sensors = settings.sensors.draw(n, stream=settings.clock_id) if settings.sensors.on else None
        self._ring = ring
        self._ring_n = self.bank.sample                       # sample number taken at each tick (-1: none)
        self._ring_t = self.bank.t_us                         # its stamp (common time base), us
        self._ring_ref = np.zeros((ring, n), np.int64)        # its reference (true) time, us
        self._ring_q = np.zeros((ring, n, 4), np.float32)     # its value
        self.start_us = 0
        self.ticks = 0
        self.finished = threading.Event()
        self._declared = False

    # ------------------------------------------------------------------ zenoh objects

    def declare(self) -> None:
        """Publishers, liveliness tokens and config queryables."""
        s = self.settings
        for d in self.devices:
            d.publisher = device_io.point_publisher(self.session, d.subject, d.segment, s.cache, s.heartbeat_s)
            d.token = device_io.alive_token(self.session, d.subject, d.segment)
        self._raw_pubs = ({d.slot: device_io.raw_publisher(self.session, d.subject, d.segment, s.heartbeat_s)
                           for d in self.devices} if s.truth else {})
        self._queries = [
            (self.session.declare_queryable(wire.device_selector("config", subject), zenoh.handlers.FifoChannel(1024)),
             {zenoh.KeyExpr(wire.config_key(d.subject, d.segment)): d for d in self.devices if d.subject == subject})
            for subject in self.feeds
        ]
        self._declared = True

    def undeclare(self) -> None:
        """Drop tokens and publishers (devices go offline); stop the time exchange."""
        if self.sync is not None:
            self.sync.close()
        for d in self.devices:
            for obj in (d.token, d.publisher):
                if obj is not None:
                    obj.undeclare()
            d.token = d.publisher = None

    # ------------------------------------------------------------------ config and status

    def status(self, d: Device) -> wire.DeviceStatus:
        """The device's own view: config, counters of its current stream, clock sync."""
        clock = self.sync.status(d.slot) if self.sync is not None else wire.ClockStatus()
        b = self.bank
        return wire.DeviceStatus(d.id, d.config, int(b.stream[d.slot]), int(self.n[d.slot] - b.base[d.slot]),
                                 d.points, clock, self.feeds[d.subject].rest_pose)

    def _answer_queries(self, budget: int = QUERIES_PER_TICK) -> None:
        """Apply config queries that arrived since the last tick (never inside a callback), at
        most ``budget`` of them: an aggregator's status poll asks every subject at once, and
        answering 100 subjects' devices in one tick would make it late; the rest wait a tick."""
        for queryable, devices in self._queries:
            while budget > 0 and (query := queryable.try_recv()) is not None:
                self._answer(query, devices)
                budget -= 1

    def _answer(self, query: zenoh.Query, devices: dict) -> None:
        """Apply and answer one query on a subject's queryable; ``devices``: its {config key: Device}."""
        targets = [d for key, d in devices.items() if key.intersects(query.key_expr)]
        device_io.answer_config(query, targets, self._apply, self.status)

    def _apply(self, d: Device, config: wire.DeviceConfig) -> None:
        self.bank.retune(d.slot, config.threshold, config.max_len, config.live_bound_deg)
        d.config = config

    # ------------------------------------------------------------------ samples

    def _take(self, k: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Which of the first ``m`` devices take a sample at tick k: (slots (j,), their sample
        numbers (j,), values (j, 4) float32)."""
        t_k = self.start_us + k * self.tick_us
        slots = np.arange(m)
        n = self.n[:m]
        live = ~self.ended[:m]
        if not self.modelled:  # every device samples at every tick, on the feed's own grid
            taken = slots[live]
            return taken, n[live], np.concatenate([f.sample(k) for f in self._live_feeds(m)])[live]
        tau = self.clocks.sample_time(n, slots)
        due = live & (tau <= t_k + 0.5)
        taken = slots[due]
        x = (tau[due] - self.start_us) / self.period_us  # position on the feed's grid
        j0 = max(0, math.floor((t_k - self.tick_us - self.start_us) / self.period_us))
        j = np.clip(np.floor(x).astype(np.int64), j0, j0 + 1)
        u = np.clip(x - j, 0.0, 1.0)
        rows = [self._row(j0 + r, m) for r in range(3)]
        first = (j == j0)[:, None]
        a = np.where(first, rows[0][taken], rows[1][taken])
        b = np.where(first, rows[1][taken], rows[2][taken])
        q = np.where((u == 0)[:, None], a, quat.slerp(a, b, u).astype(np.float32))
        return taken, n[due], q

    def _row(self, j: int, m: int) -> np.ndarray:
        """(m, 4) the feed samples j of the first m devices (finite feeds hold their last one),
        cached: consecutive ticks ask for overlapping rows."""
        row = self._rows.get((j, m))
        if row is None:
            row = self._rows[j, m] = np.concatenate([
                f.sample(j if f.length is None else min(j, f.length - 1)) for f in self._live_feeds(m)])
            for key in [key for key in self._rows if key[0] < j - 2]:
                del self._rows[key]
        return row

    def _live_feeds(self, m: int) -> list:
        return self._by_length[:sum(1 for first, _ in self._feed_slots if first < m)]

    def _streaming(self) -> int:
        """Slots of the bank still in use: those up to the last feed with a device not ended
        (recomputed when a stream ends)."""
        if self._m is None:
            self._m = 0
            for first, end in self._feed_slots:
                if not self.ended[first:end].all():
                    self._m = end
        return self._m

    # ------------------------------------------------------------------ ticks

    def _publish_points(self, slots: np.ndarray, payload: bytes, ends: np.ndarray) -> None:
        """The segment points of a tick, as the bank encoded them (message i of device slots[i]
        is payload[ends[i - 1]:ends[i]])."""
        start = 0
        for slot, end in zip(slots.tolist(), ends.tolist()):
            d = self.devices[slot]
            d.last = payload[start:end]
            d.publisher.put(d.last)
            d.points += 1
            start = end

    def _publish_held(self, d: Device, tick: int, y: np.ndarray, flags: int) -> None:
        """Device d's segment point outside the bank's update (a flushed point, a new stream's
        first point): the sample it took at ``tick`` (within the ring), held (rate 0: version 2
        with the live rule on, version 1 off)."""
        b, row = self.bank, tick % self._ring
        point = wire.SegmentPoint(int(b.stream[d.slot]), int(b.seq[d.slot]),
                                  int(self._ring_n[row, d.slot] - b.base[d.slot]), int(self._ring_t[row, d.slot]),
                                  tuple(float(v) for v in y), flags, (0.0, 0.0, 0.0) if b.live(d.slot) else None)
        d.last = wire.encode_point(point)
        d.publisher.put(d.last)
        b.seq[d.slot] = (int(b.seq[d.slot]) + 1) & 0xFFFFFFFF
        d.points += 1

    def _publish_final(self, d: Device) -> None:
        """End device d's stream: flush its last point (FINAL), or, when its last sample already
        went out as a point (the live rule closed it), repeat that point with FINAL as the end
        marker (the next sequence number; docs/protocol.md)."""
        last = self.bank.flush(d.slot)
        if last is not None:
            self._publish_held(d, int(last[0]), last[2], wire.FLAG_FINAL)
        elif d.last is not None:
            point = replace(wire.decode_point(d.last), seq=int(self.bank.seq[d.slot]), flags=wire.FLAG_FINAL)
            d.publisher.put(wire.encode_point(point))
            self.bank.seq[d.slot] = (int(self.bank.seq[d.slot]) + 1) & 0xFFFFFFFF

    def _tap(self, k: int, m: int) -> None:
        """Truth tap: each streaming device publishes its samples of the last raw_batch ticks,
        staggered over devices so each tick sends a few."""
        batch = self.settings.raw_batch
        for slot in range(-(k % batch) % batch, m, batch):  # (k + slot) % batch == 0
            if not self.ended[slot]:
                self._flush_tap(self.devices[slot], k)

    def _flush_tap(self, d: Device, k: int) -> None:
        """Publish device d's samples of ticks d.raw_next .. k (all still in the ring)."""
        if k < d.raw_next:
            return
        rows = np.arange(d.raw_next, k + 1) % self._ring
        rows = rows[self._ring_n[rows, d.slot] >= 0]
        d.raw_next = k + 1
        if len(rows) == 0:
            return
        payload = wire.encode_raw(wire.RawBatch(
            int(self.bank.stream[d.slot]), int(self._ring_n[rows[0], d.slot] - self.bank.base[d.slot]),
            self._ring_t[rows, d.slot],
            self._ring_q[rows, d.slot], self._ring_ref[rows, d.slot]))
        self._raw_pubs[d.slot].put(payload)

    def step(self, k: int) -> None:
        """Tick k: the samples due, their stamps, kernel, segment points, truth tap; the end of
        the streams whose last sample this was; new streams where a time base stepped; config."""
        m = self._streaming()
        taken, n, q = self._take(k, m)
        local = self.clocks.sample_local(n, taken) + self.clocks.jitter(len(taken))
        stamps = self.sync.stamp(taken, local) if self.sync is not None else local
        row = k % self._ring
        self._ring_n[row, :] = -1
        self._ring_n[row, taken] = n
        self._ring_t[row, taken] = np.round(stamps).astype(np.int64)
        self._ring_ref[row, taken] = np.round(self.clocks.sample_time(n, taken)).astype(np.int64)
        self._ring_q[row, taken] = q
        if self.sync is not None and self.sync.steps:
            for slot in taken[self.sync.stepped[taken]]:
                self._new_stream(self.devices[slot], k)
        y = np.full((m, 4), np.nan, np.float32)  # devices without a sample this tick: rejected, state kept
        y[taken] = q if self.sensors is None else self.sensors.report_many(taken, n / self.settings.fs, q)
        ticks = (np.round(self.clocks.phase_us[:m] + self.n[:m] * self.period_us).astype(np.int64)
                 & 0xFFFFFFFF).astype(np.uint32)
        self._publish_points(*self.bank.update_wire(ticks, y))
        self.n[taken] += 1
        self.ticks = k + 1
        if self.settings.truth:
            self._tap(k, m)
        for slot in taken[self.n[taken] > self.n_last[taken]]:
            self._end(self.devices[slot], k)
        self._answer_queries()

    def _new_stream(self, d: Device, k: int) -> None:
        """Device d's time base stepped at tick k: end its stream at its previous sample (FINAL
        if the kernel holds one to flush) and start a new one from that sample, restamped."""
        prev = (k - 1) % self._ring
        if k == 0 or self._ring_n[prev, d.slot] < 0:
            prev = (k - 2) % self._ring  # the tick before was a skip
        if self._ring_n[prev, d.slot] < 0:
            return
        if self.settings.truth:
            self._flush_tap(d, k - 1)
        self._publish_final(d)
        n_prev = self._ring_n[prev, d.slot]
        local = self.clocks.sample_local(np.array([n_prev]), np.array([d.slot]))[0]
        self._ring_t[prev, d.slot] = round(local + self.sync.c[d.slot] - self.sync.b[d.slot] * (
            self.sync.c_local[d.slot] - local))
        b = self.bank
        b.stream[d.slot], b.seq[d.slot], b.base[d.slot] = random.getrandbits(16), 0, n_prev
        d.points, d.last = 0, None
        d.restarts += 1
        d.raw_next = k
        self._publish_held(d, self._tick_of(prev, k), self._ring_q[prev, d.slot], 0)
        log.info("%s: time base stepped, new stream %d", d.id, b.stream[d.slot])

    def _tick_of(self, row: int, k: int) -> int:
        """The tick (<= k) whose samples ring row ``row`` holds."""
        return k - ((k - row) % self._ring)

    def _end(self, d: Device, k: int) -> None:
        """End device d's stream after its last sample (tick k): flush its last point (FINAL)
        and its truth tap."""
        self._publish_final(d)
        if self.settings.truth:
            self._flush_tap(d, k)
        self.ended[d.slot] = True
        self._m = None

    def finish(self) -> None:
        """End of a finite run: end every stream that has not ended yet."""
        for slot in np.flatnonzero(~self.ended):
            self._end(self.devices[slot], self.ticks - 1)
        self.finished.set()

    def start_clocks(self, stop: threading.Event) -> None:
        """Devices power up: their clocks start; with sync, their first exchanges (waits at most
        the clock settings' wait_s, less if no time service is reachable)."""
        self.clocks.boot(self.base.now_us())
        if self.sync is not None:
            self.sync.start()
            self.sync.wait_first(stop)

    def run(self, stop: threading.Event, duration_s: float | None = None) -> TickStats:
        """Tick in real time (scaled by speed) until ``stop``, the end of a finite source,
        or ``duration_s`` seconds of device time. Keeps serving queries after a finite end."""
        if not self._declared:
            self.declare()
        s = self.settings
        for feed in self.feeds.values():  # generate every feed's first chunk before the clock starts
            feed.sample(0)
        if not self.clocks.boot_us:
            self.start_clocks(stop)
        period = self.tick_us / 1e6 / s.speed
        n_ticks = None if duration_s is None else int(round(duration_s * 1e6 / self.tick_us))
        start = time.perf_counter()
        self.start_us = int(round(self.base.now_us()))
        self.clocks.start_grid(self.start_us)
        k = 0
        while not stop.is_set() and (n_ticks is None or k < n_ticks) and not self.ended.all():
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
            if self.sync is not None:
                self.sync.poll()
            self.tick_stats.busy_s += time.perf_counter() - began
            self.tick_stats.ticks += 1
            k += 1
        if not stop.is_set() and (self.ended.all() or (n_ticks is not None and k >= n_ticks)):
            self.finish()
            while not stop.wait(0.05):  # keep serving config queries, the recovery cache and the exchange
                self._answer_queries()
                if self.sync is not None:
                    self.sync.poll()
        return self.tick_stats
