"""``limbstream gateway slimevr``: SlimeVR trackers in, limbstream devices out (the part:
:mod:`limbstream.services.gateway.slimevr`; docs/protocol.md, "SlimeVR gateway")."""
from __future__ import annotations

import argparse
import json
import logging
import socket
import threading

from limbstream import wire, zconfig
from limbstream.cli import flags
from limbstream.device.clocks import ClockSettings
from limbstream.device.host import HostSettings
from limbstream.services.gateway import slimevr_protocol as proto
from limbstream.signals import stop_on_signals

HELP = "SlimeVR trackers (UDP, port 6969) as limbstream devices"


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (or ``PORT``) -> (host, port); argparse.ArgumentTypeError otherwise."""
    host, sep, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT with a port in 0..65535, got {text!r}")
    return (host.strip("[]") or "0.0.0.0") if sep else "0.0.0.0", number


def parse_assign(text: str) -> tuple[tuple[str, int | None], tuple[str | None, str]]:
    """``TRACKER[/SENSOR]=[SUBJECT/]SEGMENT`` -> ((tracker, sensor or None), (subject or None, segment))."""
    left, sep, right = text.partition("=")
    tracker, slash, sensor = left.rpartition("/") if "/" in left else (left, "", "")
    subject, _, segment = right.rpartition("/")
    try:
        number = int(sensor) if slash else None
        if not sep or not tracker or (number is not None and not 0 <= number <= 255):
            raise ValueError
        if segment not in wire.builtin_segments():
            raise argparse.ArgumentTypeError(f"--assign {text!r}: segment must be one of "
                                             f"{', '.join(wire.builtin_segments())}")
        if subject:
            wire.check_chunk(subject, "subject")
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--assign expects TRACKER[/SENSOR]=[SUBJECT/]SEGMENT (TRACKER: MAC AA:BB:CC:DD:EE:FF or ip:port, "
            f"SENSOR 0..255), got {text!r}") from None
    return (tracker.upper() if tracker.count(":") == 5 else tracker, number), (subject or None, segment)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--udp", type=parse_address, default=("0.0.0.0", proto.PORT), metavar="HOST:PORT",
                        help=f"where trackers send (default 0.0.0.0:{proto.PORT}, the port they look for)")
    parser.add_argument("--subject", type=lambda s: wire.check_chunk(s, "subject"), default="s01",
                        help="subject of the trackers (default s01)")
    parser.add_argument("--name", type=lambda s: wire.check_chunk(s, "gateway name"), default="slimevr",
                        help="the gateway's name: its sensors are listed and assigned at run time on "
                             "limbstream/@gateway/NAME (default slimevr)")
    parser.add_argument("--assign", type=parse_assign, action="append", default=[],
                        metavar="TRACKER[/SENSOR]=[SUBJECT/]SEGMENT",
                        help="the segment of a tracker's sensor (every sensor without /SENSOR); overrides the "
                             "body position it reports; repeatable")
    parser.add_argument("--assignments-file", metavar="PATH",
                        help="keep the assignments made at run time (dashboard, REST) in this JSON file: "
                             "loaded at start, over --assign; rewritten after each change")
    parser.add_argument("--rate", type=float, default=wire.DEVICE_RATE_HZ,
                        help=f"device sample rate, Hz (default {wire.DEVICE_RATE_HZ:g})")
    parser.add_argument("--delay-ms", type=float, default=30.0,
                        help="grid samples are taken this long in the past (default 30 ms)")
    flags.add_device_config(parser, defaults=wire.LIVE_MODE)  # live mode, as under limbstream up
    parser.add_argument("--no-truth", dest="truth", action="store_false",
                        help="do not publish the truth tap (every tracker packet)")
    parser.add_argument("--raw-batch", type=int, default=25, help="samples per truth-tap message (default 25)")
    parser.add_argument("--cache", type=int, default=512, help="segment points kept per device for recovery")
    parser.add_argument("--timeout", type=float, default=proto.TRACKER_TIMEOUT_S,
                        help=f"a tracker silent this long goes offline, s (default {proto.TRACKER_TIMEOUT_S:g})")
    parser.add_argument("--max-devices", type=int, default=256, help="devices served at most (default 256)")
    parser.add_argument("--report-s", type=float, default=10.0,
                        help="print the trackers, unassigned sensors and drops this often, s (default 10)")
    group = parser.add_argument_group("time sync (docs/reliability.md)")
    group.add_argument("--no-sync", dest="sync", action="store_false",
                       help="stamp with the gateway's own clock (no time service)")
    group.add_argument("--sync-wait-s", type=float, default=10.0,
                       help="at start, wait at most this long for the first time answers (default 10)")
    flags.add_layout(parser, "the wearer's body layout (docs/body.md): a sensor feeds the segment of it that its "
                             "SlimeVR body position names (docs/protocol.md, \"SlimeVR gateway\"): full (default: "
                             "pelvis, chest, head, arms, hands, legs and feet), paper10 (no chest, hands or feet) or a "
                             ".toml/.json layout file; the devices announce it with the body of --height-m/--body, or "
                             "its default body")
    flags.add_body(parser, "of the trackers' wearer (default: the default adult of about 1.75 m)")
    parser.add_argument("-v", "--verbose", action="store_true")
    flags.add_zenoh(parser)


def validate(args: argparse.Namespace) -> None:
    checks = [
        (args.rate > 0, f"--rate must be > 0, got {args.rate}"),
        (0 <= args.delay_ms <= 1000, f"--delay-ms must be in 0..1000, got {args.delay_ms}"),
        (1 <= args.raw_batch <= wire.MAX_RAW_BATCH, f"--raw-batch must be in 1..{wire.MAX_RAW_BATCH}"),
        (args.cache >= 1, f"--cache must be >= 1, got {args.cache}"),
        (args.timeout > 0, f"--timeout must be > 0, got {args.timeout}"),
        (args.max_devices >= 1, f"--max-devices must be >= 1, got {args.max_devices}"),
        (args.report_s > 0, f"--report-s must be > 0, got {args.report_s}"),
    ]
    for ok, message in checks:
        if not ok:
            raise SystemExit(f"limbstream gateway slimevr: error: {message}")
    flags.one_body(args)  # FlagError: one line, exit status 2 (a bad --layout too)


def settings_from_args(args: argparse.Namespace):
    from limbstream.services.gateway.slimevr import GatewaySettings
    assign = {key: (subject or args.subject, segment) for key, (subject, segment) in args.assign}
    host = HostSettings(fs=args.rate, config=flags.device_config(args), truth=args.truth, raw_batch=args.raw_batch,
                        cache=args.cache)
    return GatewaySettings(subject=args.subject, name=args.name, assign=assign, host=host, delay_ms=args.delay_ms,
                           timeout_s=args.timeout, max_devices=args.max_devices,
                           clock=ClockSettings(sync=args.sync, wait_s=max(args.sync_wait_s, 0.0)),
                           assignments_file=args.assignments_file, body=_body(args),
                           layout=flags.layout(args))


def _body(args: argparse.Namespace):
    """The body the gateway's devices announce: ``--height-m``/``--body``'s, else its ``--layout``'s
    default body (``full`` by default; paper10's too, so its layout is announced; a layout file's
    travels whole: :func:`flags.default_body`)."""
    from limbstream.body import PAPER10, Body
    given = flags.one_body(args)
    if given is not None:
        return given
    return Body.default(PAPER10) if flags.layout(args) == PAPER10 else flags.default_body(args)


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    from limbstream.services.gateway.slimevr import SlimeVRGateway
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(message)s")
    validate(args)
    settings = settings_from_args(args)
    sock = socket.socket(socket.AF_INET6 if ":" in args.udp[0] else socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(args.udp)
    except OSError as exc:
        raise SystemExit(f"limbstream gateway slimevr: error: cannot listen on {args.udp[0]}:{args.udp[1]}: "
                         f"{exc.strerror or exc}") from None
    stop = stop_on_signals(stop)
    session = zconfig.open_session(flags.session_settings(args, "limbstream gateway slimevr"), stop)
    if session is None:
        return 0
    with session, sock:
        try:
            gateway = SlimeVRGateway(session, sock, settings)
        except ValueError as exc:  # a bad assignments file
            raise SystemExit(f"limbstream gateway slimevr: error: {exc}") from None
        gateway.declare()
        host, port = sock.getsockname()[:2]
        print(f"slimevr gateway {settings.name} on udp {host}:{port}, subject {settings.subject}, {settings.host.fs:g} Hz, "
              f"{len(settings.assign)} assignments", flush=True)
        gateway.run(stop, on_report=lambda r: print("slimevr " + json.dumps(r, default=str), flush=True),
                    report_s=args.report_s)
        gateway.undeclare()
        print("slimevr final " + json.dumps(gateway.report(), default=str), flush=True)
    return 0
