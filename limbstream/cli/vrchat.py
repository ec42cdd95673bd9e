"""``limbstream vrchat --subject s01 --to 127.0.0.1:9000``: a subject's pose as VRChat's OSC
trackers (:mod:`limbstream.services.outputs.vrchat`, docs/outputs.md "VRChat")."""
from __future__ import annotations

import argparse

from limbstream import wire, zconfig
from limbstream.cli import flags
from limbstream.signals import stop_on_signals
from limbstream.services.outputs import vrchat
from limbstream.services.outputs.subscription import Subscription

DEFAULT_TO = "127.0.0.1:9000"


PROG = "limbstream vrchat"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--subject", required=False, default=None, help="subject to send, e.g. s01")
    parser.add_argument("--to", default=DEFAULT_TO,
                        help=f"HOST:PORT VRChat receives OSC on (default {DEFAULT_TO})")
    parser.add_argument("--wait", type=float, default=30.0,
                        help="exit with an error if the subject sends no pose frame within this many "
                             "seconds (0: wait forever; default 30)")
    flags.add_zenoh(parser)


def _error(message: str) -> int:
    return flags.fail(PROG, message)


def run(args: argparse.Namespace) -> int:
    if not args.subject:
        return _error("--subject is required")
    try:
        wire.check_chunk(args.subject, "subject")
    except ValueError as exc:
        return _error(f"--subject {args.subject}: {exc}")
    try:
        target = vrchat.parse_target(args.to)
    except ValueError as exc:
        return _error(f"--to {args.to}: {exc}")
    if not args.wait >= 0:
        return _error(f"--wait must be >= 0, got {args.wait}")
    settings = flags.session_settings(args, "limbstream vrchat")
    stop = stop_on_signals()
    session = zconfig.open_session(settings, stop)
    if session is None:
        return 130
    sender = vrchat.VrchatSender(args.subject, target)
    sub = None
    try:
        sub = Subscription(session, args.subject, ("pose",), capacity=4096)
        print(f"limbstream vrchat: {args.subject} -> {target[0]}:{target[1]}", flush=True)
        came = vrchat.serve(sender, sub, stop, wait_s=args.wait)
    finally:
        if sub is not None:
            sub.close()
        sender.close()
        session.close()
    if not came:
        return _error(f"--subject {args.subject}: no pose frame in {args.wait:g} s (is it running? "
                      f"limbstream watch {args.subject} --kind auto)")
    c = sender.counters
    dropped = sum(sub.errors.values())
    print(f"limbstream vrchat: {c.sent} frames sent, {c.bad} bad frames, {c.send_errors} send errors, "
          f"{dropped} messages dropped", flush=True)
    return 0
