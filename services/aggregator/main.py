"""Run one aggregator until stopped (what ``limbstream aggregate`` starts)."""
from __future__ import annotations

import threading

from limbstream import zconfig
from limbstream.signals import stop_on_signals
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings


def run(settings: AggregatorSettings, zenoh: zconfig.ZenohSettings, stop: threading.Event | None = None) -> int:
    """Open the session (waiting for the router), aggregate until ``stop`` or a signal; exit code."""
    stop = stop_on_signals(stop)
    session = zconfig.open_session(zenoh, stop)
    if session is None:  # stopped while waiting for the router
        return 0
    with session:
        aggregator = Aggregator(session, settings)
        aggregator.open()
        print(f"aggregating subjects {','.join(settings.subjects)} at {settings.rate:g} Hz", flush=True)
        loop = aggregator.run(stop)
        aggregator.close()
    print(f"aggregator: {loop.pacing.ticks} ticks ({loop.pacing.late} late), {loop.points} points, {loop.frames} frames, "
          f"{loop.missed} missed, max backlog {loop.max_backlog}", flush=True)
    return 0
