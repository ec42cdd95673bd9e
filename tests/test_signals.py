"""Signals set a command's stop event without deadlocking its main thread (limbstream.signals)."""
from __future__ import annotations

import selectors
import subprocess
import sys

CHILD = """
import sys, time
from limbstream.signals import stop_on_signals
stop = stop_on_signals()
print("ready", flush=True)
woken, end = 0, time.monotonic() + 2.0
while time.monotonic() < end:  # in and out of the event's lock, as a command's loop polls it
    if stop.wait(1e-6):
        woken += 1
        stop.clear()
print(woken, flush=True)
sys.stdin.read()  # until the test has stopped the signals
"""

SENDER = """
import os, signal, sys
pid = int(sys.argv[1])
while True:
    try:
        os.kill(pid, signal.SIGTERM if sys.argv[2] == "TERM" else signal.SIGINT)
    except ProcessLookupError:
        break
"""


def test_signals_arriving_while_the_main_thread_waits_on_the_event_all_set_it():
    """Signals rain on a process whose main thread waits on its stop event again and again: each
    sets the event (the process sees it set), and none deadlocks it. A handler that set the event
    itself failed within seconds: a signal came while the main thread held the event's lock, and
    the handler waited for it (and, as more signals came, ran again inside itself until Python's
    recursion limit ended the process)."""
    for sig in ("TERM", "INT"):
        child = subprocess.Popen([sys.executable, "-c", CHILD], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        sender = None
        try:
            assert child.stdout.readline().strip() == "ready"
            sender = subprocess.Popen([sys.executable, "-c", SENDER, str(child.pid), sig])
            with selectors.DefaultSelector() as sel:
                sel.register(child.stdout, selectors.EVENT_READ)
                assert sel.select(timeout=60), f"SIG{sig}: the process is stuck"
            line = child.stdout.readline()
            assert line.strip().isdigit(), f"SIG{sig}: the process ended early ({child.wait()})"
            woken = int(line)
            sender.kill()
            sender.wait(timeout=30)
            child.stdin.close()
            assert child.wait(timeout=30) == 0 and woken > 0, (sig, child.returncode, woken)
        finally:
            for proc in (sender, child):
                if proc is not None:
                    proc.kill()
                    proc.wait()


def test_the_last_calls_event_is_the_one_set():
    code = """
import os, signal, threading
from limbstream.signals import stop_on_signals
first = stop_on_signals()
second = stop_on_signals(threading.Event())
os.kill(os.getpid(), signal.SIGTERM)
assert second.wait(10) and not first.is_set()
print("ok")
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "ok", out.stderr
