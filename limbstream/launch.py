"""Child processes of limbstream: the one launcher of ``limbstream up``, the tests' stack
(``tests/support/stack.py``) and the benchmarks (``bench/``).

- :class:`Child`: one command (by default ``python -P -m limbstream.cli <command> ...``) in its own
  process group, with ``PYTHONUNBUFFERED=1``; its output is appended to a log file, or forwarded
  line by line to this process's stdout (the last lines kept for error messages). It gets
  SIGTERM when the *thread* that started it ends (``PR_SET_PDEATHSIG``): start children from
  the main thread, so none outlives its parent.
- :class:`Launcher`: the children of one run; :meth:`Launcher.router` and
  :meth:`Launcher.dashboard` return once the part serves, and fail at once if a child exits.
- :func:`free_port`, :func:`wait_until`, :func:`wait_for_port`: readiness polled with a deadline.
- :func:`stop_all`: SIGTERM to every process group, SIGKILL after a grace period.
- :class:`Supervisor`: starts again a child that exited, with back-off; a child that keeps
  exiting raises :class:`CrashLoop`.
"""
from __future__ import annotations

import collections
import ctypes
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any
from dataclasses import dataclass, field
from pathlib import Path

LIMBSTREAM = (sys.executable, "-P", "-m", "limbstream.cli")
"""The ``limbstream`` command of this interpreter. ``-P``: the working directory is not put on the
module path, so a folder there named ``limbstream`` (e.g. a clone of the repository, seen from the
folder that holds it) never hides the installed package."""
STOP_GRACE_S = 5.0
TAIL_LINES = 40
_PR_SET_PDEATHSIG = 1
_output_lock = threading.Lock()


# ----------------------------------------------------------------------------- readiness


class PortTaken(RuntimeError):
    """A server part's port already accepts connections before the part starts (another process
    listens there; a readiness check would be fooled by it)."""

    def __init__(self, name: str, host: str, port: int):
        super().__init__(f"{name} cannot start: {host}:{port} is already in use by another process")
        self.name = name


class ChildExited(RuntimeError):
    """A child exited while something waited for it (or for another part)."""

    def __init__(self, child: Child):
        super().__init__(f"{child.name} exited ({child.exit_text()}): {child.last_line()}")
        self.child = child


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free on ``host`` a moment ago."""
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def wait_until(predicate: Callable, timeout: float, what: str, interval: float = 0.05,
               on_fail: Callable[[], str] | None = None):
    """Poll ``predicate()`` until it returns a truthy value, which is returned.

    An exception from the predicate counts as "not yet" (the last one is reported), except
    :class:`ChildExited`, which is raised at once. After ``timeout`` seconds: ``TimeoutError``
    naming ``what``, the predicate's last value and ``on_fail()`` (e.g. the children's logs).
    """
    deadline = time.monotonic() + timeout
    last = None
    while True:
        try:
            last = predicate()
        except ChildExited:
            raise
        except Exception as exc:  # noqa: BLE001 - the last error is reported on timeout
            last = exc
        else:
            if last:
                return last
        if time.monotonic() >= deadline:
            extra = on_fail() if on_fail else ""
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {what} (last: {last!r}){extra}")
        time.sleep(interval)


def port_open(host: str, port: int) -> bool:
    """True if a TCP connection to host:port is accepted now."""
    try:
        with socket.create_connection((host, port), timeout=0.2):
            return True
    except OSError:
        return False


def http_status(url: str, timeout: float = 1.0) -> int:
    """HTTP status of a GET (0 if nothing answers)."""
    try:
        with urllib.request.urlopen(url, timeout=timeout) as res:
            return res.status
    except urllib.error.HTTPError as exc:
        return exc.code
    except OSError:
        return 0


def split_endpoint(endpoint: str) -> tuple[str, int]:
    """``tcp/HOST:PORT`` or ``HOST:PORT`` (the first of a comma-separated list) -> (host, port);
    ValueError otherwise."""
    endpoint = endpoint.split(",")[0].strip()
    address = endpoint.split("/", 1)[1] if "/" in endpoint else endpoint
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"expected HOST:PORT, got {endpoint!r}")
    return host.strip("[]"), int(port)


def local_host(host: str) -> str:
    """Where to reach a server bound to ``host`` from this machine (0.0.0.0 -> 127.0.0.1)."""
    return {"": "127.0.0.1", "0.0.0.0": "127.0.0.1", "::": "::1"}.get(host, host)


def wait_for_port(host: str, port: int, timeout: float, watch: Iterable[Child] = (),
                  on_fail: Callable[[], str] | None = None) -> None:
    """Poll until host:port accepts a connection; ChildExited if a child in ``watch`` exits first."""
    watch = list(watch)

    def listening() -> bool:
        _check(watch)
        return port_open(host, port)
    wait_until(listening, timeout, f"port {port} on {host}", on_fail=on_fail)


def _check(children: Iterable[Child]) -> None:
    for child in children:
        if not child.alive():
            raise ChildExited(child)


# ----------------------------------------------------------------------------- one child


def _die_with_parent() -> Callable[[], None]:
    """The child's setup between fork and exec: SIGTERM when the parent thread ends."""
    parent = os.getpid()
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl  # loaded here, not in the forked child
    except (OSError, AttributeError):  # not Linux
        prctl = None

    def setup() -> None:
        if prctl is not None:
            prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:  # the parent died before the line above took effect
            os._exit(1)
    return setup


