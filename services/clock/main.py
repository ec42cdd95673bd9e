"""Run the time service until stopped (what ``limbstream clock`` starts)."""
from __future__ import annotations

import threading

from limbstream import wire, zconfig
from limbstream.services.clock.service import ClockServiceSettings, TimeService


def run(settings: ClockServiceSettings, zenoh: zconfig.ZenohSettings, stop: threading.Event | None = None) -> int:
    """Open the session (waiting for the router), serve time until ``stop`` or a signal; exit code."""
    stop, session = zconfig.part_session(zenoh, stop)
    if session is None:  # stopped while waiting for the router
        return 0
    with session:
        service = TimeService(session, settings)
        extra = ""
        if settings.delay_ms or settings.jitter_ms:
            extra += f", exchange path delayed {settings.delay_ms:g} +- {settings.jitter_ms:g} ms each way"
        if settings.jump_ms:
            extra += f", clock jumps {settings.jump_ms:+g} ms after {settings.jump_after_s:g} s"
        print(f"serving time on {wire.time_key()} x{settings.speed:g}{extra}", flush=True)
        stats = service.run(stop)
    print(f"clock: {stats.answered} time requests answered, {stats.bad} refused", flush=True)
    return 0
