"""Emulated IMU devices: each samples its subject's motion on its own clock, runs the C fastSW
kernel with its own state, and publishes only its segment points over Zenoh, stamped on the
common time base (:mod:`limbstream.device.sync`).

Where the samples come from is this module: each subject's motion feed
(:mod:`limbstream.device.feeds`), sampled on every device's own clock. What a device does with
a sample, and its Zenoh side, are the device host's (:mod:`limbstream.device`): all devices of one
process advance together, one tick at a time, through one :class:`~limbstream.device.bank.DeviceBank`
call. With clocks of their own (``--clock-*``), each device samples on its own clock's grid:
ticks come at ``rate * (1 + max drift)`` and a device whose next sample is not due yet gives the
kernel no sample that tick (a NaN row, rejected without touching its state; the kernel's index,
which counts calls, is mapped back to the device's sample number); its sample is the motion at
the sample's true instant (SLERP between the feed's samples). A device whose feed ends
(``--once``, clips of different lengths) publishes its last point as FINAL then, and nothing
after it. The truth tap carries raw sample batches with each sample's reference time and the
device's own orientation (what its kernel compressed: its sensor's reading); with
``HostSettings.truth_by_subject`` (``limbstream emulate``) one message per subject and batch. A device
whose time base steps (its first sync after starting unsynced, or a resync after its holdover
that moved more than 128 ms) starts a new stream.

With raw sensors (``EmulatorSettings.imu``), each subject's feed is a
:class:`~limbstream.device.readings.RawFeed` and each tick brings every device the raw samples
its sensor reads over one device period (:class:`~limbstream.device.readings.RawSensors`), fused
by the bank's raw stage; the truth tap carries the segments' true orientations at the devices'
instants. Device clocks are then the feed's own (no offset, drift or jitter models).
"""
from __future__ import annotations

import bisect
import logging
import math
import threading
from dataclasses import dataclass, field

import numpy as np
import zenoh

from limbstream import quat, wire
from limbstream.calibration import SensorModel
from limbstream.device.bank import DeviceBank, RawStage
from limbstream.device.clocks import ClockSettings, DeviceClocks, TimeBase
from limbstream.device.feeds import FeedRows
from limbstream.device.host import Device, DeviceHost, HostSettings
from limbstream.device.readings import RawSensors
from limbstream.device.sync import SyncClient
from limbstream.imu import ImuModel
from limbstream.kernel import fusion
from limbstream.pacing import LoopStats, PacedLoop

log = logging.getLogger("limbstream.emulator")

RING_MIN = 4
"""Ticks of samples kept at least (segment points refer to the last one or two)."""


@dataclass(frozen=True)
class EmulatorSettings:
    """What one emulator process runs.

    Attributes
    ----------
    host : what every device shares (rate, initial config, truth tap, recovery cache).
    speed : time scale: 1 = real time, 10 = ten times faster (device clocks run faster too).
    clock : the devices' clocks and their sync.
    anchor_us : the instant the scaled time base agrees with the host clock (with speed != 1 the
        time service must use the same); None: the emulator's start.
    clock_id : distinguishes this process's clock draws from other processes' (first subject).
    sensors : the sensors' errors (mounting, heading, drift; limbstream.calibration): on, each
        device compresses what its sensor reports while its truth tap carries the segment's true
        orientation. With ``imu``: each sensor's mounting and its filter's start heading.
    imu : the part of raw sensors (feeds are RawFeeds, ``imu_rate_hz``): each device fuses raw
        samples (:class:`~limbstream.device.bank.RawStage`); None: devices are handed their
        sensors' orientations.
    imu_rate_hz : the raw sensors' rate, Hz.
    vqf_precision : the devices' VQF precision (``fusion.VQF_PRECISIONS``; default the firmware's).
    """

    host: HostSettings = HostSettings()
    speed: float = 1.0
    clock: ClockSettings = field(default_factory=ClockSettings)
    sensors: SensorModel = field(default_factory=SensorModel)
    anchor_us: float | None = None
    clock_id: int = 0
    imu: ImuModel | None = None
    imu_rate_hz: float = 200.0
    vqf_precision: str = fusion.DEFAULT_VQF_PRECISION


