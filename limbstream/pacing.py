"""The paced loop of every process that works in ticks: the emulator, the gateways and the
aggregator.

Tick k is due at ``start + k * period``. The loop waits for it (or does what its owner does
between ticks), runs it, and counts a tick that began more than one period after it was due as
late. A loop that fell behind runs its ticks back to back until it has caught up: it never skips
one. Times are seconds.

A tick is late for one of two reasons: the loop's own work (its ticks cost more than their
period) or its process waiting for a core (a machine with more runnable threads than cores).
``late`` counts both, as a deployment sees them; ``late_own`` counts the first alone: the ticks
that would have begun more than a period late had every tick taken only its CPU time (the loop
thread's) and the thread never waited for a core. Load on the machine leaves it unchanged, so it
is the figure that tells whether the loop's work fits its period. Time a tick spends blocked
(a lock, a congested publisher) is in ``late`` only.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass
class LoopStats:
    """Pacing figures of one loop (the aggregator publishes them in its stats: ``wire.AGGREGATOR_FIELDS``)."""

    ticks: int = 0
    late: int = 0                    # ticks that began more than one period late
    late_own: int = 0                # ticks late by the loop's own work (CPU time), not by waiting for a core
    busy_s: float = 0.0              # time spent working (not waiting for the next tick), s
    load: float = 0.0                # share of the last round spent working (0..1; >= 1: cannot keep up)
    max_tick_ms: float = 0.0         # longest tick's work, ms
    recent_max_tick_ms: float = 0.0  # longest tick's work since the last round, ms

    _round_start: float = field(default_factory=time.perf_counter, repr=False)
    _round_busy: float = field(default=0.0, repr=False)

    def record(self, work_s: float) -> None:
        """One tick done, after ``work_s`` seconds of work."""
        self.ticks += 1
        self.busy_s += work_s
        self._round_busy += work_s
        self.max_tick_ms = max(self.max_tick_ms, 1e3 * work_s)
        self.recent_max_tick_ms = max(self.recent_max_tick_ms, 1e3 * work_s)

    def end_round(self, now: float) -> None:
        """A reporting round ends at ``now`` (the loop's clock): ``load`` over it, and the
        ``recent_*`` figures start over."""
        self.load = round(self._round_busy / max(now - self._round_start, 1e-9), 4)
        self._round_start, self._round_busy = now, 0.0
        self.recent_max_tick_ms = 0.0

    def as_dict(self) -> dict:
        """The figures by name."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__ if not k.startswith("_")}


class PacedLoop:
    """Ticks every ``period_s``.

    Parameters
    ----------
    period_s : tick period, s.
    clock : the clock ticks are due on and ``now`` is read from (``time.perf_counter``).
    work_clock : the clock a tick's work is measured with (default ``clock``; ``time.thread_time``
        counts the loop thread's CPU only).
    cpu_clock : the loop thread's CPU time, the clock of ``late_own`` (``time.thread_time``).
    stats : where the ticks of every :meth:`run` are counted (default: a new :class:`LoopStats`).
    """

    def __init__(self, period_s: float, clock: Callable[[], float] = time.perf_counter,
                 work_clock: Callable[[], float] | None = None, cpu_clock: Callable[[], float] = time.thread_time,
                 stats: LoopStats | None = None):
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.period_s, self.clock = float(period_s), clock
        self.work_clock, self.cpu_clock = work_clock or clock, cpu_clock
        self.stats = LoopStats() if stats is None else stats

    def run(self, stop: threading.Event, tick: Callable[[int, float], bool | None], ticks: int | None = None,
            between: Callable[[float], None] | None = None, start: float | None = None) -> int:
        """Call ``tick(k, now)`` for k = 0, 1, ... as each comes due, until ``stop`` is set,
        ``ticks`` ticks ran (None: no limit) or a tick returns False; the ticks run.

        ``between(deadline)`` runs while the next tick is not due and returns at the latest at
        ``deadline`` (the loop's clock); by default the loop waits on ``stop``. Tick 0 is due at
        ``start`` (the loop's clock; default: now).
        """
        start = self.clock() if start is None else start
        k = 0
        own_free = start  # when the loop would be free had every tick taken only its CPU time
        while not stop.is_set() and (ticks is None or k < ticks):
            deadline = start + k * self.period_s
            now = self.clock()
            if now < deadline:
                if between is None:
                    stop.wait(deadline - now)
                else:
                    between(deadline)
                continue
            own_start = max(deadline, own_free)
            if now - deadline > self.period_s:
                self.stats.late += 1
                self.stats.late_own += int(own_start - deadline > self.period_s)
            began, cpu = self.work_clock(), self.cpu_clock()
            more = tick(k, now)
            self.stats.record(self.work_clock() - began)
            own_free = own_start + self.cpu_clock() - cpu
            k += 1
            if more is False:
                break
        return k


class Deadlines:
    """Deadlines every ``period_s`` from ``start`` (the loop's clock, s), each met at most once:
    by a tick within half a period after it, else missed (so the ticks that meet two deadlines in
    a row are at least half a period apart)."""

    def __init__(self, period_s: float, start: float):
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.period_s, self.start = float(period_s), start
        self.next = 0  # the first deadline not yet met or missed

    def due(self, now: float) -> tuple[bool, int]:
        """At ``now``: (whether the newest deadline passed is met now, deadlines missed since the
        last call)."""
        k = math.floor((now - self.start) / self.period_s + 1e-6)  # the newest deadline passed
        if k < self.next:
            return False, 0
        met = now - (self.start + k * self.period_s) <= self.period_s / 2
        missed = k - self.next + (0 if met else 1)
        self.next = k + 1
        return met, missed
