"""``limbstream up``: the whole live system on this machine, one command.

Starts a Zenoh router, emulated devices, the aggregator and the dashboard as child processes
(:mod:`limbstream.launch`), forwards their output, prints what runs and where to look, and
keeps them running: a part that exits is started again after a back-off (0.5 s, doubling up
to 10 s, back to 0.5 s after a minute of health); one that exits ``--max-exits`` times within
60 s, or fails while the system starts, stops everything with a one-line error naming it.
Ctrl-C or SIGTERM stops everything; children get SIGTERM if this process dies
(PR_SET_PDEATHSIG), so none outlives it.

Restart counts per part are kept in a JSON status file (``--status-file``; its path is given
to the dashboard in ``LIMBSTREAM_UP_STATUS``)::

    {"supervisor": "limbstream up", "pid": 4242, "state": "running", "updated": 1730000000.0,
     "parts": {"router": {"pid": 4243, "state": "running", "restarts": 0, "last_exit": null}, ...}}

``state`` of ``up``: starting, running, stopped; of a part: running, restarting (waiting for its
back-off), exited; ``last_exit``: e.g. ``killed by SIGKILL``, ``exit status 1``.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import secrets
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

from limbstream.cli.emulate import add_clock_arguments, clock_flags
from limbstream.cli.gateway_slimevr import parse_address
from limbstream import wire, zconfig
from limbstream.cli import flags
from limbstream.launch import (ChildExited, CrashLoop, Launcher, PortTaken, RestartPolicy, Supervisor,
                                   split_endpoint)
from limbstream.services.dashboard.supervision import STATUS_ENV  # the status file's path, for the dashboard
from limbstream.signals import stop_on_signals

TOKEN_ENV = "LIMBSTREAM_API_TOKEN"
ROUTER_TIMEOUT_S = 15.0
DASHBOARD_TIMEOUT_S = 30.0
POLL_S = 0.1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--subjects", type=int, default=2, help="subjects to emulate (10 IMUs each), default 2")
    parser.add_argument("--source", default="generator", help="'generator' (default) or a motion file/folder")
    parser.add_argument("--router", default=zconfig.DEFAULT_ROUTER, help=f"router endpoint (default {zconfig.DEFAULT_ROUTER})")
    parser.add_argument("--http", default="127.0.0.1:8000", help="dashboard address (default 127.0.0.1:8000)")
    parser.add_argument("--speed", type=float, default=1.0, help="time scale of the devices (default 1)")
    parser.add_argument("--emulators", type=int, default=1, help="emulator processes to spread subjects over")
    # the device tunables, passed on to the emulators; live mode on by default (wire.LIVE_MODE)
    flags.add_device_config(parser, defaults=wire.LIVE_MODE)
    parser.add_argument("--no-truth", action="store_true", help="devices do not publish the truth tap")
    parser.add_argument("--firmware", action="store_true",
                        help="the devices run their firmware under QEMU (emulate --firmware: one process per device)")
    add_clock_arguments(parser, tuning=False)  # device clocks, passed on; with sync a time service is started
    flags.add_sensor_model(parser)  # sensors, passed on; on, the aggregator calibrates every new stream
    parser.add_argument("--no-dashboard", action="store_true", help="do not start the dashboard")
    parser.add_argument("--slimevr", default=None, metavar="[HOST:]PORT",
                        help="also start the SlimeVR gateway: trackers send to this UDP port (their default: 6969); "
                             "with --subjects 0 only real trackers run")
    parser.add_argument("--slimevr-subject", default="sv01",
                        help="subject of the SlimeVR trackers (default sv01)")
    parser.add_argument("--max-exits", type=int, default=RestartPolicy.max_exits,
                        help=f"stop everything when one part exits this many times within "
                             f"{RestartPolicy.window_s:g} s (default {RestartPolicy.max_exits})")
    parser.add_argument("--status-file", type=Path, default=None,
                        help="where to keep the JSON status of the parts (restart counts); default: a "
                             "temporary file removed on exit")


def plan(args: argparse.Namespace) -> list[tuple[str, list[str]]]:
    """(name, ``limbstream`` arguments) of the time service, the emulators and the aggregator, in
    start order."""
    connect = ["--connect", args.router]
    sensors = flags.sensor_model(args)
    parts = []
    # a scaled time base (--speed) is shared by the time service and the devices: one anchor
    anchor = [] if args.speed == 1 else ["--time-anchor", f"{time.time():.3f}"]
    if args.sync:
        parts.append(("clock", ["clock", "--speed", str(args.speed), *anchor] + connect))
    per = -(-args.subjects // args.emulators)
    for e in range(args.emulators):
        first = 1 + e * per
        count = min(per, args.subjects - e * per)
        if count <= 0:
            break
        argv = ["emulate", "--subjects", str(count), "--first-subject", str(first), "--source", args.source,
                "--speed", str(args.speed), *flags.device_config(args).flags(), *clock_flags(args), *anchor]
        if args.no_truth:
            argv.append("--no-truth")
        if args.firmware:
            argv.append("--firmware")
        if sensors.on:
            argv += flags.sensor_model_argv(sensors)
        parts.append((f"emulator{e + 1}" if args.emulators > 1 else "emulator", argv + connect))
    if args.slimevr is not None:
        argv = ["gateway", "slimevr", "--udp", args.slimevr, "--subject", args.slimevr_subject,
                *flags.device_config(args).flags()]
        argv += (["--no-truth"] if args.no_truth else []) + ([] if args.sync else ["--no-sync"])
        if args.status_file is not None:  # run-time assignments kept beside the status file, as calibrations
            argv += ["--assignments-file", str(Path(args.status_file).with_name("slimevr-assignments.json"))]
        parts.append(("slimevr", argv + connect))
    calibrations = ["--calibrate-on-start"] if sensors.on else []
    if sensors.on and args.status_file is not None:  # kept beside the status file: they outlive a restart
        calibrations += ["--calibration-file", str(Path(args.status_file).with_name("calibrations.json"))]
    parts.append(("aggregator", ["aggregate", *calibrations] + connect))
    return parts


def write_status(path: Path, state: str, supervisor: Supervisor) -> None:
    """Replace the status file at once (readers never see half a file)."""
    data = {"supervisor": "limbstream up", "pid": os.getpid(), "state": state, "updated": time.time(),
            "parts": supervisor.status()}
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    os.replace(tmp, path)


def dashboard_env(status_file: Path) -> dict[str, str]:
    """The dashboard's extra variables: the status file, and in development mode without a token
    one generated here, so that a restarted dashboard keeps it."""
    env = {STATUS_ENV: str(status_file)}
    if not os.environ.get(TOKEN_ENV, "").strip() and os.environ.get("LIMBSTREAM_MODE", "development") != "production":
        env[TOKEN_ENV] = secrets.token_urlsafe(24)
    return env


def _abort_start(*_) -> None:
    raise KeyboardInterrupt


def say(message: str) -> None:
    print(f"limbstream up: {message}", file=sys.stderr, flush=True)


def check(args: argparse.Namespace) -> str | None:
    """The flags' first mistake (one sentence), or None."""
    try:
        split_endpoint(args.router)
        split_endpoint(args.http)
        if args.subjects < (0 if args.slimevr is not None else 1) or args.emulators < 1 or args.max_exits < 1:
            raise ValueError("--subjects (>= 0 with --slimevr), --emulators and --max-exits must be >= 1")
        if args.slimevr is not None:
            parse_address(args.slimevr)
            wire.check_chunk(args.slimevr_subject, "--slimevr-subject")
        flags.sensor_model(args)  # ValueError naming a bad sensor bound
    except (ValueError, argparse.ArgumentTypeError) as exc:
        return str(exc)
    return None