@dataclass(eq=False)
class Child:
    """One child process; :meth:`start` may be called again after it exited (a restart).

    Attributes
    ----------
    name : the part's name in messages (``router``, ``emulator2``, ...).
    argv : the command.
    env : its whole environment (``PYTHONUNBUFFERED=1`` is added); None: this process's.
    log : file its stdout and stderr are appended to (``os.devnull``: discarded); None: forwarded
        line by line to this process's stdout.
    cwd : working directory (None: this process's).
    """

    name: str
    argv: Sequence[str]
    env: Mapping[str, str] | None = None
    log: Path | None = None
    cwd: Path | None = None
    popen: subprocess.Popen | None = field(default=None, init=False, repr=False)
    started_at: float = field(default=0.0, init=False)
    """``time.monotonic()`` of the last start."""
    _lines: collections.deque = field(default_factory=lambda: collections.deque(maxlen=TAIL_LINES),
                                      init=False, repr=False)
    _reader: threading.Thread | None = field(default=None, init=False, repr=False)

    def start(self) -> Child:
        env = dict(os.environ if self.env is None else self.env, PYTHONUNBUFFERED="1")
        options: dict[str, Any] = dict(cwd=self.cwd, env=env, stdin=subprocess.DEVNULL, stderr=subprocess.STDOUT,
                                       start_new_session=True, preexec_fn=_die_with_parent())
        if self.log is None:
            self.popen = subprocess.Popen(list(self.argv), stdout=subprocess.PIPE, **options)
            self._reader = threading.Thread(target=self._forward, args=(self.popen.stdout,),
                                            name=f"{self.name}-output", daemon=True)
            self._reader.start()
        else:
            with open(self.log, "ab") as out:
                self.popen = subprocess.Popen(list(self.argv), stdout=out, **options)
        self.started_at = time.monotonic()
        return self

    def _forward(self, stream) -> None:
        with stream:
            for raw in stream:
                line = raw.decode(errors="replace")
                self._lines.append(line.rstrip())
                with _output_lock:
                    sys.stdout.write(line)
                    sys.stdout.flush()

    @property
    def pid(self) -> int | None:
        return self.popen.pid if self.popen else None

    @property
    def returncode(self) -> int | None:
        return self.popen.poll() if self.popen else None

    def alive(self) -> bool:
        return self.popen is not None and self.popen.poll() is None

    def exit_text(self) -> str:
        """``exit status N`` or ``killed by SIGNAME`` (``running`` if it has not exited)."""
        code = self.returncode
        if code is None:
            return "running"
        if code < 0:
            try:
                return f"killed by {signal.Signals(-code).name}"
            except ValueError:
                return f"killed by signal {-code}"
        return f"exit status {code}"

    def tail(self, n: int = TAIL_LINES) -> list[str]:
        """The last ``n`` lines of its output (over all its starts)."""
        if self.log is None:
            if self._reader is not None and not self.alive():
                self._reader.join(1.0)  # the lines it wrote before exiting
            return list(self._lines)[-n:]
        try:
            with open(self.log, "rb") as f:
                f.seek(max(0, os.fstat(f.fileno()).st_size - 200 * n))
                return f.read().decode(errors="replace").splitlines()[-n:]
        except OSError:
            return []

    def last_line(self) -> str:
        """Its last line of output that mentions an error (what stopped it; a process may print
        more while it shuts down), else its last non-blank line."""
        lines = [line.strip() for line in self.tail() if line.strip()]
        return next((line for line in reversed(lines) if "error" in line.lower()), lines[-1] if lines else "(no output)")

    def signal(self, sig: int) -> None:
        """Send ``sig`` to its process group (gone groups are ignored)."""
        if self.popen is not None:
            try:
                os.killpg(self.popen.pid, sig)
            except (ProcessLookupError, PermissionError):
                pass


