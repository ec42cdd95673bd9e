"""No command waits silently for a router that is not there: each says where it connects, gives
up with an error naming the endpoint and how to set it within its timeout (+ 2 s), and Ctrl-C
(SIGINT) stops it within 2 s while it connects. Real processes; the endpoint is a port nothing
listens on."""
from __future__ import annotations

import queue
import signal
import subprocess
import threading
import time

import pytest
from stack import ROOT, free_port

from limbstream.launch import LIMBSTREAM

pytestmark = pytest.mark.e2e

TIMEOUT_S = 1.0
COMMANDS = {
    "watch": ["watch", "s01", "--timeout", f"{TIMEOUT_S:g}"],
    "calibrate": ["calibrate", "s01", "--pose", "rest", "--connect-timeout", f"{TIMEOUT_S:g}"],
    "record": ["record", "{tmp}/session.mcap", "--duration", "5", "--connect-timeout", f"{TIMEOUT_S:g}"],
    "emulate": ["emulate", "--subjects", "1", "--connect-timeout", f"{TIMEOUT_S:g}"],
    "aggregate": ["aggregate", "--connect-timeout", f"{TIMEOUT_S:g}"],
}
"""Commands of each kind: a viewer with its own --timeout, a one-shot query, an output that writes a
file, a part that `limbstream up` supervises (which waits: --connect-timeout 0), a service."""


class Command:
    """A ``limbstream`` command whose output (stdout and stderr) is read line by line as it comes."""

    def __init__(self, argv: list[str]):
        self.proc = subprocess.Popen([*LIMBSTREAM, *argv], cwd=ROOT, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def wait_line(self, text: str, timeout: float = 60.0) -> float:
        """The time the first line containing ``text`` arrived (AssertionError if none came)."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"no line with {text!r} within {timeout:g} s: {self.seen}") from None
            self.seen.append(line)
            if text in line:
                return time.monotonic()

    def exit_code(self, within: float) -> tuple[int, float]:
        """(exit code, time of the exit), waiting at most ``within`` seconds."""
        try:
            code = self.proc.wait(within)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise AssertionError(f"still running {within:g} s later: {self.seen}") from None
        return code, time.monotonic()

    def rest(self) -> list[str]:
        while not self.lines.empty():
            self.seen.append(self.lines.get())
        return self.seen


@pytest.mark.parametrize("name", list(COMMANDS))
def test_without_a_router_a_command_says_where_and_gives_up_in_time(name, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cmd = Command([a.format(tmp=tmp_path) for a in COMMANDS[name]] + ["--connect", endpoint])
    said = cmd.wait_line(f"connecting to {endpoint} (--connect, env LIMBSTREAM_ROUTER; up to {TIMEOUT_S:g} s)")
    code, ended = cmd.exit_code(TIMEOUT_S + 2.0)
    lines = cmd.rest()
    print(f"\nCONNECT | {name} | gave up {ended - said:.2f} s after saying where (timeout {TIMEOUT_S:g} s) |")
    assert code == 1 and ended - said <= TIMEOUT_S + 2.0, (code, ended - said, lines)
    assert lines[-1] == (f"limbstream {name}: error: no Zenoh router answered at {endpoint} within {TIMEOUT_S:g} s "
                         "(set the router's endpoint with --connect or LIMBSTREAM_ROUTER; `limbstream up` or "
                         "`limbstream router` starts one)"), lines
    assert not list(tmp_path.iterdir()), "no file is left behind"


@pytest.mark.parametrize("name", list(COMMANDS))
def test_ctrl_c_stops_a_command_while_it_connects(name, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    argv = [a.format(tmp=tmp_path) for a in COMMANDS[name]] + ["--connect", endpoint, "--connect-timeout", "0"]
    if name == "watch":  # its --timeout bounds the wait: 0 waits for frames, the router the default 10 s
        argv = ["watch", "s01", "--connect", endpoint]
    cmd = Command(argv)
    cmd.wait_line(f"connecting to {endpoint}")
    cmd.proc.send_signal(signal.SIGINT)
    sent = time.monotonic()
    code, ended = cmd.exit_code(2.0)
    print(f"\nCONNECT | {name} | stopped {ended - sent:.2f} s after SIGINT |")
    assert ended - sent <= 2.0 and code in (0, 130), (code, cmd.rest())
    assert "Traceback" not in "\n".join(cmd.rest()), cmd.rest()
    assert not list(tmp_path.iterdir()), "no file is left behind"


def test_the_dashboard_says_it_still_waits_for_its_router_and_stops_on_ctrl_c():
    """The dashboard, a server, keeps waiting for its router (/health 503 meanwhile), but says so
    once the default connect timeout has passed; Ctrl-C stops it within 2 s."""
    from limbstream import zconfig
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cmd = Command(["dashboard", "--http", f"127.0.0.1:{free_port()}", "--connect", endpoint])
    cmd.wait_line(f"(zenoh client -> {endpoint})")
    cmd.wait_line(f"dashboard: no Zenoh router answered at {endpoint} within {zconfig.CONNECT_TIMEOUT_S:g} s; "
                  "still waiting", timeout=zconfig.CONNECT_TIMEOUT_S + 10)
    cmd.proc.send_signal(signal.SIGINT)
    sent = time.monotonic()
    code, ended = cmd.exit_code(2.0)
    assert ended - sent <= 2.0 and code in (0, 130), (code, cmd.rest())
