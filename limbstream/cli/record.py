"""``limbstream record OUT.mcap``: write what crosses the router (segment points, truth batches,
pose frames, stats, device config changes) to an MCAP file until Ctrl-C or ``--duration``
(services/outputs/record.py; the file's layout: docs/outputs.md)."""
from __future__ import annotations

import argparse
import socket
import sys
import threading

from limbstream import wire
from limbstream.cli import zenoh_args
from limbstream.signals import stop_on_signals
from limbstream.services.outputs.record import Recorder, summary_line
from limbstream.services.outputs.recording import RecordingError, RecordingWriter
from limbstream.services.outputs.subscription import open_session

PROG = "limbstream record"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", metavar="OUT.mcap", help="the recording to write (replaced if it exists)")
    parser.add_argument("--subjects", default="*",
                        help="subject pattern to record: '*' (default, all), a name, or a name with '*' inside")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")
    parser.add_argument("--truth", action=argparse.BooleanOptionalAction, default=True,
                        help="record the devices' truth-tap batches (default: yes)")
    parser.add_argument("--history", type=int, default=512,
                        help="segment points per device asked for from the devices' caches when starting (default 512)")
    parser.add_argument("--config-poll", type=float, default=5.0,
                        help="ask devices for their settings every this many s, record changes (0: never; default 5)")
    parser.add_argument("--no-skeleton", dest="skeleton", action="store_false",
                        help="do not write the Foxglove skeleton channel")
    zenoh_args.add_arguments(parser)


def fail(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    try:
        wire.subject_pattern(args.subjects)
    except ValueError as exc:
        return fail(f"--subjects: {exc}")
    if args.duration is not None and not args.duration > 0:
        return fail(f"--duration must be > 0, got {args.duration:g}")
    if args.history < 1 or args.config_poll < 0:
        return fail("--history must be >= 1 and --config-poll >= 0")
    settings = zenoh_args.from_args(args)
    metadata = {"subjects": args.subjects, "truth": str(args.truth).lower(), "host": socket.gethostname(),
                "connect": ",".join(settings.connect)}
    try:
        writer = RecordingWriter(args.out, metadata, skeleton=args.skeleton)
    except RecordingError as exc:
        return fail(str(exc))
    stop = stop_on_signals(stop)
    try:
        zenoh_args.announce(PROG, settings)
        session = open_session(settings, stop)
    except ValueError as exc:
        writer.discard()
        return fail(str(exc))
    except BaseException:  # no router in time (zconfig.ConnectError), Ctrl-C: no file is left
        writer.discard()
        raise
    if session is None:  # stopped while waiting for the router
        writer.discard()
        return 0
    tty = sys.stderr.isatty()

    def show(line: str) -> None:
        print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)

    with session:
        recorder = Recorder(session, writer, args.subjects, args.truth, args.history, args.config_poll)
        print(f"recording subjects {args.subjects!r} to {args.out} (Ctrl-C stops)", flush=True)
        try:
            recorder.run(stop, args.duration, show, progress_s=1.0 if tty else 5.0)
        finally:
            recorder.close()
    if tty:
        print(file=sys.stderr)
    print(recorder.progress(), flush=True)
    print(summary_line(recorder.summary()), flush=True)
    return 0
