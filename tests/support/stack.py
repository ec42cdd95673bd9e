"""Start the real live system as subprocesses for end-to-end tests, with the launcher of
``limbstream up`` (limbstream/launch.py).

Usage in a test module::

    from support.stack import Stack, stack  # noqa: F401  (the fixture)

    def test_something(stack):
        stack.router()
        stack.emulator(subjects=2)
        stack.aggregator()
        url = stack.dashboard()
        ...

Every process gets free ports, its output goes to a log file under the test's tmp_path (the
tail is shown when a readiness wait fails), readiness is polled with a deadline (a child that
exits meanwhile fails the wait at once), and teardown sends SIGTERM to each process group, then
SIGKILL after a grace period (no orphans).
"""
from __future__ import annotations

import contextlib
import json
import threading
import urllib.error
import urllib.request
from pathlib import Path

import pytest
import zenoh

from limbstream import wire, zconfig
from limbstream import launch
from limbstream.launch import Child, free_port  # noqa: F401  (re-exported for the tests)
from support import ROOT



def wait_until(predicate, timeout: float, what: str, interval: float = 0.05, on_fail=None):
    """Poll ``predicate()`` until it returns a truthy value (returned) or fail naming ``what``
    (:func:`limbstream.launch.wait_until`, failing as an assertion)."""
    try:
        return launch.wait_until(predicate, timeout, what, interval, on_fail)
    except TimeoutError as exc:
        raise AssertionError(str(exc)) from None


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


PAPER10 = ("--layout", "paper10")
"""The flags of the paper's 10 segments a subject (``emulate``'s and ``up``'s default is ``full``, 15):
what the tests stream unless they are about the layout."""


class Stack(launch.Launcher):
    """Router, emulator(s), aggregator(s) and dashboard of one test, on free ports.

    Parameters
    ----------
    workdir : where the logs go.
    launcher : the ``limbstream`` command (e.g. the entry point of an installed wheel instead).
    cwd : working directory of the processes.
    base_env : environment every process starts from (default: this process's).
    env : variables added for every process.
    """

    def __init__(self, workdir: Path, launcher=launch.LIMBSTREAM, cwd: Path = ROOT, base_env: dict | None = None,
                 env: dict | None = None):
        super().__init__(logdir=workdir, command=launcher, cwd=cwd, base_env=base_env, env=env)
        self.workdir = workdir
        self.port = free_port()

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    @property
    def procs(self) -> list[Child]:
        return self.children

    def _wait_port(self, port: int, proc: Child, timeout: float) -> None:
        self.wait_ready(proc, lambda: launch.port_open("127.0.0.1", port), f"{proc.name} to listen on port {port}",
                        timeout)

    def wait_ready(self, child, predicate, what, timeout):
        try:
            super().wait_ready(child, predicate, what, timeout)
        except TimeoutError as exc:
            raise AssertionError(str(exc)) from None

    def router(self, *extra: str, timeout: float = 20.0) -> Child:
        return super().router(self.endpoint, *extra, timeout=timeout)

    def emulator(self, subjects: int = 2, speed: float = 1.0, *extra: str) -> Child:
        """``emulate`` of ``subjects`` at ``speed``; on the generator ``--layout paper10`` unless ``extra``
        gives a layout or a source (10 devices a subject keep the tests light; emulate's default is full)."""
        given = any(a.split("=")[0] in ("--layout", "--source") for a in extra)
        return self.start("emulate", "emulate", "--connect", self.endpoint, "--subjects", str(subjects),
                          "--speed", str(speed), *([] if given else PAPER10), *extra)

    def aggregator(self, *extra: str) -> Child:
        return self.start("aggregate", "aggregate", "--connect", self.endpoint, *extra)

    def dashboard(self, *extra: str, env: dict | None = None, timeout: float = 30.0) -> str:
        """Start the dashboard; returns its base URL once ``/health`` answers 200."""
        return super().dashboard(f"127.0.0.1:{free_port()}", self.endpoint, *extra, env=env, timeout=timeout)[1]


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
        self.sub = self.session.declare_subscriber(wire.subject_selector("stats"), zenoh.handlers.FifoChannel(4096))
        self.devices: dict[str, dict] = {}
        self.subjects: dict[str, dict] = {}
        self.subject_history: dict[str, list[dict]] = {}  # every stats message of each subject, in order

    def poll(self) -> dict[str, dict]:
        while (sample := self.sub.try_recv()) is not None:
            data = wire.decode_stats(sample.payload.to_bytes())
            self.subjects[data["subject"]] = data
            self.subject_history.setdefault(data["subject"], []).append(data)
            for d in data["devices"]:
                self.devices[d["device"]] = d
        return self.devices

    def device_status(self, device: str) -> dict:
        """The device's own counters, asked over its config queryable (again while a busy device
        lets a query time out without a reply)."""
        subject, segment = device.split("/")

        def ask():
            replies = [r.ok for r in self.session.get(wire.config_key(subject, segment), timeout=5.0) if r.ok]
            return json.loads(replies[0].payload.to_bytes()) if replies else None
        return wait_until(ask, 60, f"{device}'s status")

    def close(self):
        self.session.close()


@pytest.fixture
def watch(stack):  # noqa: F811 - the fixture above
    stack.router()
    w = StatsWatch(stack.endpoint)
    yield w
    w.close()


@contextlib.contextmanager
def aggregator_in_thread(stack: Stack, subjects: tuple[str, ...] = ("s01",)):
    """Start ``stack``'s router and an aggregator of ``subjects`` running in a thread of this
    process (its loop reachable: its lock, its counters), connected to it; yields (the aggregator,
    the Zenoh settings of a client of that router) once it subscribes. Stopped and closed after."""
    from limbstream.services.aggregator.aggregator import Aggregator
    from limbstream.services.aggregator.settings import AggregatorSettings

    stack.router()
    settings = zconfig.ZenohSettings(connect=(stack.endpoint,))
    session = zconfig.open_session(settings)
    agg = Aggregator(session, AggregatorSettings(subjects=subjects))
    agg.open()
    stop = threading.Event()
    loop = threading.Thread(target=agg.run, args=(stop,), daemon=True)
    try:
        loop.start()
        wait_for_subscribers(stack.endpoint, [wire.seg_key(subjects[0], "hip")], "the aggregator", on_fail=stack.logs)
        yield agg, settings
    finally:
        stop.set()
        loop.join(10)
        agg.close()
        session.close()