def stop_all(children: Sequence[Child], grace: float = STOP_GRACE_S) -> None:
    """SIGTERM every child's process group (last started first), then SIGKILL what is left after
    ``grace`` seconds (a group may hold processes even after its leader exited)."""
    started = [(c, c.popen) for c in reversed(children) if c.popen is not None]
    for child, _ in started:
        if child.alive():
            child.signal(signal.SIGTERM)
    deadline = time.monotonic() + grace
    for child, popen in started:
        try:
            popen.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            pass
        child.signal(signal.SIGKILL)
        popen.wait()


# ----------------------------------------------------------------------------- one run


class Launcher:
    """The children of one run (``limbstream up``, a test, a benchmark), stopped together.

    Parameters
    ----------
    logdir : each child's output goes to ``<logdir>/<name>-<k>.log``; None: forwarded to stdout.
    command : the ``limbstream`` command (default this interpreter's; e.g. an installed entry point).
    cwd : working directory of the children.
    base_env : the environment children start from (None: this process's).
    env : variables added for every child.
    """

    def __init__(self, logdir: Path | None = None, command: Sequence[str] = LIMBSTREAM, cwd: Path | None = None,
                 base_env: Mapping[str, str] | None = None, env: Mapping[str, str] | None = None):
        self.logdir = logdir
        self.command = tuple(command)
        self.cwd = cwd
        self.base_env = base_env
        self.env = dict(env or {})
        self.children: list[Child] = []
        self.abort: threading.Event | None = None
        """Set (e.g. by a signal handler): :meth:`wait_ready` raises KeyboardInterrupt at its next poll."""

    def start(self, name: str, *args: str, env: Mapping[str, str] | None = None, prefix: Sequence[str] = (),
              command: Sequence[str] | None = None) -> Child:
        """Start ``limbstream <args>`` as ``name``; ``prefix`` is a wrapper command, e.g.
        ``("ip", "netns", "exec", "ns1")``; ``env`` adds variables for this child; ``command``
        replaces the ``limbstream`` command (e.g. ``(sys.executable, "-c", CODE)``)."""
        base = os.environ if self.base_env is None else self.base_env
        log = None if self.logdir is None else Path(self.logdir) / f"{name}-{len(self.children)}.log"
        argv = [*prefix, *(self.command if command is None else command), *args]
        child = Child(name, argv, {**base, **self.env, **(env or {})}, log, self.cwd)
        self.children.append(child)  # before it starts: stopped with the others whenever an interrupt comes
        return child.start()

    def wait_ready(self, child: Child, predicate: Callable[[], bool], what: str, timeout: float) -> None:
        """Poll ``predicate`` until true; ChildExited at once if ``child`` exits, or another child
        that was running exits with an error (a start that cannot succeed); KeyboardInterrupt
        once :attr:`abort` is set."""
        others = [c for c in self.children if c is not child and c.alive()]

        def ready() -> bool:
            if self.abort is not None and self.abort.is_set():
                raise KeyboardInterrupt
            _check([child])
            for other in others:
                if other.returncode not in (None, 0):
                    raise ChildExited(other)
            return predicate()
        try:
            wait_until(ready, timeout, what, on_fail=self.logs)
        except ChildExited as exc:
            exc.add_note(self.logs())
            raise

    def router(self, listen: str, *extra: str, timeout: float = 20.0) -> Child:
        """``limbstream router --listen LISTEN``, returned once its first endpoint accepts connections
        (:class:`PortTaken` if it did before)."""
        host, port = split_endpoint(listen)
        if port_open(host, port):
            raise PortTaken("router", host, port)
        child = self.start("router", "router", "--listen", listen, *extra)
        self.wait_ready(child, lambda: port_open(host, port), f"the router to listen on {listen}", timeout)
        return child

    def dashboard(self, http: str, connect: str, *extra: str, env: Mapping[str, str] | None = None,
                  timeout: float = 30.0) -> tuple[Child, str]:
        """``limbstream dashboard --http HTTP --connect CONNECT``, returned with its base URL once
        ``/health`` answers 200 (its Zenoh session is open); :class:`PortTaken` if its port is."""
        host, port = split_endpoint(http)
        host = local_host(host)
        url = f"http://{'[' + host + ']' if ':' in host else host}:{port}"
        if port_open(host, port):
            raise PortTaken("dashboard", host, port)
        child = self.start("dashboard", "dashboard", "--http", http, "--connect", connect, *extra, env=env)
        self.wait_ready(child, lambda: http_status(url + "/health") == 200, f"dashboard health at {url}", timeout)
        return child, url

    def logs(self, n: int = TAIL_LINES) -> str:
        """The last lines of every child's output, for failure messages."""
        return "".join(f"\n--- {c.name} ({c.exit_text()}) {c.log or ''}:\n" + "\n".join(c.tail(n))
                       for c in self.children)

    def stop(self, grace: float = STOP_GRACE_S) -> None:
        stop_all(self.children, grace)

    def __enter__(self) -> Launcher:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


