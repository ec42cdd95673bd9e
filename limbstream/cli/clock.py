"""``limbstream clock``: the flags of the time service the devices synchronise to (the part:
:mod:`limbstream.services.clock.main`)."""
from __future__ import annotations

import argparse
import logging
import threading

from limbstream.cli import zenoh_args
from limbstream.services.clock import main as clock
from limbstream.services.clock.service import ClockServiceSettings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--speed", type=float, default=1.0,
                        help="time scale of the served time, as the emulators' --speed (default 1)")
    parser.add_argument("--time-anchor", type=float, default=None, metavar="EPOCH_S",
                        help="with --speed != 1: the instant (Unix seconds) the scaled time agrees with the host "
                             "clock; the emulators need the same (default: the start)")
    test = parser.add_argument_group("testing (the exchange path and the service clock)")
    test.add_argument("--sync-delay-ms", type=float, default=0.0,
                      help="delay each direction of every exchange by this much, wall ms (default 0)")
    test.add_argument("--sync-jitter-ms", type=float, default=0.0,
                      help="... plus uniform +- this much, drawn per direction and query (default 0)")
    test.add_argument("--jump-ms", type=float, default=0.0, help="the served clock jumps by this much once")
    test.add_argument("--jump-after-s", type=float, default=0.0, help="... this many wall seconds after the start")
    parser.add_argument("-v", "--verbose", action="store_true")
    zenoh_args.add_arguments(parser)


def settings_from_args(args: argparse.Namespace) -> ClockServiceSettings:
    checks = [
        (args.speed > 0, f"--speed must be > 0, got {args.speed}"),
        (args.sync_delay_ms >= 0, f"--sync-delay-ms must be >= 0, got {args.sync_delay_ms}"),
        (args.sync_jitter_ms >= 0, f"--sync-jitter-ms must be >= 0, got {args.sync_jitter_ms}"),
        (args.jump_after_s >= 0, f"--jump-after-s must be >= 0, got {args.jump_after_s}"),
    ]
    for ok, message in checks:
        if not ok:
            raise SystemExit(f"limbstream clock: error: {message}")
    return ClockServiceSettings(speed=args.speed, anchor_us=None if args.time_anchor is None else args.time_anchor * 1e6,
                                delay_ms=args.sync_delay_ms, jitter_ms=args.sync_jitter_ms, jump_ms=args.jump_ms,
                                jump_after_s=args.jump_after_s)


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(message)s")
    settings = settings_from_args(args)
    return clock.run(settings, zenoh_args.session_settings(args, "limbstream clock"), stop)
