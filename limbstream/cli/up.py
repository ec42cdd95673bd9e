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
import shlex
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

from limbstream.cli.emulate import (add_clock_arguments, add_source_arguments, check_clock, clip_of, clock_flags,
                                    default_subjects)
from limbstream.cli.gateway_slimevr import parse_address
from limbstream import sources, wire, zconfig
from limbstream.body import LAYOUTS, Layout, layout_for
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
    parser.add_argument("--subjects", type=int, default=None,
                        help="subjects to emulate, each with a device per segment of the source (default: 2 on the "
                             "generator, 1 on a motion file or recording, whose person it is; more are copies)")
    parser.add_argument("--source", default="generator",
                        help="'generator' (default: the body of --layout) or a motion file/folder (.npz, .bvh, x-IMU3 "
                             ".csv, Xsens .txt); its clips go to the subjects in turn")
    add_source_arguments(parser)  # --names, --same-start: passed on
    router = os.environ.get(zconfig.ROUTER_ENV, zconfig.DEFAULT_ROUTER)
    parser.add_argument("--router", default=router, metavar="ENDPOINT",
                        help=f"where the router listens; every part connects there (env {zconfig.ROUTER_ENV}, which "
                             f"every command's --connect also defaults to; default {router})")
    parser.add_argument("--http", default="127.0.0.1:8000", action=flags.Given,
                        help="dashboard address (default 127.0.0.1:8000)")
    parser.add_argument("--speed", type=float, default=1.0, help="time scale of the devices (default 1)")
    parser.add_argument("--emulators", type=int, default=1, help="emulator processes to spread subjects over")
    # the device tunables, passed on to the emulators; live mode on by default (wire.LIVE_MODE)
    flags.add_device_config(parser, defaults=wire.LIVE_MODE)
    parser.add_argument("--no-truth", action="store_true", help="devices do not publish the truth tap")
    parser.add_argument("--firmware", action="store_true",
                        help="the devices run their firmware under QEMU (emulate --firmware: one process per device)")
    add_clock_arguments(parser, tuning=False)  # device clocks, passed on; with sync a time service is started
    flags.add_sensor_model(parser)  # sensors, passed on; on, the aggregator calibrates every new stream
    flags.add_layout(parser)  # the generator's body, passed on
    flags.add_body(parser)  # the subjects' dimensions, passed on: their devices announce them
    flags.add_heading_correction(parser)  # the aggregator's, for the calibrated devices
    parser.add_argument("--no-dashboard", action="store_true", help="do not start the dashboard")
    parser.add_argument("--slimevr", default=None, metavar="[HOST:]PORT",
                        help="also start the SlimeVR gateway: trackers send to this UDP port (their default: 6969); "
                             "with --subjects 0 only real trackers run")
    parser.add_argument("--slimevr-subject", default="sv01", action=flags.Given,
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
    connect = ["--connect", args.router, "--connect-timeout", "0"]  # parts wait for a restarted router
    sensors = flags.sensor_model(args)
    raw = args.imu == "raw"  # a raw sensor's filter starts at its own heading: calibrated as a modelled one
    parts = []
    # a scaled time base (--speed) is shared by the time service and the devices: one anchor
    anchor = [] if args.speed == 1 else ["--time-anchor", f"{time.time():.3f}"]
    if args.sync:
        parts.append(("clock", ["clock", "--speed", str(args.speed), *anchor] + connect))
    subjects = default_subjects(args.source) if args.subjects is None else args.subjects
    per = -(-subjects // args.emulators)
    for e in range(args.emulators):
        first = 1 + e * per
        count = min(per, subjects - e * per)
        if count <= 0:
            break
        argv = ["emulate", "--subjects", str(count), "--first-subject", str(first), "--source", args.source,
                *flags.names_argv(args.names), *(["--same-start"] if args.same_start else []),
                "--speed", str(args.speed), *flags.device_config(args).flags(), *clock_flags(args), *anchor,
                *flags.layout_argv(args), *flags.body_argv(args)]
        if args.no_truth:
            argv.append("--no-truth")
        if args.firmware:
            argv.append("--firmware")
        if sensors.on or raw:
            argv += flags.sensor_model_argv(sensors, args)
        parts.append((f"emulator{e + 1}" if args.emulators > 1 else "emulator", argv + connect))
    if args.slimevr is not None:
        argv = ["gateway", "slimevr", "--udp", args.slimevr, "--subject", args.slimevr_subject,
                *flags.device_config(args).flags(), *flags.layout_argv(args)]
        argv += (["--no-truth"] if args.no_truth else []) + ([] if args.sync else ["--no-sync"])
        if args.status_file is not None:  # run-time assignments kept beside the status file, as calibrations
            argv += ["--assignments-file", str(Path(args.status_file).with_name("slimevr-assignments.json"))]
        parts.append(("slimevr", argv + connect))
    calibrations = ["--calibrate-on-start"] if sensors.on or raw else []
    if calibrations and args.status_file is not None:  # kept beside the status file: they outlive a restart
        calibrations += ["--calibration-file", str(Path(args.status_file).with_name("calibrations.json"))]
    parts.append(("aggregator", ["aggregate", *calibrations, "--heading-correction", args.heading_correction] + connect))
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


def start(args: argparse.Namespace, launcher: Launcher, supervisor: Supervisor, status_file: Path,
          dashboard: bool) -> dict[str, str]:
    """Start the router, the parts and the dashboard, each once ready (ChildExited, PortTaken or
    TimeoutError if one cannot; KeyboardInterrupt at the next step once ``launcher.abort`` is
    set: a signal never lands inside a fork); the dashboard's extra variables."""

    def step(message: str = "") -> None:
        if launcher.abort is not None and launcher.abort.is_set():
            raise KeyboardInterrupt
        if message:
            progress(message)
    step(f"starting the router on {args.router}")
    launcher.router(args.router, timeout=ROUTER_TIMEOUT_S)
    write_status(status_file, "starting", supervisor)
    parts = plan(args)
    step(f"starting {', '.join(name for name, _ in parts)}")
    for name, argv in parts:
        step()
        launcher.start(name, *argv)
    write_status(status_file, "starting", supervisor)
    dashboard_vars = dashboard_env(status_file)
    if dashboard:
        step(f"starting the dashboard on http://{args.http}/")
        launcher.dashboard(args.http, args.router, env=dashboard_vars, timeout=DASHBOARD_TIMEOUT_S)
    return dashboard_vars


def banner(args: argparse.Namespace, launcher: Launcher, devices: list[tuple[str, ...]],
           dashboard_vars: dict[str, str] | None, status_file: Path) -> None:
    """What runs and where to look (stdout)."""
    print(f"\nlimbstream is running ({running(devices, args)}):")
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
    commands = client_commands(args)
    print(f"  try         {commands[0]}")
    for command in commands[1:]:
        print(f"              {command}")
    if args.source == "generator" and args.subjects:  # (the built-in motion's still moments: generator.STILL_S)
        print("  still       the built-in motion stands still in the rest pose for 3 s about every 30 s "
              "(calibrate waits for that)")


def say(message: str) -> None:
    print(f"limbstream up: {message}", file=sys.stderr, flush=True)


def progress(message: str) -> None:
    """A step of the start, on stdout (``limbstream up: starting ...``): where a Ctrl-C came."""
    print(f"limbstream up: {message}", flush=True)


def check(args: argparse.Namespace) -> list[tuple[str, ...]]:
    """Every flag and the source, before any part starts: ValueError naming the first problem
    (a flag, or the source's file and what is wrong with it). Returns the segments of each
    emulated subject's devices."""
    if args.subjects is None:
        args.subjects = default_subjects(args.source)
    if "," not in args.router:
        zconfig.check_endpoint(args.router, "--router", listen=True)
    if args.router.split("/", 1)[0] not in zconfig.HOST_PORT_PROTOCOLS or "," in args.router:
        raise ValueError(f"--router {args.router}: expected one endpoint PROTOCOL/HOST:PORT, e.g. "
                         f"{zconfig.DEFAULT_ROUTER} (the router listens there, every part connects there)")
    if split_endpoint(args.router)[1] == 0:
        raise ValueError(f"--router {args.router}: the parts need the router's port: 0 picks none")
    flags.parse_http(args.http, allow_zero=False)
    for flag, dest, needs, present in (("--http", "http", "the dashboard (without --no-dashboard)", not args.no_dashboard),
                                       ("--slimevr-subject", "slimevr_subject", "--slimevr", args.slimevr is not None)):
        if flags.given(args, dest) and not present:
            raise ValueError(f"{flag} applies only with {needs}")
    flags.check_shared(args)  # (the sensors' flags; limbstream has checked them too)
    least = 0 if args.slimevr is not None else 1
    for flag, value, low in (("--subjects", args.subjects, least), ("--emulators", args.emulators, 1),
                             ("--max-exits", args.max_exits, 1)):
        if value < low:
            extra = " (0: the SlimeVR trackers alone)" if flag == "--subjects" and least == 0 else ""
            raise ValueError(f"{flag} must be >= {low}{extra}, got {value}")
    if not args.speed > 0:
        raise ValueError(f"--speed must be > 0, got {args.speed:g}")
    if args.slimevr is not None:
        parse_address(args.slimevr)
        wire.check_chunk(args.slimevr_subject, "--slimevr-subject")
    flags.sensor_model(args)  # a bad sensor bound, or one raw sensors do not take
    flags.bodies(args)  # a bad layout, a height or bone out of bounds, a malformed body file
    check_clock(args)
    if args.imu == "raw" and (args.clock_offset_ms or args.clock_drift_ppm or args.clock_jitter_us):
        raise ValueError("--imu raw samples on the feed's own clock: device clock models (--clock-offset-ms, "
                         "--clock-drift-ppm, --clock-jitter-us) are not available with it")
    if args.source == "generator":
        if args.names is not None:
            raise ValueError("--names maps the sensors of an IMU recording; the generator has none")
        return [flags.layout(args).segment_names] * args.subjects
    motions = sources.load(args.source, args.names, layout=flags.source_layout(args))
    for motion in motions:
        flags.check_source_layout(args, motion.segments, args.source)
    return [motions[clip_of(k, len(motions))[0]].segments for k in range(1, args.subjects + 1)]


def subject_layouts(args: argparse.Namespace, devices: list[tuple[str, ...]]) -> list[Layout]:
    """The subjects' layouts: ``--layout`` (without it the generator's default, ``flags.DEFAULT_LAYOUT``), else
    the smallest built-in layout holding a motion file's segments (as the aggregator takes it)."""
    if not devices:
        return []
    if args.source == "generator" or getattr(args, "layout", None) is not None:
        return [flags.layout(args)]
    return [layout_for(segments) for segments in devices]


def typed_command() -> str:
    """How to type this interpreter's ``limbstream`` command in the shell ``up`` runs in, so that the
    banner's commands work as printed: ``limbstream`` when PATH finds this very one (e.g. in an
    activated virtual environment), else the path of its entry point, relative to the working
    directory when below it (``.venv/bin/limbstream`` under ``make run``), else ``python -m``."""
    script = Path(sys.executable).parent / "limbstream"
    found = shutil.which("limbstream")
    if found is not None and Path(found).resolve() == script.resolve():
        return "limbstream"
    if not script.is_file():
        return f"{shlex.quote(sys.executable)} -P -m limbstream.cli"
    relative = os.path.relpath(script)
    return shlex.quote(relative if not relative.startswith("..") else str(script))


def client_commands(args: argparse.Namespace) -> list[str]:
    """Ready-to-paste commands of clients of this system (:func:`typed_command`; with ``--connect``
    unless they would find its router by default)."""
    subject = "s01" if args.subjects != 0 else args.slimevr_subject  # None: the source's default, >= 1
    default = os.environ.get(zconfig.ROUTER_ENV, zconfig.DEFAULT_ROUTER)
    connect = "" if args.router == default else f" --connect {args.router}"
    command = typed_command()
    return [f"{command} watch {subject}{connect}", f"{command} record session.mcap --duration 60{connect}",
            f"{command} calibrate {subject} --pose rest{connect}"]


def running(devices: list[tuple[str, ...]], args: argparse.Namespace) -> str:
    """What runs, for the banner: subjects, the devices that really run (a built-in layout's by
    its name, others by their segments), source."""
    subjects = f"{len(devices)} subject{'s' if len(devices) != 1 else ''}"
    if len(set(devices)) == 1:
        what = f"{subjects} x {len(devices[0])} devices"
        named = [name for name, layout in LAYOUTS.items() if set(devices[0]) == set(layout.segment_names)]
        what += f" (layout {named[0]})" if named else f" ({', '.join(devices[0])})"
    else:
        what = f"{subjects}, {sum(len(d) for d in devices)} devices"
    if args.slimevr is not None:
        what += " and the SlimeVR trackers"
    return f"{what}, source {args.source}"


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
    """Check, start, supervise, stop. Ctrl-C (or SIGTERM once started) at any moment: the parts
    started so far are stopped, ``limbstream up: stopped``; exit status 0 once everything ran,
    130 when the start was cut short, 2 for a bad flag or source, 1 when a part cannot start."""
    try:
        if args.source != "generator":
            progress(f"loading {args.source}")
        devices = check(args)
        if (note := flags.no_root_note(subject_layouts(args, devices))) is not None:
            progress(note)
    except (ValueError, argparse.ArgumentTypeError) as exc:  # MotionFileError is a ValueError
        print(f"limbstream up: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("limbstream up: stopped", flush=True)
        return 130
    # from here on Ctrl-C or SIGTERM set stop: the start ends at its next step, a running system at once
    stop = stop_on_signals(stop)
    temp = None
    if args.status_file is None:
        temp = Path(tempfile.mkdtemp(prefix="limbstream-up-"))
        args.status_file = temp / "status.json"
    status_file = args.status_file.resolve()
    launcher = Launcher()
    supervisor = Supervisor(launcher.children, RestartPolicy(max_exits=args.max_exits), report=say)
    dashboard = not args.no_dashboard and importlib.util.find_spec("limbstream.services.dashboard.main") is not None
    launcher.abort = stop
    try:
        try:
            dashboard_vars = start(args, launcher, supervisor, status_file, dashboard)
        except ChildExited as exc:
            say(f"{exc.child.name} failed to start ({exc.child.exit_text()}): {exc.child.last_line()}")
            return 1
        except PortTaken as exc:
            say(str(exc))
            return 1
        except TimeoutError:
            late = launcher.children[-1]
            say(f"{late.name} did not come up within "
                f"{ROUTER_TIMEOUT_S if late.name == 'router' else DASHBOARD_TIMEOUT_S:g} s: {late.last_line()}")
            return 1
        if stop.is_set():
            raise KeyboardInterrupt
        write_status(status_file, "running", supervisor)
        banner(args, launcher, devices, dashboard_vars if dashboard else None, status_file)
        print("\nCtrl-C stops everything.\n", flush=True)
        return supervise(supervisor, status_file, stop)
    except KeyboardInterrupt:
        return 130
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):  # stopping: not interrupted again
            signal.signal(sig, signal.SIG_IGN)
        launcher.stop()
        if temp is not None:  # the status file and what the parts kept beside it (calibrations)
            shutil.rmtree(temp, ignore_errors=True)
        elif status_file.exists():
            write_status(status_file, "stopped", supervisor)
        print("limbstream up: stopped", flush=True)