def start(args: argparse.Namespace, launcher: Launcher, supervisor: Supervisor, status_file: Path,
          dashboard_vars: dict | None) -> bool:
    """Start the router, the parts of :func:`plan` and (with ``dashboard_vars``) the dashboard;
    False, said in one line, if one of them cannot start."""
    try:
        launcher.router(args.router, timeout=ROUTER_TIMEOUT_S)
        write_status(status_file, "starting", supervisor)
        for name, argv in plan(args):
            launcher.start(name, *argv)
        write_status(status_file, "starting", supervisor)
        if dashboard_vars is not None:
            launcher.dashboard(args.http, args.router, env=dashboard_vars, timeout=DASHBOARD_TIMEOUT_S)
    except ChildExited as exc:
        say(f"{exc.child.name} failed to start ({exc.child.exit_text()}): {exc.child.last_line()}")
        return False
    except PortTaken as exc:
        say(str(exc))
        return False
    except TimeoutError:
        late = launcher.children[-1]
        say(f"{late.name} did not come up within "
            f"{ROUTER_TIMEOUT_S if late.name == 'router' else DASHBOARD_TIMEOUT_S:g} s: {late.last_line()}")
        return False
    return True


def banner(args: argparse.Namespace, launcher: Launcher, status_file: Path, dashboard_vars: dict | None) -> None:
    """What runs where, once everything is up."""
    print(f"\nlimbstream is running ({args.subjects} subjects x 10 IMUs, source {args.source}):")
    for child in launcher.children:
        print(f"  {child.name:<11} pid {child.pid}")
    if dashboard_vars is not None:
        print(f"\n  dashboard   http://{args.http}/   (API docs http://{args.http}/docs)")
        if TOKEN_ENV in dashboard_vars:
            print(f"  API token   {dashboard_vars[TOKEN_ENV]}   (development; set {TOKEN_ENV} to choose one)")
    if args.slimevr is not None:
        host, port = parse_address(args.slimevr)
        print(f"  slimevr     udp {host}:{port}  subject {args.slimevr_subject} (point trackers at this "
              "machine's address and this port)")
    print(f"  zenoh       {args.router}  keys limbstream/<subject>/pose, limbstream/<subject>/stats")
    print(f"  status      {status_file}  (restart counts; a part that exits is started again)")
    print("\nCtrl-C stops everything.\n", flush=True)


