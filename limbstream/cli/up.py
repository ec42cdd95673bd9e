"""``limbstream up``: the whole live system on this machine, one command.

Starts a Zenoh router, emulated devices, the aggregator and the dashboard as child
processes, prints what runs and where to look, and stops them all on Ctrl-C or SIGTERM.
Children get SIGTERM if this process dies (PR_SET_PDEATHSIG), so none outlives it.
"""
from __future__ import annotations

import argparse
import ctypes
import importlib.util
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass

from limbstream.signals import stop_on_signals

STOP_TIMEOUT_S = 5.0


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


@dataclass
class Child:
    """A started component."""

    name: str
    argv: list[str]
    process: subprocess.Popen | None = None


def start(child: Child, env: dict | None = None) -> Child:
    child.process = subprocess.Popen(child.argv, preexec_fn=_die_with_parent, env=env)
    return child


def stop_all(children: list[Child], timeout: float = STOP_TIMEOUT_S) -> None:
    """SIGTERM every child (last started first), then SIGKILL what is left after ``timeout``."""
    for child in reversed(children):
        if child.process and child.process.poll() is None:
            child.process.terminate()
    deadline = time.monotonic() + timeout
    for child in reversed(children):
        if child.process is None:
            continue
        try:
            child.process.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.process.kill()
            child.process.wait()


def wait_for_port(host: str, port: int, timeout: float, proc: subprocess.Popen | None = None) -> bool:
    """Poll until a TCP connect to host:port succeeds (or the process dies / time runs out)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            return False
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return True
        except OSError:
            time.sleep(0.05)
    return False


def split_endpoint(endpoint: str) -> tuple[str, int]:
    """``tcp/HOST:PORT`` or ``HOST:PORT`` -> (host, port); ValueError otherwise."""
    address = endpoint.split("/", 1)[1] if "/" in endpoint else endpoint
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"expected HOST:PORT, got {endpoint!r}")
    return host.strip("[]"), int(port)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--subjects", type=int, default=2, help="subjects to emulate (10 IMUs each), default 2")
    parser.add_argument("--source", default="generator", help="'generator' (default) or a motion file/folder")
    parser.add_argument("--router", default="tcp/127.0.0.1:7447", help="router endpoint (default tcp/127.0.0.1:7447)")
    parser.add_argument("--http", default="127.0.0.1:8000", help="dashboard address (default 127.0.0.1:8000)")
    parser.add_argument("--speed", type=float, default=1.0, help="time scale of the devices (default 1)")
    parser.add_argument("--emulators", type=int, default=1, help="emulator processes to spread subjects over")
    parser.add_argument("--threshold", type=float, default=1e-2, help="fastSW SSR threshold (default 1e-2)")
    parser.add_argument("--max-len", type=int, default=25, help="max segment length, samples (default 25)")
    parser.add_argument("--no-truth", action="store_true", help="devices do not publish the truth tap")
    parser.add_argument("--no-dashboard", action="store_true", help="do not start the dashboard")


def plan(args: argparse.Namespace) -> list[Child]:
    """The child processes ``up`` starts, in start order."""
    py = [sys.executable, "-m", "limbstream.cli"]
    connect = ["--connect", args.router]
    children = [Child("router", py + ["router", "--listen", args.router])]
    per = -(-args.subjects // args.emulators)
    for e in range(args.emulators):
        first = 1 + e * per
        count = min(per, args.subjects - e * per)
        if count <= 0:
            break
        argv = py + ["emulate", "--subjects", str(count), "--first-subject", str(first), "--source", args.source,
                     "--speed", str(args.speed), "--threshold", str(args.threshold), "--max-len", str(args.max_len)]
        if args.no_truth:
            argv.append("--no-truth")
        children.append(Child(f"emulator{e + 1}" if args.emulators > 1 else "emulator", argv + connect))
    children.append(Child("aggregator", py + ["aggregate"] + connect))
    if not args.no_dashboard and importlib.util.find_spec("services.dashboard.main") is not None:
        children.append(Child("dashboard", py + ["dashboard", "--http", args.http] + connect))
    return children


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    try:
        router_host, router_port = split_endpoint(args.router)
        split_endpoint(args.http)
        if args.subjects < 1 or args.emulators < 1:
            raise ValueError("--subjects and --emulators must be >= 1")
    except ValueError as exc:
        raise SystemExit(f"limbstream up: error: {exc}") from None
    stop = stop_on_signals(stop)
    children = plan(args)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    started: list[Child] = []
    try:
        started.append(start(children[0], env))
        if not wait_for_port(router_host, router_port, 15.0, children[0].process):
            print(f"limbstream up: the router did not come up on {args.router} (port in use?)", file=sys.stderr)
            return 1
        for child in children[1:]:
            started.append(start(child, env))
        print(f"\nlimbstream is running ({args.subjects} subjects x 10 IMUs, source {args.source}):")
        for child in started:
            print(f"  {child.name:<11} pid {child.process.pid}")
        if any(c.name == "dashboard" for c in started):
            print(f"\n  dashboard   http://{args.http}/   (API docs http://{args.http}/docs)")
        print(f"  zenoh       {args.router}  keys limbstream/<subject>/pose, limbstream/<subject>/stats")
        print("\nCtrl-C stops everything.\n", flush=True)
        while not stop.wait(0.2):
            dead = [c for c in started if c.process.poll() is not None]
            if dead:
                for c in dead:
                    print(f"limbstream up: {c.name} exited with status {c.process.returncode}; stopping",
                          file=sys.stderr)
                return 1
        return 0
    finally:
        stop_all(started)
        print("limbstream up: stopped", flush=True)
