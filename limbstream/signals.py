"""Process lifecycle: the stop event every long-running command waits on."""
from __future__ import annotations

import signal
import threading


def stop_on_signals(stop: threading.Event | None = None) -> threading.Event:
    """The event a command's loop waits on, set by SIGINT and SIGTERM (a new one if None)."""
    stop = stop or threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop
