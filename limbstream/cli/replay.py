"""``limbstream replay IN.mcap``: publish a recording's devices again — segment points and truth
batches at the recorded times scaled by ``--speed`` — for an aggregator to rebuild the same
frames (services/outputs/replay.py)."""
from __future__ import annotations

import argparse
import sys
import threading

from limbstream import wire
from limbstream.cli import zenoh_args
from limbstream.signals import stop_on_signals
from limbstream.services.outputs.recording import Recording, RecordingError
from limbstream.services.outputs.replay import Replayer, ReplaySettings
from limbstream.services.outputs.subscription import open_session

PROG = "limbstream replay"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="IN.mcap", help="a recording of limbstream record")
    parser.add_argument("--speed", type=float, default=1.0, help="time scale (default 1 = as recorded; 20 = 20x faster)")
    parser.add_argument("--loop", action="store_true",
                        help="start again at the end, each pass a new stream of every device (until Ctrl-C)")
    parser.add_argument("--subject-prefix", default="",
                        help="put this before every subject name (e.g. 'r-': s01 -> r-s01), to replay beside live subjects")
    parser.add_argument("--truth", action=argparse.BooleanOptionalAction, default=True,
                        help="publish the recorded truth batches too (default: yes)")
    parser.add_argument("--hold", type=float, default=2.0,
                        help="keep the devices online this many s after the last message (default 2)")
    zenoh_args.add_arguments(parser)


def fail(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    if not args.speed > 0:
        return fail(f"--speed must be > 0, got {args.speed:g}")
    if not args.hold >= 0:
        return fail(f"--hold must be >= 0, got {args.hold:g}")
    try:
        wire.check_chunk(args.subject_prefix + "s", "--subject-prefix (+ a subject)")
    except ValueError as exc:
        return fail(str(exc))
    try:
        recording = Recording(args.recording)
        recording.check()
    except RecordingError as exc:
        return fail(str(exc))
    stop = stop_on_signals(stop)
    try:
        session = open_session(zenoh_args.session_settings(args, PROG), stop)
    except ValueError as exc:
        return fail(str(exc))
    if session is None:
        return 0
    settings = ReplaySettings(speed=args.speed, loop=args.loop, subject_prefix=args.subject_prefix,
                              truth=args.truth, hold_s=args.hold)
    with session:
        replayer = Replayer(session, recording, settings)
        print(f"replaying {args.recording} at x{args.speed:g}{' in a loop' if args.loop else ''}", flush=True)
        try:
            stats = replayer.run(stop, lambda line: print(line, flush=True))
        except RecordingError as exc:
            replayer.close()
            return fail(str(exc))
    if recording.truncated:
        print(f"{PROG}: warning: {args.recording}: {recording.truncated}; replayed what it holds", file=sys.stderr)
    bad = {**stats.undecodable, **{f"{k}_key": n for k, n in stats.skipped.items()}}
    print(f"replay: {sum(stats.published.values())} messages ({dict(stats.published)}) of {len(replayer.devices)} "
          f"devices, {stats.recorded_s:.1f} s recorded, {stats.passes} pass(es)"
          + (f"; refused by the contract: {bad}" if bad else ""), flush=True)
    return 0
