"""Device clocks and their synchronisation to the time service (docs/protocol.md, "Time
exchange"; docs/reliability.md, "Device clocks").

- :class:`DeviceClocks`: every emulated device's own clock, vectorised: a fixed offset drawn
  uniform in +-MAX, a drift drawn uniform in +-MAX ppm (seeded), optional read jitter uniform
  in +-J. A device samples on its own clock's grid (a random phase after boot), so a fast clock
  takes more samples than a slow one.
- :class:`SyncEstimator`: one device's SNTP-style estimator: a sliding window of four-timestamp
  exchanges, weighted by their round trip (the shortest round trips carry the smallest
  asymmetry), fitted with a line (offset and drift); answers inconsistent with that line are
  held back until three agree (a service clock jump), then followed.
- :class:`SyncClient`: the exchanges of all devices of one emulator: two worker threads send the
  time queries and stamp the answers (the tick loop never calls Zenoh and never waits); the tick
  loop takes the results between ticks, updates the estimators and stamps samples on the
  common time base with a bounded slew (in C: :class:`limbstream.kernel.Stamper`). The
  querier's matching listener tells when a time service becomes reachable: every device then
  exchanges within RESUME_SPREAD_S, whatever its poll interval had grown to.

Times are microseconds. "True" time is the emulation's time base (host clock, scaled by
``--speed`` around ``anchor``); it is what the time service serves and what the truth tap's
reference times carry.
"""
from __future__ import annotations

import collections
import heapq
import logging
import math
import random
import threading
import time
from dataclasses import dataclass

import numpy as np
import zenoh

from limbstream import kernel, wire

log = logging.getLogger("limbstream.emulator.clock")

WINDOW = 96
"""Exchanges kept per device (the newest)."""
BURST = 4
"""Exchanges 0.25 s apart when a device starts; it streams once they are in (or after the wait)."""
FILL = 8
"""Exchanges 1 s apart until the window holds this many (then the interval doubles)."""
MIN_POLL_S = 1.0
"""Poll interval while the measured jitter is high (or after a failure or a held-back answer), s."""
OFFSET_SE_US = 250.0
"""While the offset's standard error (jitter over the square root of the exchanges' effective
number) exceeds this, a device polls every MIN_POLL_S (a jittery path needs many exchanges)."""
DRIFT_BUDGET_US = 150.0
"""The interval to the next exchange is at most this over the drift's standard error: what the
drift estimate's uncertainty may add to the offset before the next answer."""
MIN_SPREAD_US = 2e6
"""The drift is fitted only once the weighted exchanges span at least this much (std of their
times), else the previous drift stands."""
MAX_DRIFT = 2e-3
"""Largest drift a fit may report (2000 ppm); beyond it is treated as noise (clipped)."""
SLEW = 500e-6
"""Largest rate at which a synced device's correction may change beyond its estimated drift
(500 ppm, 0.5 ms per second): a service clock jump is followed this slowly."""
STEP_US = 128_000.0
"""A device resyncing after its holdover expired steps (new stream) if its estimate moved more."""
JUMP_FLOOR_US = 1000.0
"""An answer is held back as a possible service jump when its offset is further from the fit
than half its round-trip excess plus max(4 x jitter, this)."""
JUMP_CONFIRM = 3
"""Held-back answers that must agree before the device follows a service jump."""
SANE_US = 10e6
"""A synced device discards answers more than 10 s from its estimate (``future`` / ``past``)."""
MIN_SYNC = 3
"""Valid answers before a device counts as synced."""
RETRY_S = 8.0
"""Longest wait before asking again after a query without an answer, device seconds."""
RESUME_SPREAD_S = 0.5
"""When the time service becomes reachable (its queryable matches), every device exchanges
within this, each at its own fixed offset in [0, this), so that thousands of devices do not
storm the service at once, wall seconds."""
WORKERS = 2
"""Threads sending time queries (each waits for one answer at a time)."""
LOG_EVERY_S = 30.0
"""Interval of the INFO line with the sync's counters and CPU so far (emulate -v), wall seconds."""