# ----------------------------------------------------------------------------- supervision


@dataclass(frozen=True)
class RestartPolicy:
    """When :class:`Supervisor` starts an exited child again.

    The first restart waits ``first_delay_s``; each further one twice as long, up to
    ``max_delay_s``; a child that ran ``healthy_s`` before exiting starts over at
    ``first_delay_s``. ``max_exits`` exits within ``window_s`` are a crash loop.
    """

    first_delay_s: float = 0.5
    max_delay_s: float = 10.0
    healthy_s: float = 60.0
    max_exits: int = 5
    window_s: float = 60.0


class CrashLoop(RuntimeError):
    """A child exited :attr:`RestartPolicy.max_exits` times within the window."""

    def __init__(self, child: Child, exits: int, window_s: float):
        super().__init__(f"{child.name} exited {exits} times within {window_s:g} s ({child.exit_text()}): "
                         f"{child.last_line()}")
        self.child = child


@dataclass
class _Record:
    delay: float
    restarts: int = 0
    exits: collections.deque = field(default_factory=collections.deque)
    due: float | None = None  # restart time while it waits, else None
    last_exit: str | None = None


class Supervisor:
    """Keeps started children running: one that exits is started again after its back-off.

    ``children`` is used as given (not copied): children appended later are supervised too.
    Call :meth:`poll` periodically from the thread that started the children (a child dies with
    the thread that started it). ``report(message)`` is told of every exit and restart.
    """

    def __init__(self, children: list[Child], policy: RestartPolicy = RestartPolicy(),
                 report: Callable[[str], None] = print):
        self.children = children
        self.policy = policy
        self.report = report
        self.records: dict[str, _Record] = {}

    def _record(self, child: Child) -> _Record:
        return self.records.setdefault(child.name, _Record(self.policy.first_delay_s))

    def poll(self, now: float | None = None) -> bool:
        """Note exits, start what is due; True if anything changed. Raises :class:`CrashLoop`."""
        now = time.monotonic() if now is None else now
        changed = False
        for child in self.children:
            rec = self._record(child)
            if rec.due is not None:
                if now >= rec.due:
                    child.start()
                    rec.due, rec.restarts, changed = None, rec.restarts + 1, True
                    self.report(f"{child.name} started again (pid {child.pid}, restart {rec.restarts})")
                continue
            if child.alive():
                continue
            changed = True
            rec.last_exit = child.exit_text()
            rec.exits.append(now)
            while rec.exits and rec.exits[0] < now - self.policy.window_s:
                rec.exits.popleft()
            if len(rec.exits) >= self.policy.max_exits:
                raise CrashLoop(child, len(rec.exits), self.policy.window_s)
            if now - child.started_at >= self.policy.healthy_s:
                rec.delay = self.policy.first_delay_s
            rec.due = now + rec.delay
            self.report(f"{child.name} {rec.last_exit}; starting it again in {rec.delay:g} s")
            rec.delay = min(2 * rec.delay, self.policy.max_delay_s)
        return changed

    def status(self) -> dict[str, dict]:
        """Per child: ``pid``, ``state`` (running, restarting, exited), ``restarts``, ``last_exit``."""
        parts = {}
        for child in self.children:
            rec = self._record(child)
            state = "running" if child.alive() else "restarting" if rec.due is not None else "exited"
            parts[child.name] = {"pid": child.pid, "state": state, "restarts": rec.restarts,
                                 "last_exit": rec.last_exit}
        return parts
