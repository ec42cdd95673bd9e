"""The one paced loop (limbstream.pacing): ticks come due on their grid, a late one is counted and
the loop catches up without skipping any, the work is measured, a tick late by the loop's own
work is told from one late by waiting for a core, and the loop ends on its stop, its tick count or
a tick that says so. Clocks of the test's own: no waiting on wall time."""
from __future__ import annotations

import threading

import pytest

from limbstream.pacing import LoopStats, PacedLoop


class Clock:
    """Time that passes only when the test says so (the loop's ``between`` moves it to the deadline)."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def until(self, deadline: float) -> None:
        self.now = max(self.now, deadline)


def test_ticks_on_their_grid_late_ones_counted_none_skipped():
    clock, seen = Clock(), []

    def tick(k: int, now: float) -> None:
        seen.append((k, round(now, 6)))
        if k == 2:
            clock.now += 0.35  # tick 2 works 350 ms: ticks 3 and 4 begin more than a period late

    loop = PacedLoop(0.1, clock=clock, cpu_clock=clock)  # the 350 ms are CPU time: the loop's own work
    assert loop.run(threading.Event(), tick, ticks=6, between=clock.until) == 6
    assert seen == [(0, 0.0), (1, 0.1), (2, 0.2), (3, 0.55), (4, 0.55), (5, 0.55)]
    s = loop.stats
    assert (s.ticks, s.late, s.late_own) == (6, 2, 2) and s.max_tick_ms == pytest.approx(350.0)
    assert s.busy_s == pytest.approx(0.35)


def test_ticks_late_by_waiting_for_a_core_are_not_late_by_the_loops_own_work():
    """The same loop kept off the CPU instead: tick 2 takes 350 ms of wall time but 5 ms of CPU
    (its process waited for a core), so ticks 3 and 4 are late on the wall clock and not by the
    loop's work. A loop whose every tick costs 1.5 periods of CPU falls behind by its own work:
    each tick after the first three is late both ways."""
    clock, cpu = Clock(), Clock()

    def preempted(k: int, now: float) -> None:
        cpu.now += 0.005
        clock.now += 0.35 if k == 2 else 0.005

    loop = PacedLoop(0.1, clock=clock, cpu_clock=cpu)
    assert loop.run(threading.Event(), preempted, ticks=6, between=clock.until) == 6
    assert (loop.stats.late, loop.stats.late_own) == (2, 0)

    clock, cpu = Clock(), Clock()

    def heavy(k: int, now: float) -> None:
        cpu.now += 0.15
        clock.now += 0.15

    loop = PacedLoop(0.1, clock=clock, cpu_clock=cpu)
    loop.run(threading.Event(), heavy, ticks=10, between=clock.until)
    assert (loop.stats.late, loop.stats.late_own) == (7, 7)  # tick k begins at 0.15 k: 0.05 k late


def test_the_loop_ends_on_stop_or_when_a_tick_says_so():
    clock, stop = Clock(), threading.Event()

    def tick(k: int, now: float) -> bool:
        if k == 3:
            stop.set()
        return True

    assert PacedLoop(0.02, clock=clock).run(stop, tick, between=clock.until) == 4
    assert PacedLoop(0.02, clock=clock).run(threading.Event(), lambda k, now: k < 2, between=clock.until) == 3
    assert PacedLoop(0.02).run(stop, tick) == 0  # stopped before the first tick
    with pytest.raises(ValueError, match="period_s"):
        PacedLoop(0.0)


def test_rounds_give_the_load_and_start_the_recent_figures_over():
    stats = LoopStats(_round_start=10.0)
    stats.record(0.25)
    stats.record(0.05)
    stats.end_round(11.0)
    assert stats.load == pytest.approx(0.3) and stats.recent_max_tick_ms == 0.0 and stats.max_tick_ms == 250.0
    assert set(stats.as_dict()) == {"ticks", "late", "late_own", "busy_s", "load", "max_tick_ms",
                                     "recent_max_tick_ms"}