@dataclass(frozen=True)
class ClockSettings:
    """Clocks and sync of one emulator.

    Attributes
    ----------
    offset_ms, drift_ppm : each device's offset and drift are drawn uniform in +- these.
    jitter_us : every clock read is off by uniform +- this (stamps and exchange times).
    seed : seed of the draws (with the first subject number: distinct per emulator process).
    sync : run the time exchange (else devices stamp with their own clock).
    poll_s : longest interval between exchanges, device seconds.
    holdover_s : a device without a valid answer for this long reports itself unsynced.
    wait_s : at start, wait this long (wall seconds) at most for the first exchanges.
    timeout_s : a time query without an answer for this long counts as lost (wall seconds).
    """

    offset_ms: float = 0.0
    drift_ppm: float = 0.0
    jitter_us: float = 0.0
    seed: int = 0
    sync: bool = True
    poll_s: float = 512.0
    holdover_s: float = 600.0
    wait_s: float = 10.0
    timeout_s: float = 1.0

    @property
    def modelled(self) -> bool:
        """Devices have clocks of their own (not the emulation's true clock)."""
        return self.offset_ms > 0 or self.drift_ppm > 0 or self.jitter_us > 0


class TimeBase:
    """The emulation's true time: ``anchor + speed * (host clock - anchor)``, us.

    Parameters
    ----------
    speed : time scale (1: the host clock).
    anchor_us : the instant the scaled time agrees with the host clock (processes that share a
        time base at speed != 1 must share it), us since the epoch; None: now.
    """

    def __init__(self, speed: float = 1.0, anchor_us: float | None = None):
        self.speed = float(speed)
        self.anchor_us = float(time.time_ns() / 1e3 if anchor_us is None else anchor_us)

    def now_us(self) -> float:
        return self.anchor_us + self.speed * (time.time_ns() / 1e3 - self.anchor_us)


class DeviceClocks:
    """The local clocks of ``n`` devices: ``local(T) = T + offset + drift * (T - boot)``.

    Attributes
    ----------
    offset_us, drift, phase_us : (n,) float64: offset at boot (us), drift (fraction), phase of
        the sampling grid after boot (us, in [0, period)).
    boot_us : true time of boot (set by :meth:`boot`).
    """

    def __init__(self, n: int, settings: ClockSettings, period_us: float, base: TimeBase, seed: int = 0):
        rng = np.random.default_rng([settings.seed, seed])
        self.settings, self.period_us, self.base = settings, float(period_us), base
        self.offset_us = rng.uniform(-1, 1, n) * settings.offset_ms * 1e3
        self.drift = rng.uniform(-1, 1, n) * settings.drift_ppm * 1e-6
        self.phase_us = rng.uniform(0, period_us, n) if settings.modelled else np.zeros(n)
        self.max_drift = settings.drift_ppm * 1e-6
        self.boot_us = self.grid_us = 0.0
        self.grid_local = np.zeros(n)
        self._jitter = random.Random(settings.seed)

    def boot(self, true_us: float) -> None:
        """The devices power up at true time ``true_us`` (their drift counts from then)."""
        self.boot_us = float(true_us)

    def start_grid(self, true_us: float) -> None:
        """The devices start sampling at true time ``true_us``: sample 0 of each is taken at its
        first grid point after it (its phase)."""
        self.grid_us = float(true_us)
        self.grid_local = self.local(self.grid_us)

    def local(self, true_us, slots=slice(None)) -> np.ndarray:
        """Local clocks of ``slots`` at true time(s) ``true_us`` (no jitter), us."""
        return true_us + self.offset_us[slots] + self.drift[slots] * (true_us - self.boot_us)

    def jitter(self, n: int) -> np.ndarray:
        j = self.settings.jitter_us
        return np.zeros(n) if j <= 0 else np.random.default_rng(self._jitter.getrandbits(64)).uniform(-j, j, n)

    def read(self, slot: int) -> int:
        """Device ``slot`` reads its clock now (with jitter), us (any thread)."""
        t = self.base.now_us()
        j = self.settings.jitter_us
        noise = self._jitter.uniform(-j, j) if j > 0 else 0.0
        return int(round(t + self.offset_us[slot] + self.drift[slot] * (t - self.boot_us) + noise))

    def sample_time(self, n: np.ndarray, slots) -> np.ndarray:
        """True time at which sample ``n`` of each device is taken: its local grid point
        (:meth:`sample_local`) mapped back to true time, us."""
        return self.grid_us + (self.phase_us[slots] + n * self.period_us) / (1.0 + self.drift[slots])

    def sample_local(self, n: np.ndarray, slots) -> np.ndarray:
        """Local time of sample ``n``: ``local(grid start) + phase + n * period``, us."""
        return self.grid_local[slots] + self.phase_us[slots] + n * self.period_us

    def describe(self, names: list[str]) -> list[str]:
        return [f"clock {name}: offset {o / 1e3:+.3f} ms, drift {d * 1e6:+.2f} ppm"
                for name, o, d in zip(names, self.offset_us, self.drift)]


