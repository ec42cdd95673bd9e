"""``limbstream foxglove``: the live pose and stats for the Foxglove app over its WebSocket
protocol (:mod:`limbstream.services.outputs.foxglove`, docs/outputs.md)."""
from __future__ import annotations

import argparse
import sys

from limbstream import wire, zconfig
from limbstream.cli import flags
from limbstream.signals import stop_on_signals
from limbstream.services.outputs.foxglove import FoxgloveOutput
from limbstream.services.outputs.subscription import Subscription


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--subjects", default="*", help="subject pattern: *, s01, s0* (default *)")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765; 0: a free one)")
    flags.add_zenoh(parser)


def _error(message: str) -> int:
    print(f"limbstream foxglove: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    try:
        wire.subject_pattern(args.subjects)
    except ValueError as exc:
        return _error(f"--subjects {args.subjects}: {exc}")
    if not 0 <= args.port < 65536:
        return _error(f"--port must be in 0..65535, got {args.port}")
    settings = flags.zenoh_settings(args)
    try:
        output = FoxgloveOutput(args.host, args.port)
    except OSError as exc:
        return _error(f"--port {args.port} on --host {args.host}: {exc}")
    stop = stop_on_signals()
    try:
        print(f"limbstream foxglove: serving ws://{args.host}:{output.port} (subjects {args.subjects})", flush=True)
        flags.announce("limbstream foxglove", settings)
        session = zconfig.open_session(settings, stop)
        if session is None:
            return 130
        with session, Subscription(session, args.subjects, ("pose", "stats"), capacity=1 << 14) as sub:
            print(f"limbstream foxglove: connected; waiting for the pose and stats of subjects {args.subjects}",
                  file=sys.stderr, flush=True)
            while not stop.wait(0.01):
                for item in sub.drain():
                    output.publish(item)
            dropped = sum(sub.errors.values())
    finally:
        output.close()
    print(f"limbstream foxglove: {output.published} messages sent, {dropped} dropped", flush=True)
    return 0
