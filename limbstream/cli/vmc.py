"""``limbstream vmc --subject s01 --to 127.0.0.1:39539``: a subject's pose as the VMC protocol
(OSC over UDP) for avatar apps (:mod:`limbstream.services.outputs.vmc`, docs/outputs.md)."""
from __future__ import annotations

import argparse

from limbstream import wire, zconfig
from limbstream.cli import flags
from limbstream.signals import stop_on_signals
from limbstream.services.outputs import vmc
from limbstream.services.outputs.subscription import Subscription


PROG = "limbstream vmc"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--subject", action="append", default=[],
                        help="subject to send, e.g. s01; repeat it with one --to each for several")
    parser.add_argument("--to", action="append", default=[],
                        help="HOST:PORT of the VMC receiver (VSeeFace, Warudo ... listen on 39539)")
    parser.add_argument("--rest-pose", choices=wire.REST_POSES, default=None,
                        help="override the rest pose the pose frames carry in their flags (default: theirs)")
    parser.add_argument("--wait", type=float, default=30.0,
                        help="exit with an error if a subject sends no pose frame within this many "
                             "seconds (0: wait forever; default 30)")
    flags.add_zenoh(parser)


def _error(message: str) -> int:
    return flags.fail(PROG, message)


def run(args: argparse.Namespace) -> int:
    if not args.subject:
        return _error("--subject is required")
    if len(args.to) != len(args.subject):
        return _error(f"--to: give one per --subject ({len(args.subject)} subjects, {len(args.to)} --to)")
    if len(set(args.subject)) != len(args.subject):
        return _error("--subject: each subject once")
    if not args.wait >= 0:
        return _error(f"--wait must be >= 0, got {args.wait}")
    targets = {}
    for subject, to in zip(args.subject, args.to):
        try:
            wire.check_chunk(subject, "subject")
        except ValueError as exc:
            return _error(f"--subject {subject}: {exc}")
        try:
            targets[subject] = vmc.parse_target(to)
        except ValueError as exc:
            return _error(f"--to {to}: {exc}")
    settings = flags.session_settings(args, "limbstream vmc")
    stop = stop_on_signals()
    session = zconfig.open_session(settings, stop)
    if session is None:
        return 130
    sender = vmc.VmcSender(targets, args.rest_pose)
    subs = []
    try:
        subs = [Subscription(session, s, ("pose",), capacity=4096) for s in targets]
        for s, (host, port) in targets.items():
            print(f"limbstream vmc: {s} -> {host}:{port}", flush=True)
        missing = vmc.serve(sender, subs, stop, wait_s=args.wait)
    finally:
        for sub in subs:
            sub.close()
        sender.close()
        session.close()
    if missing is not None:
        return _error(f"--subject {missing}: no pose frame in {args.wait:g} s (is it running? "
                      f"limbstream watch {missing} --kind auto)")
    c = sender.counters
    dropped = sum(sum(sub.errors.values()) for sub in subs)
    print(f"limbstream vmc: {c.sent} bundles sent, {c.bad} bad frames, {c.send_errors} send errors, "
          f"{dropped} messages dropped", flush=True)
    return 0
