"""Start the real live system as subprocesses for end-to-end tests.

Usage in a test module::

    from stack import Stack, stack  # noqa: F401  (the fixture)

    def test_something(stack):
        stack.router()
        stack.emulator(subjects=2)
        stack.aggregator()
        url = stack.dashboard()
        ...

Every process gets free ports, its output goes to a log file under the test's tmp_path (the
tail is shown when a readiness wait fails), readiness is polled with a deadline, and teardown
sends SIGTERM to each process group, then SIGKILL after a grace period (no orphans).
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zenoh

from limbstream import wire, zconfig

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    """A TCP port that was free on 127.0.0.1 a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(predicate, timeout: float, what: str, interval: float = 0.05, on_fail=None):
    """Poll ``predicate()`` until it returns a truthy value (returned) or fail naming ``what``."""
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        try:
            last = predicate()
        except Exception as exc:  # noqa: BLE001 - the last error is reported on timeout
            last = exc
        else:
            if last:
                return last
        time.sleep(interval)
    extra = on_fail() if on_fail else ""
    raise AssertionError(f"timed out after {timeout:g} s waiting for {what} (last: {last!r}){extra}")


def http_json(url: str, timeout: float = 5.0, method: str = "GET", body=None, headers=None):
    """(status, parsed JSON or text) of one HTTP request; HTTP errors are returned, not raised."""
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method,
                                 headers={"Content-Type": "application/json", **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as res:
            status, raw = res.status, res.read()
    except urllib.error.HTTPError as exc:
        status, raw = exc.code, exc.read()
    try:
        return status, json.loads(raw)
    except ValueError:
        return status, raw.decode(errors="replace")


@dataclass
class Proc:
    """One started process and its log file."""

    name: str
    popen: subprocess.Popen
    log: Path

    def tail(self, n: int = 40) -> str:
        try:
            lines = self.log.read_text(errors="replace").splitlines()[-n:]
        except OSError:
            return ""
        return f"\n--- {self.name} (exit {self.popen.poll()}) {self.log}:\n" + "\n".join(lines)

    def alive(self) -> bool:
        return self.popen.poll() is None


@dataclass
class Stack:
    """Router, emulator(s), aggregator(s) and dashboard of one test, on free ports."""

    workdir: Path
    port: int = field(default_factory=free_port)
    procs: list[Proc] = field(default_factory=list)
    env: dict = field(default_factory=dict)
    launcher: tuple[str, ...] = (sys.executable, "-m", "limbstream.cli")
    """The ``limbstream`` command (e.g. the entry point of an installed wheel instead)."""
    cwd: Path = ROOT
    base_env: dict | None = None
    """Environment every process starts from (default: this process's)."""

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    def logs(self) -> str:
        return "".join(p.tail() for p in self.procs)

    def start(self, name: str, *args: str, env: dict | None = None, prefix: tuple[str, ...] = ()) -> Proc:
        """Run ``limbstream <args>`` (see :attr:`launcher`) in its own process group; ``prefix`` is
        a wrapper command, e.g. ``("ip", "netns", "exec", "ns1")``."""
        log = self.workdir / f"{name}-{len(self.procs)}.log"
        base = os.environ if self.base_env is None else self.base_env
        full_env = dict(base) | {"PYTHONUNBUFFERED": "1"} | self.env | (env or {})
        with open(log, "wb") as out:
            popen = subprocess.Popen([*prefix, *self.launcher, *args], cwd=self.cwd,
                                     stdout=out, stderr=subprocess.STDOUT, env=full_env,
                                     start_new_session=True)
        proc = Proc(name, popen, log)
        self.procs.append(proc)
        return proc

    def _wait_port(self, port: int, proc: Proc, timeout: float) -> None:
        def listening():
            if not proc.alive():
                raise AssertionError(f"{proc.name} exited with {proc.popen.returncode}")
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return True
        wait_until(listening, timeout, f"{proc.name} to listen on port {port}", on_fail=self.logs)

    def router(self, *extra: str, timeout: float = 20.0) -> Proc:
        proc = self.start("router", "router", "--listen", self.endpoint, *extra)
        self._wait_port(self.port, proc, timeout)
        return proc

    def emulator(self, subjects: int = 2, speed: float = 1.0, *extra: str) -> Proc:
        return self.start("emulate", "emulate", "--connect", self.endpoint, "--subjects", str(subjects),
                          "--speed", str(speed), *extra)

    def aggregator(self, *extra: str) -> Proc:
        return self.start("aggregate", "aggregate", "--connect", self.endpoint, *extra)

    def dashboard(self, *extra: str, env: dict | None = None, timeout: float = 30.0) -> str:
        """Start the dashboard; returns its base URL once ``/health`` answers 200."""
        port = free_port()
        proc = self.start("dashboard", "dashboard", "--http", f"127.0.0.1:{port}", "--connect",
                          self.endpoint, *extra, env=env)
        url = f"http://127.0.0.1:{port}"

        def healthy():
            if not proc.alive():
                raise AssertionError(f"dashboard exited with {proc.popen.returncode}")
            return http_json(url + "/health", timeout=1.0)[0] == 200
        wait_until(healthy, timeout, f"dashboard health at {url}", interval=0.1, on_fail=self.logs)
        return url

    def stop(self, grace: float = 5.0) -> None:
        """SIGTERM every process group (newest first), then SIGKILL what is left."""
        for proc in reversed(self.procs):
            if proc.alive():
                try:
                    os.killpg(proc.popen.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + grace
        for proc in reversed(self.procs):
            try:
                proc.popen.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
            try:  # the group may hold children even after the leader exited
                os.killpg(proc.popen.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
            proc.popen.wait()


@pytest.fixture
def stack(tmp_path):
    """A :class:`Stack` torn down after the test."""
    s = Stack(tmp_path)
    try:
        yield s
    finally:
        s.stop()


def wait_for_subscribers(endpoint: str, keys: list[str], what: str, on_fail=None) -> None:
    """Block until a publisher on ``endpoint`` would reach a subscriber for every key (no sample is sent)."""
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    try:
        publishers = [session.declare_publisher(k) for k in keys]
        wait_until(lambda: all(p.matching_status.matching for p in publishers), 30, what, on_fail=on_fail)
    finally:
        session.close()


class StatsWatch:
    """A client session in the test that keeps the latest stats of every device."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.sub = self.session.declare_subscriber("limbstream/*/stats", zenoh.handlers.FifoChannel(4096))
        self.devices: dict[str, dict] = {}
        self.subjects: dict[str, dict] = {}

    def poll(self) -> dict[str, dict]:
        while (sample := self.sub.try_recv()) is not None:
            data = wire.decode_stats(sample.payload.to_bytes())
            self.subjects[data["subject"]] = data
            for d in data["devices"]:
                self.devices[d["device"]] = d
        return self.devices

    def device_status(self, device: str) -> dict:
        """The device's own counters, asked over its config queryable."""
        subject, segment = device.split("/")
        replies = list(self.session.get(wire.config_key(subject, segment), timeout=5.0))
        return json.loads(replies[0].ok.payload.to_bytes())

    def close(self):
        self.session.close()


@pytest.fixture
def watch(stack):  # noqa: F811 - the fixture above
    stack.router()
    w = StatsWatch(stack.endpoint)
    yield w
    w.close()