class SyncEstimator:
    """One device's estimate of the common time base from its exchanges.

    The correction ``service - local`` at local time ``L`` is ``a + b * (L - ref)``. Each
    exchange gives the offset at its midpoint, off by at most half its round-trip excess
    over the shortest one seen; a weighted least-squares line through the window
    (weights 1 / (eps^2 + (excess / 2)^2), eps the floor of that bound) gives ``a`` and the
    drift ``b``.
    """

    def __init__(self, window: int = WINDOW):
        self.x = collections.deque(maxlen=window)      # midpoint, local us
        self.theta = collections.deque(maxlen=window)  # offset, us
        self.delay = collections.deque(maxlen=window)  # round trip, us
        self.a = self.b = self.ref = 0.0
        self.fitted = False
        self.jitter = math.inf
        self.drift_se = math.inf   # standard error of b
        self.offset_se = math.inf  # standard error of the line at the newest exchange, us
        self.held: list[tuple[float, float, float]] = []

    def __len__(self) -> int:
        return len(self.x)

    def predict(self, local_us: float) -> float:
        return self.a + self.b * (local_us - self.ref)

    def add(self, t1: float, t2: float, t3: float, t4: float) -> str:
        """Take one exchange. Returns ``ok``, ``held`` (inconsistent with the fit: a possible
        service jump, not used yet), ``jump`` (JUMP_CONFIRM such answers agree: the window starts
        over from them), or a discard reason: ``negative_rtt``, ``future``, ``past``."""
        theta, delay = wire.offset_delay(t1, t2, t3, t4)
        if delay < 0:
            return "negative_rtt"
        x = (t1 + t4) / 2.0
        if self.fitted:
            residual = theta - self.predict(x)
            if abs(residual) > SANE_US:
                return "future" if residual > 0 else "past"
            allowed = (delay - min(self.delay)) / 2.0 + max(4.0 * self.jitter, JUMP_FLOOR_US)
            if abs(residual) > allowed:
                self.held.append((x, theta, delay))
                if len(self.held) < JUMP_CONFIRM:
                    return "held"
                shifted = [th - self.b * (hx - x) for hx, th, _ in self.held]
                if max(shifted) - min(shifted) > max(4.0 * self.jitter, JUMP_FLOOR_US):
                    self.held = self.held[1:]
                    return "held"
                self.x.clear(), self.theta.clear(), self.delay.clear()
                for hx, th, d in self.held:
                    self._append(hx, th, d)
                self.held = []
                self._fit()
                return "jump"
        self.held = []
        self._append(x, theta, delay)
        self._fit()
        return "ok"

    def _append(self, x: float, theta: float, delay: float) -> None:
        self.x.append(x)
        self.theta.append(theta)
        self.delay.append(delay)

    def _fit(self) -> None:
        ref = self.x[-1]
        x = np.fromiter(self.x, float, len(self.x)) - ref
        y = np.fromiter(self.theta, float, len(self.x))
        excess = np.fromiter(self.delay, float, len(self.x))
        excess -= excess.min()
        eps = max(25.0, float(np.partition(excess, len(excess) // 4)[len(excess) // 4]) / 2.0)
        w = 1.0 / (eps * eps + (excess / 2.0) ** 2)
        sw = w.sum()
        mx, my = float(w @ x) / sw, float(w @ y) / sw
        sxx = float(w @ (x - mx) ** 2) / sw
        neff = sw * sw / float(w @ w)
        fitted_b = len(x) >= 3 and neff >= 3.0 and sxx >= MIN_SPREAD_US ** 2
        if fitted_b:
            self.b = min(MAX_DRIFT, max(-MAX_DRIFT, float(w @ ((x - mx) * (y - my))) / sw / sxx))
        self.a, self.ref = my - self.b * mx, ref
        if len(x) >= 3:
            self.jitter = math.sqrt(float(w @ (y - self.a - self.b * x) ** 2) / sw)
            self.offset_se = max(self.jitter, 1.0) / math.sqrt(max(neff - 2.0, 1.0))
            if fitted_b:
                self.drift_se = max(self.jitter, 1.0) / math.sqrt(max(neff - 2.0, 1.0) * sxx)
        self.fitted = True


class SyncClient:
    """The time exchanges of ``n`` devices of one process and their stamps.

    Per device the tick loop reads :meth:`stamp` (vectorised). The correction ``C`` a device
    stamps with follows the estimator's line: at each sample it advances by the estimated drift
    and moves towards the line by at most SLEW times the elapsed time (a first sync, or a resync
    after the holdover that moved more than STEP_US, sets it at once: a step, which the emulator
    turns into a new stream).

    Parameters
    ----------
    session : open Zenoh session.
    clocks : the devices' clocks.
    settings : ClockSettings.
    names : device ids, for logs.
    """

    def __init__(self, session: zenoh.Session, clocks: DeviceClocks, settings: ClockSettings, names: list[str]):
        n = len(names)
        self.session, self.clocks, self.settings, self.names = session, clocks, settings, names
        self.est = [SyncEstimator() for _ in range(n)]
        # the estimators' lines (a, b, ref), the stamping correction c at device time c_local, and
        # per device: ever (synced once: stamps follow the line from then on), step (the next
        # stamp sets c to the line, no slew), stepped (its last stamp was a step)
        self.stamper = kernel.Stamper(n, SLEW)
        st = self.stamper
        self.a, self.b, self.ref, self.c, self.c_local = st.a, st.b, st.ref, st.c, st.c_local
        self.ever, self.step, self.stepped = st.ever, st.step, st.stepped
        self.steps = 0                         # stamps of the last stamp() call that were steps
        self.have = np.zeros(n, bool)          # the line exists (one valid answer)
        self.valid = np.zeros(n, np.int64)     # valid answers
        self.last_valid = np.full(n, -np.inf)  # local time of the last valid answer
        self.rtt_us = np.full(n, np.nan)
        self.bad = [collections.Counter() for _ in range(n)]
        self.lost = np.zeros(n, np.int64)      # queries without an answer
        self.backoff = np.full(n, MIN_POLL_S)
        self.interval = np.full(n, MIN_POLL_S)
        self.exchanges = 0
        self.busy_s = 0.0                      # CPU time the tick loop spent on sync (results, stamps), s
        self._log_at = time.monotonic() + LOG_EVERY_S
        self._worker_cpu = [0.0] * WORKERS     # CPU time of each worker thread, s
        self._ids = np.zeros(n, np.int64)      # id of each device's request in flight
        self.sent_at = np.full(n, -np.inf)     # monotonic time each device last sent a query, s
        self.resumes: list[float] = []         # monotonic times a time service became reachable, s
        self._resume_at: float | None = None   # set by the matching listener (Zenoh thread)
        self._offset_s = np.random.default_rng(settings.seed).uniform(0.0, RESUME_SPREAD_S, n)
        self._heap: list[tuple[float, int]] = []
        self._cond = threading.Condition()
        self._results: collections.deque = collections.deque()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.querier = None
        self.listener = None

    # ------------------------------------------------------------------ threads

    def start(self) -> None:
        """Declare the querier, start the workers and schedule every device's first burst,
        spread over the first second."""
        # remote only: the time service is another process, and a session holding thousands of
        # publishers (each with its cache's queryable) would otherwise match every query against
        # them (~300 us of CPU per query and per matching check, instead of ~40 and ~1)
        self.querier = self.session.declare_querier(
            wire.time_key(), target=zenoh.QueryTarget.BEST_MATCHING, consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self.settings.timeout_s, allowed_destination=zenoh.Locality.REMOTE)
        self.listener = self.querier.declare_matching_listener(self._on_matching)
        now = time.monotonic()
        rng = random.Random(self.settings.seed)
        for slot in range(len(self.names)):
            self._schedule(slot, now + rng.uniform(0.0, 1.0))
        for i in range(WORKERS):
            t = threading.Thread(target=self._work, args=(i,), name=f"time-sync-{i}", daemon=True)
            t.start()
            self._threads.append(t)

    def close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for t in self._threads:
            t.join(timeout=2.0)
        if self.listener is not None:
            self.listener.undeclare()
            self.listener = None
        if self.querier is not None:
            self.querier.undeclare()
            self.querier = None

    def service_present(self) -> bool:
        """A time service's queryable is reachable now."""
        return self.querier is not None and bool(self.querier.matching_status.matching)

    def _on_matching(self, status: zenoh.MatchingStatus) -> None:
        """Matching listener (Zenoh thread): hand the event to the workers, nothing more."""
        if status.matching:
            with self._cond:
                self._resume_at = time.monotonic()
                self._cond.notify()

    def _resume(self) -> None:
        """A time service became reachable: every device waiting for its next exchange has it
        within RESUME_SPREAD_S of that instant (worker thread, lock held). Devices whose exchange
        is under way are rescheduled the same way when its result comes (:meth:`poll`)."""
        seen, self._resume_at = self._resume_at, None
        self.resumes.append(seen)
        self._heap = [(min(due, seen + self._offset_s[slot]), slot) for due, slot in self._heap]
        heapq.heapify(self._heap)

    def _schedule(self, slot: int, wall: float) -> None:
        with self._cond:
            heapq.heappush(self._heap, (wall, slot))
            if self._heap[0] == (wall, slot):
                self._cond.notify()

    def _next(self) -> int | None:
        """The next device due (waits), or None when stopping."""
        with self._cond:
            while not self._stop.is_set():
                if self._resume_at is not None:
                    self._resume()
                now = time.monotonic()
                if self._heap and self._heap[0][0] <= now:
                    return heapq.heappop(self._heap)[1]
                self._cond.wait(self._heap[0][0] - now if self._heap else 0.5)
        return None

    def _work(self, worker: int) -> None:
        """Worker: one exchange at a time; the answer's arrival is stamped as soon as recv
        returns. Results go to a deque the tick loop reads."""
        while (slot := self._next()) is not None:
            began = time.thread_time()
            self._exchange(slot)
            self._worker_cpu[worker] += time.thread_time() - began

    def _exchange(self, slot: int) -> None:
        """One exchange of device ``slot`` (worker thread)."""
        rid = int(self._ids[slot] + 1) & 0xFFFFFFFF
        self._ids[slot] = rid
        if not self.querier.matching_status.matching:  # no time service: no query sent
            self._results.append((slot, rid, 0, 0, None))
            return
        t1 = self.clocks.read(slot)
        self.sent_at[slot] = time.monotonic()
        replies = self.querier.get(zenoh.handlers.FifoChannel(4),
                                   payload=wire.encode_time_request(wire.TimeRequest(rid, t1)))
        answer, t4 = None, 0
        try:
            reply = replies.recv()
            t4 = self.clocks.read(slot)
            if reply.ok is not None:  # (an error reply: timeout, refused)
                answer = reply.ok.payload.to_bytes()
        except zenoh.ZError:  # the query ended without an answer
            pass
        del replies  # later replies (another service) are dropped with the channel
        self._results.append((slot, rid, t1, t4, answer))

    # ------------------------------------------------------------------ tick loop

    def poll(self) -> int:
        """Apply the exchanges finished since the last call (tick loop, between ticks).
        Returns how many."""
        done = 0
        if self._results:
            began = time.thread_time()
            speed = self.clocks.base.speed
            while self._results:
                slot, rid, t1, t4, answer = self._results.popleft()
                done += 1
                due = time.monotonic() + self._apply(slot, rid, t1, t4, answer) / speed
                if self.resumes and self.resumes[-1] > self.sent_at[slot]:  # the service came back meanwhile
                    due = min(due, self.resumes[-1] + self._offset_s[slot])
                self._schedule(slot, due)
            self.busy_s += time.thread_time() - began
        if time.monotonic() >= self._log_at:
            self._log_at += LOG_EVERY_S
            log.info("%s", self.summary())
        return done

    def _apply(self, slot: int, rid: int, t1: int, t4: int, payload: bytes | None) -> float:
        """One finished exchange of device ``slot``; returns the device seconds until its next."""
        if payload is None:  # no answer (or no time service): retry after 1, 2, 4, 8, 8 ... s
            self.lost[slot] += 1
            self.backoff[slot] = min(2.0 * self.backoff[slot], self.settings.poll_s, 2 * RETRY_S)
            return self.backoff[slot] / 2.0
        self.exchanges += 1
        try:
            answer = wire.decode_time_answer(payload)
            if answer.id != rid or answer.t1_us != t1:
                raise wire.WireError("mismatch", "answer to another request")
        except wire.WireError:
            return self._reject(slot, "malformed")
        est = self.est[slot]
        was_synced = self.synced(slot, t4)
        outcome = est.add(t1, answer.t2_us, answer.t3_us, t4)
        if outcome in ("future", "past") and not was_synced:  # holdover over: acquire afresh
            est = self.est[slot] = SyncEstimator()
            self.valid[slot] = 0
            outcome = est.add(t1, answer.t2_us, answer.t3_us, t4)
        if outcome in ("negative_rtt", "future", "past"):
            return self._reject(slot, outcome)
        if outcome == "held":
            return MIN_POLL_S
        self.backoff[slot] = MIN_POLL_S
        self.valid[slot] += 1
        self.rtt_us[slot] = (t4 - t1) - (answer.t3_us - answer.t2_us)
        self.last_valid[slot] = t4
        self.a[slot], self.b[slot], self.ref[slot] = est.a, est.b, est.ref
        self.have[slot] = True
        if not was_synced and self.synced(slot, t4):  # acquired, or reacquired after the holdover
            if not self.ever[slot]:
                self.step[slot] = True
            elif abs(est.predict(t4) - (self.c[slot] + self.b[slot] * (t4 - self.c_local[slot]))) > STEP_US:
                self.step[slot] = True
            self.ever[slot] = True
        n = len(est)
        if n < BURST:
            return 0.25
        if n < FILL:
            return 1.0
        if est.offset_se > OFFSET_SE_US:
            self.interval[slot] = MIN_POLL_S
        else:  # doubling, as long as the drift's uncertainty allows
            self.interval[slot] = max(MIN_POLL_S, min(2.0 * self.interval[slot], self.settings.poll_s,
                                                      DRIFT_BUDGET_US / 1e6 / max(est.drift_se, 1e-12)))
        # at the latest when the holdover ends: past it, a device polls at the short back-off
        # (1, 2, 4, 8 s) whatever its interval had grown to
        return float(min(self.interval[slot], self.settings.holdover_s))

    def _reject(self, slot: int, reason: str) -> float:
        self.bad[slot][reason] += 1
        self.backoff[slot] = min(2.0 * self.backoff[slot], self.settings.poll_s)
        return self.backoff[slot] / 2.0

    def synced(self, slot: int, local_us: float) -> bool:
        """Device ``slot`` counts as synced at its local time ``local_us``."""
        return bool(self.valid[slot] >= MIN_SYNC
                    and local_us - self.last_valid[slot] <= self.settings.holdover_s * 1e6)

    def ready(self) -> bool:
        """Every device has its first burst of answers."""
        return bool(np.all(self.valid >= BURST))

    def wait_first(self, stop: threading.Event) -> None:
        """At start: return once every device has its burst, when no time service is reachable
        (0.3 s to find one), or after ``wait_s``."""
        deadline = time.monotonic() + self.settings.wait_s
        seen = time.monotonic() + 0.3
        while not stop.is_set() and time.monotonic() < deadline:
            self.poll()
            if self.ready():
                return
            if time.monotonic() > seen and not self.service_present():
                return
            stop.wait(0.01)

    def stamp(self, slots: np.ndarray, local_us: np.ndarray) -> np.ndarray:
        """Common-time stamps of samples taken at local times ``local_us`` by devices ``slots``
        (each once, times increasing per device), us float64; sets :attr:`stepped` and
        :attr:`steps` (how many stepped; :class:`limbstream.kernel.Stamper`, one C call)."""
        began = time.thread_time()
        stamps, self.steps = self.stamper.stamp(slots, local_us)
        self.busy_s += time.thread_time() - began
        return stamps

    def status(self, slot: int) -> wire.ClockStatus:
        """Device ``slot``'s own report of its sync (its status)."""
        now = self.clocks.read(slot)
        offset = None
        if self.ever[slot] and not np.isnan(self.c_local[slot]):  # what it stamps with
            offset = round(-(self.c[slot] + self.b[slot] * (now - self.c_local[slot])) / 1e3, 4)
        elif self.have[slot]:  # not stamping with it yet
            offset = round(-self.est[slot].predict(now) / 1e3, 4)
        rtt = None if np.isnan(self.rtt_us[slot]) else round(float(self.rtt_us[slot]) / 1e3, 4)
        return wire.ClockStatus(offset, rtt, self.synced(slot, now), dict(self.bad[slot]))

    def summary(self) -> str:
        bad = collections.Counter()
        for c in self.bad:
            bad.update(c)
        return (f"time sync: {self.exchanges} answers, {int(self.lost.sum())} lost, discarded "
                f"{dict(bad) or 0}, {int(np.sum(self.valid >= MIN_SYNC))}/{len(self.names)} devices synced; "
                f"CPU: workers {sum(self._worker_cpu):.2f} s, tick loop {self.busy_s:.2f} s")
