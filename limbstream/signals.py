"""Process lifecycle: the stop event every long-running command waits on.

SIGINT and SIGTERM set it, but not from their handler: a Python signal handler runs in the main
thread between two of its bytecodes, which may be inside that very event's ``wait()`` while it
holds the event's lock, and ``set()`` would then wait for the lock forever (``limbstream up`` hung
so on a Ctrl-C, once, in CI). The handler only writes a byte to a pipe; a thread reading the pipe
sets the event.
"""
from __future__ import annotations

import os
import signal
import threading

_wake_fd = -1                                # the pipe's write end (-1: no relay yet)
_relay_pid = -1                              # the process whose thread reads the pipe
_current: threading.Event | None = None      # the event the next signal sets
_relay_lock = threading.Lock()


def _relay(read_fd: int) -> None:
    """Set the current event for every byte a handler wrote (runs forever, a daemon thread)."""
    while True:
        if os.read(read_fd, 64) and _current is not None:
            _current.set()


def _on_signal(signum: int, frame) -> None:
    try:
        os.write(_wake_fd, b"\0")  # no lock taken
    except BlockingIOError:  # a full pipe already holds a wake for the relay
        pass


def stop_on_signals(stop: threading.Event | None = None) -> threading.Event:
    """The event a command's loop waits on, set by SIGINT and SIGTERM (a new one if None; the
    last call's event is the one set). Call from the main thread."""
    global _wake_fd, _relay_pid, _current
    stop = stop or threading.Event()
    with _relay_lock:
        if _relay_pid != os.getpid():  # (a forked child has the pipe but not the thread)
            read_fd, _wake_fd = os.pipe()
            os.set_blocking(_wake_fd, False)
            threading.Thread(target=_relay, args=(read_fd,), name="signal-relay", daemon=True).start()
            _relay_pid = os.getpid()
        _current = stop
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_signal)
    return stop
