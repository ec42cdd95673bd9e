"""The time exchanges of a process's devices with the time service (docs/protocol.md, "Time
exchange") and the stamps they give: each emulated device has its own clock; a gateway has one
clock for all its devices.

:class:`SyncClient`: two worker threads send the time queries and stamp the answers (the tick
loop never calls Zenoh and never waits); the tick loop takes the results between ticks, updates
each device's :class:`limbstream.timesync.SyncEstimator` and stamps samples on the common time
base with a bounded slew (in C: :class:`limbstream.kernel.Stamper`). The querier's matching
listener tells when a time service becomes reachable: every device then exchanges within
RESUME_SPREAD_S, whatever its poll interval had grown to.

Times are microseconds.
"""
from __future__ import annotations

import collections
import heapq
import logging
import random
import threading
import time
from typing import Any

import numpy as np
import zenoh

from limbstream import kernel, wire
from limbstream.timesync import SyncEstimator
from limbstream.device.clocks import ClockSettings, DeviceClocks

log = logging.getLogger("limbstream.device.clock")

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
SLEW = 500e-6
"""Largest rate at which a synced device's correction may change beyond its estimated drift
(500 ppm, 0.5 ms per second): a service clock jump is followed this slowly."""
STEP_US = 128_000.0
"""A device resyncing after its holdover expired steps (new stream) if its estimate moved more."""
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


class SyncClient:
    """The time exchanges of ``n`` devices of one process and their stamps.

    Per device the tick loop reads :meth:`stamp` (vectorised). The correction ``C`` a device
    stamps with follows the estimator's line: at each sample it advances by the estimated drift
    and moves towards the line by at most SLEW times the elapsed time (a first sync, or a resync
    after the holdover that moved more than STEP_US, sets it at once: a step, which the device
    host turns into a new stream).

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
        self.bad: list[collections.Counter[str]] = [collections.Counter() for _ in range(n)]
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
        self.querier: zenoh.Querier | None = None
        self.listener: Any = None

    # ------------------------------------------------------------------ threads

    def start(self) -> None:
        """Declare the querier, start the workers and schedule every device's first burst,
        spread over the first second."""
        # remote only: the time service is another process, and a session holding thousands of
        # publishers (each with its cache's queryable) would otherwise match every query against
        # them (~300 us of CPU per query and per matching check, instead of ~40 and ~1)
        self.querier = querier = self.session.declare_querier(
            wire.time_key(), target=zenoh.QueryTarget.BEST_MATCHING, consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self.settings.timeout_s, allowed_destination=zenoh.Locality.REMOTE)
        self.listener = querier.declare_matching_listener(self._on_matching)
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
        return self.querier is not None and bool(self.querier.matching_status.matching)  # type: ignore[attr-defined]  # (a MatchingStatus, not the stubs' bool)

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
        if seen is None:
            return
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
        querier = self.querier
        if querier is None or not querier.matching_status.matching:  # type: ignore[attr-defined]  # no time service: no query sent (a MatchingStatus, not the stubs' bool)
            self._results.append((slot, rid, 0, 0, None))
            return
        t1 = self.clocks.read(slot)
        self.sent_at[slot] = time.monotonic()
        replies = querier.get(zenoh.handlers.FifoChannel(4),
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
        bad: collections.Counter[str] = collections.Counter()
        for c in self.bad:
            bad.update(c)
        return (f"time sync: {self.exchanges} answers, {int(self.lost.sum())} lost, discarded "
                f"{dict(bad) or 0}, {int(np.sum(self.valid >= MIN_SYNC))}/{len(self.names)} devices synced; "
                f"CPU: workers {sum(self._worker_cpu):.2f} s, tick loop {self.busy_s:.2f} s")