def supervise(supervisor: Supervisor, status_file: Path, stop: threading.Event) -> int:
    """Restart the parts that exit until ``stop``; 1 when one keeps exiting (its last lines said)."""
    while not stop.wait(POLL_S):
        try:
            if supervisor.poll():
                write_status(status_file, "running", supervisor)
        except CrashLoop as exc:
            say(f"{exc}; stopping")
            print(f"last lines of {exc.child.name}'s output:", file=sys.stderr)
            for line in exc.child.tail(10):
                print(f"  {line}", file=sys.stderr)
            return 1
    return 0


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    mistake = check(args)
    if mistake is not None:
        print(f"limbstream up: error: {mistake}", file=sys.stderr)
        return 2
    temp = None
    if args.status_file is None:
        temp = Path(tempfile.mkdtemp(prefix="limbstream-up-"))
        args.status_file = temp / "status.json"
    status_file = args.status_file.resolve()
    launcher = Launcher()
    supervisor = Supervisor(launcher.children, RestartPolicy(max_exits=args.max_exits), report=say)
    dashboard = not args.no_dashboard and importlib.util.find_spec("limbstream.services.dashboard.main") is not None
    dashboard_vars = dashboard_env(status_file) if dashboard else None
    signal.signal(signal.SIGTERM, _abort_start)  # while starting, Ctrl-C or SIGTERM abort the start
    try:
        if not start(args, launcher, supervisor, status_file, dashboard_vars):
            return 1
        stop = stop_on_signals(stop)
        write_status(status_file, "running", supervisor)
        banner(args, launcher, status_file, dashboard_vars)
        return supervise(supervisor, status_file, stop)
    except KeyboardInterrupt:
        return 130
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # stopping: not interrupted again
        launcher.stop()
        if temp is not None:
            for f in (status_file, status_file.with_name(status_file.name + ".tmp")):
                f.unlink(missing_ok=True)
            temp.rmdir()
        elif status_file.exists():
            write_status(status_file, "stopped", supervisor)
        print("limbstream up: stopped", flush=True)