class Emulator:
    """Devices of several subjects in one process.

    Parameters
    ----------
    session : an open Zenoh session (client).
    feeds : {subject: feed}, a feed has ``segments``, ``sample(k) -> (S, 4) float32``,
        ``length`` (samples, or None for endless), ``rest_pose`` and, optionally, ``body`` (its
        wearer's dimensions, :class:`limbstream.body.Body`, which its devices announce).
    settings : EmulatorSettings.
    """

    def __init__(self, session: zenoh.Session, feeds: dict, settings: EmulatorSettings):
        self.session, self.feeds, self.settings = session, feeds, settings
        hs = settings.host
        self.host: DeviceHost = DeviceHost(session, hs, self._configure, self._status)
        # longer feeds take the lower slots: the devices still streaming at any tick are a prefix of the bank
        by_length = sorted(feeds, key=lambda subject: -(feeds[subject].length or math.inf))
        self._by_length = [feeds[subject] for subject in by_length]
        self._feed_rows = FeedRows(self._by_length)
        self._feed_slots: list[tuple[int, int]] = []  # (first slot, last slot + 1) of each feed, in slot order
        for subject in by_length:
            first = len(self.host.devices)
            for segment in feeds[subject].segments:
                self.host.add(subject, segment, feeds[subject])
            self._feed_slots.append((first, len(self.host.devices)))
        self._feed_first = [first for first, _ in self._feed_slots]
        self.devices: list[Device] = self.host.devices
        n = len(self.devices)
        ring = max(hs.raw_batch, RING_MIN)
        self.raw: RawSensors | None = None
        if settings.imu is not None:
            if settings.clock.modelled:
                raise ValueError("raw sensors sample on the feed's own clock: device clock models (--clock-offset-ms, "
                                 "--clock-drift-ppm, --clock-jitter-us) are not available with them")
            self.raw = RawSensors(self._by_length, settings.imu, settings.imu_rate_hz, settings.sensors,
                                  settings.clock_id)
        self.bank = DeviceBank(self.host, n, ring, None if self.raw is None else
                               RawStage(settings.imu_rate_hz, self.raw.devices.heading,
                                                        vqf_precision=settings.vqf_precision))
        for d in self.devices:
            self.bank.start_stream(d, 0)
        self.n = self.bank.n  # samples each device has taken
        self.period_us = 1e6 / hs.fs
        c = settings.clock
        self.base = TimeBase(settings.speed, settings.anchor_us)
        self.clocks = DeviceClocks(n, c, self.period_us, self.base, seed=settings.clock_id)
        self.modelled = c.modelled
        # ticks come often enough that no clock needs two samples in one
        self.tick_us = self.period_us / (1.0 + self.clocks.max_drift)
        self.sync = SyncClient(session, self.clocks, c, [d.id for d in self.devices]) if c.sync else None
        self.ended = np.zeros(n, bool)  # its stream ended (finite feed)
        self.raw_next = np.zeros(n, np.int64)  # first tick whose sample is not yet on the truth tap
        self._m: int | None = None       # see _streaming
        self._rows: dict[tuple[int, int], np.ndarray] = {}  # see _row
        # last sample each device may take (a finite feed ends when its clip's true time does)
        ends = np.array([(d.source.length - 1) if d.source.length else -1 for d in self.devices], np.float64)
        last = np.floor(((ends * self.period_us) * (1.0 + self.clocks.drift) - self.clocks.phase_us) / self.period_us)
        self.n_last = np.where(ends >= 0, last, np.inf)
        self._finite = bool((ends >= 0).any())  # a feed ends
        on = settings.sensors.on and self.raw is None
        self.sensors = settings.sensors.draw(n, stream=settings.clock_id) if on else None
        self._ring = ring
        self._ring_n = self.bank.kernel.sample                # sample number taken at each tick (-1: none)
        self._ring_t = self.bank.kernel.t_us                  # its stamp (common time base), us
        if self.raw is not None:  # the kernel's rows are its fastSW calls': the tap's by tick
            self._ring_n, self._ring_t = np.full((ring, n), -1, np.int64), np.zeros((ring, n), np.int64)
        self._ring_ref = np.zeros((ring, n), np.int64)        # its reference (true) time, us
        self._ring_q = np.zeros((ring, n, 4), np.float32)     # its value
        self._ring_own = np.zeros((ring, n, 4), np.float32)   # what the device compressed (its own orientation)
        self.start_us = 0
        self.ticks = 0
        self.finished = threading.Event()

    # ------------------------------------------------------------------ zenoh objects

    def declare(self) -> None:
        """Publishers, config queryables; every device comes online."""
        self.host.declare()
        for d in self.devices:
            self.host.online(d)

    def undeclare(self) -> None:
        """Devices go offline; the time exchange stops."""
        if self.sync is not None:
            self.sync.close()
        self.host.close()

    def _status(self, d: Device) -> wire.DeviceStatus:
        """The device's own view: config, counters of its current stream, clock sync, what its
        orientations are (its sensor's reading under a sensor model, else its feed's) and its
        feed's body."""
        clock = self.sync.status(d.slot) if self.sync is not None else wire.ClockStatus()
        orientations = "sensors" if self.sensors is not None else d.source.orientations
        return self.bank.status(d, clock, d.source.rest_pose, orientations=orientations,
                                body=getattr(d.source, "body", None))

    def _configure(self, d: Device, config: wire.DeviceConfig) -> None:
        self.bank.configure(d, config)

    # ------------------------------------------------------------------ samples

    def _take(self, k: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Which of the first ``m`` devices take a sample at tick k: (slots (j,), their sample
        numbers (j,), values (j, 4) float32)."""
        t_k = self.start_us + k * self.tick_us
        slots = np.arange(m)
        n = self.n[:m]
        live = ~self.ended[:m]
        if not self.modelled:  # every device samples at every tick, on the feed's own grid
            rows = self._feed_rows.rows(k, self._feeds_in(m))
            if live.all():
                return slots, n.copy(), rows
            return slots[live], n[live], rows[live]
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
            row = self._rows[j, m] = self._feed_rows.rows(j, self._feeds_in(m))
            for key in [key for key in self._rows if key[0] < j - 2]:
                del self._rows[key]
        return row

    def _feeds_in(self, m: int) -> int:
        """How many feeds (of ``_by_length``) the first m slots hold."""
        return bisect.bisect_left(self._feed_first, m)

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

    def _tap(self, k: int, m: int) -> None:
        """Truth tap: each streaming device publishes its samples of the last raw_batch ticks,
        staggered over devices so each tick sends a few (with ``truth_by_subject`` over subjects:
        a subject's devices together, one message)."""
        batch = self.settings.host.raw_batch
        if self.settings.host.truth_by_subject:  # all the devices of a subject at once, subjects staggered
            due = [np.arange(first, min(end, m)) for i, (first, end) in enumerate(self._feed_slots)
                   if first < m and (k + i) % batch == 0]
            slots = np.concatenate(due) if due else np.zeros(0, np.int64)
        else:
            slots = np.arange(-(k % batch) % batch, m, batch)  # (k + slot) % batch == 0
        self._flush_tap(slots[~self.ended[slots]], k)

    def _flush_tap(self, slots: np.ndarray, k: int) -> None:
        """Publish the samples of ticks raw_next .. k of the devices ``slots`` (all still in the
        ring), a batch each (none where a device took no sample), encoded together."""
        first = self.raw_next[slots]
        self.raw_next[slots] = np.maximum(first, k + 1)
        ticks = first[:, None] + np.arange(self._ring)  # (j, ring): the ring's ticks from each one's first
        rows, cols = ticks % self._ring, np.broadcast_to(slots[:, None], ticks.shape)
        n = self._ring_n[rows, cols]
        taken = (ticks <= k) & (n >= 0)
        count = taken.sum(axis=1)
        has = count > 0
        if not has.any():
            return
        rows, cols, n, count, slots = rows[taken], cols[taken], n[taken], count[has], slots[has]
        b = self.bank.kernel
        payload, ends = wire.encode_raws(b.stream[slots], n[np.cumsum(count) - count] - b.base[slots], count,
                                         self._ring_t[rows, cols], self._ring_q[rows, cols], self._ring_ref[rows, cols],
                                         self._ring_own[rows, cols])
        self.host.publish_raws(slots, payload, ends)

    def step(self, k: int) -> None:
        """Tick k: the samples due, their stamps, kernel, segment points, truth tap; the end of
        the streams whose last sample this was; new streams where a time base stepped; config."""
        m = self._streaming()
        taken, n, q = self._take(k, m)
        row = k % self._ring
        truth = self.settings.host.truth
        if truth:  # the truth tap's columns
            self._ring_ref[row, taken] = np.round(self.clocks.sample_time(n, taken)).astype(np.int64)
        self._ring_q[row, taken] = q
        if self.raw is not None:
            self._step_raw(k, m, taken)
        else:
            local = self.clocks.sample_local(n, taken) + self.clocks.jitter(len(taken))
            stamps = np.round(self.sync.stamp(taken, local) if self.sync is not None else local).astype(np.int64)
            if self.sync is not None and self.sync.steps:
                for slot in taken[self.sync.stepped[taken]]:
                    self._new_stream(self.devices[slot], k)
            own = q if self.sensors is None else self.sensors.report_many(taken, n / self.settings.host.fs, q)
            if len(taken) == m:
                y = np.asarray(own, np.float32)
            else:  # devices without a sample this tick: rejected, state kept
                y = np.full((m, 4), np.nan, np.float32)
                y[taken] = own
            if truth:
                self._ring_own[row, taken] = y[taken]
            ticks = (np.round(self.clocks.phase_us[:m] + self.n[:m] * self.period_us).astype(np.int64)
                     & 0xFFFFFFFF).astype(np.uint32)
            self.bank.update(ticks, y, taken, stamps)
        self.ticks = k + 1
        if truth:
            self._tap(k, m)
        if self._finite:
            self._end(taken[self.n[taken] > self.n_last[taken]], k)
        self.host.answer_queries()

    def _step_raw(self, k: int, m: int, taken: np.ndarray) -> None:
        """Tick k of raw sensors: the first m devices' raw samples of device sample k, one bank
        call each, stamped on the common time base; a device whose time base steps starts a new
        stream (its fastSW afresh, its filter going on)."""
        assert self.raw is not None
        gyr, acc = self.raw.read(k, np.arange(m))
        per = self.raw.per
        raw_us = self.period_us / per
        row = k % self._ring
        self._ring_n[row, :m] = -1
        b = self.bank
        for i in range(per):
            on_clock = self.clocks.phase_us[:m] + (k * per + i) * raw_us
            stamps = self.clocks.grid_local[:m] + on_clock
            if self.sync is not None:
                stamps[taken] = self.sync.stamp(taken, stamps[taken])
                if i == 0 and self.sync.steps:
                    for slot in taken[self.sync.stepped[taken]]:
                        self._restart_raw(self.devices[slot], k)
            stamps = np.round(stamps).astype(np.int64)
            ticks = (np.round(on_clock).astype(np.int64) & 0xFFFFFFFF).astype(np.uint32)
            took = np.flatnonzero(b.update_raw(ticks, stamps, gyr[i], acc[i]))
            self._ring_n[row, took] = b.kernel.base[took] + b.calls[took] - 1
            self._ring_t[row, took] = stamps[took]
            self._ring_own[row, took] = b.kernel.newest_samples(m)[took]  # its filter's orientation, fused

    def _restart_raw(self, d: Device, k: int) -> None:
        """Device d (raw sensors) starts a new stream at tick k: its stream so far ended (FINAL),
        a fresh fastSW from this tick's sample."""
        if self.settings.host.truth:
            self._flush_tap(np.array([d.slot]), k - 1)
        self.bank.end_stream(d)
        self.bank.start_stream(d, reset=True)
        self.raw_next[d.slot] = k
        log.info("%s: time base stepped, new stream %d", d.id, self.bank.kernel.stream[d.slot])

    def _new_stream(self, d: Device, k: int) -> None:
        """Device d's time base stepped at tick k: end its stream at its previous sample (FINAL
        if the kernel holds one to flush) and start a new one from that sample, restamped."""
        prev = (k - 1) % self._ring
        if k == 0 or self._ring_n[prev, d.slot] < 0:
            prev = (k - 2) % self._ring  # the tick before was a skip
        if self._ring_n[prev, d.slot] < 0:
            return
        if self.settings.host.truth:
            self._flush_tap(np.array([d.slot]), k - 1)
        self.bank.end_stream(d)
        n_prev = self._ring_n[prev, d.slot]
        local = self.clocks.sample_local(np.array([n_prev]), np.array([d.slot]))[0]
        self._ring_t[prev, d.slot] = round(local + self.sync.c[d.slot] - self.sync.b[d.slot] * (
            self.sync.c_local[d.slot] - local))
        self.bank.start_stream(d, n_prev)
        self.raw_next[d.slot] = k
        self.bank.held(d, self._tick_of(prev, k), self._ring_q[prev, d.slot], 0)
        log.info("%s: time base stepped, new stream %d", d.id, self.bank.kernel.stream[d.slot])

    def _tick_of(self, row: int, k: int) -> int:
        """The tick (<= k) whose samples ring row ``row`` holds."""
        return k - ((k - row) % self._ring)

    def _end(self, slots: np.ndarray, k: int) -> None:
        """End the streams of devices ``slots`` after their last sample (tick k): flush each one's
        last point (FINAL), then their truth taps together (per subject: one message)."""
        if len(slots) == 0:
            return
        for slot in slots.tolist():
            self.bank.end_stream(self.devices[slot])
        if self.settings.host.truth:
            self._flush_tap(slots, k)
        self.ended[slots] = True
        self._m = None

    def finish(self) -> None:
        """End of a finite run: end every stream that has not ended yet."""
        self._end(np.flatnonzero(~self.ended), self.ticks - 1)
        self.finished.set()

    def start_clocks(self, stop: threading.Event) -> None:
        """Devices power up: their clocks start; with sync, their first exchanges (waits at most
        the clock settings' wait_s, less if no time service is reachable)."""
        self.clocks.boot(self.base.now_us())
        if self.sync is not None:
            self.sync.start()
            self.sync.wait_first(stop)

    def run(self, stop: threading.Event, duration_s: float | None = None) -> LoopStats:
        """Tick in real time (scaled by speed) until ``stop``, the end of a finite source,
        or ``duration_s`` seconds of device time. Keeps serving queries after a finite end."""
        if not self.host.declared:
            self.declare()
        for feed in self.feeds.values():  # generate every feed's first chunk before the clock starts
            feed.sample(0)
        if not self.clocks.boot_us:
            self.start_clocks(stop)
        loop = PacedLoop(self.tick_us / 1e6 / self.settings.speed)
        n_ticks = None if duration_s is None else int(round(duration_s * 1e6 / self.tick_us))
        self.start_us = int(round(self.base.now_us()))
        self.clocks.start_grid(self.start_us)
        k = loop.run(stop, self._tick, n_ticks) if not self.ended.all() else 0
        if not stop.is_set() and (self.ended.all() or (n_ticks is not None and k >= n_ticks)):
            self.finish()
            self.host.idle(stop, self.sync.poll if self.sync is not None else None)
        return loop.stats

    def _tick(self, k: int, now: float) -> bool:
        """One tick of the loop: False once every stream has ended."""
        self.step(k)
        if self.sync is not None:
            self.sync.poll()
        return not self.ended.all()
