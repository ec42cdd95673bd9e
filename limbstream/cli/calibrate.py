"""``limbstream calibrate s01 --pose rest [--countdown 3]``: calibrate a subject's devices from the
pose it holds (docs/evaluation.md, "Calibration"); the aggregator serving the subject answers.
A refusal because the subject is not still is asked again, until it holds still or ``--wait``
seconds passed (the built-in motion stands still in the rest pose about every 30 s)."""
from __future__ import annotations

import argparse
import sys
import time

import zenoh

from limbstream import wire, zconfig
from limbstream.cli import flags

PROG = "limbstream calibrate"
NOT_STILL = "not still"
"""What the aggregator's refusal says when the subject moved during the hold (calibration.still_mean)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("subject", help="the subject, e.g. s01")
    parser.add_argument("--pose", choices=wire.CALIBRATION_POSES, required=True,
                        help="rest: full reset in the rest pose; mounting: the mounting pose, after rest; "
                             "yaw: heading only, in the rest pose")
    parser.add_argument("--countdown", type=float, default=0.0, metavar="S",
                        help="count down this many seconds first, to get into the pose (default 0)")
    parser.add_argument("--wait", type=float, default=45.0, metavar="S",
                        help="while the subject is not still, ask again for up to this many seconds (default 45: "
                             "the built-in motion stands still about every 30 s; 0: ask once)")
    flags.add_zenoh(parser)


def answers(replies, poll_s: float = 0.05) -> list:
    """Every reply of a query, taken without blocking in Zenoh (so that Ctrl-C stops the wait)."""
    got: list = []
    while True:
        try:
            reply = replies.try_recv()
        except zenoh.ZError:  # the query is over: "channel is empty and closed"
            return got
        if reply is None:
            time.sleep(poll_s)
        else:
            got.append(reply)


def _not_still(replies: list) -> bool:
    """The answer is a refusal because the subject moved during the hold."""
    if not replies or replies[0].ok is None:
        return False
    try:
        answer = wire.decode_calibrate_answer(replies[0].ok.payload.to_bytes())
    except wire.WireError:
        return False  # (said by run)
    return not answer.ok and NOT_STILL in (answer.reason or "")


def ask_until_still(session, key: str, args: argparse.Namespace) -> list:
    """The replies of the calibration request, asked again while the subject is not still, for up
    to ``args.wait`` seconds (said once, on the first such refusal)."""
    until = time.monotonic() + args.wait
    told = False
    while True:
        replies = answers(session.get(key, payload=wire.encode_calibrate_request(args.pose),
                                      timeout=wire.CALIBRATION_ANSWER_TIMEOUT_S))
        if not _not_still(replies) or time.monotonic() >= until:
            return replies
        if not told:
            print(f"not still yet: asking again until the subject holds the {args.pose} pose still "
                  f"(up to {args.wait:g} s)", flush=True)
            told = True


def run(args: argparse.Namespace) -> int:
    try:
        key = wire.calibrate_key(args.subject)
    except ValueError as exc:
        print(f"limbstream calibrate: error: {exc}", file=sys.stderr)
        return 2
    if not args.wait >= 0:
        print(f"limbstream calibrate: error: --wait must be >= 0, got {args.wait}", file=sys.stderr)
        return 2
    if not args.countdown >= 0:
        print(f"limbstream calibrate: error: --countdown must be >= 0, got {args.countdown}", file=sys.stderr)
        return 2
    session = zconfig.open_session(flags.session_settings(args, PROG))
    if session is None:  # (only with a stop event)
        return 0
    try:
        for left in range(int(round(args.countdown)), 0, -1):
            print(f"hold the {args.pose} pose in {left} ...", flush=True)
            time.sleep(1.0)
        print(f"hold the {args.pose} pose still for {wire.CALIBRATION_HOLD_S:g} s", flush=True)
        replies = ask_until_still(session, key, args)
    finally:
        session.close()
    if not replies:
        print(f"limbstream calibrate: error: no aggregator serving {args.subject} answered", file=sys.stderr)
        return 1
    reply = replies[0]
    if reply.ok is None:
        error = reply.err.payload.to_string() if reply.err is not None else "no answer"
        print(f"limbstream calibrate: error: {error}", file=sys.stderr)
        return 1
    answer = wire.decode_calibrate_answer(reply.ok.payload.to_bytes())
    if not answer.ok:
        print(f"limbstream calibrate: refused: {answer.reason}", file=sys.stderr)
        return 1
    print(f"{args.subject}: {len(answer.devices)} devices calibrated ({args.pose})"
          + (f"; no device on {', '.join(answer.absent)} (not calibrated)" if answer.absent else ""))
    for device, info in sorted(answer.devices.items()):
        print(f"  {device}: {'+'.join(info.get('poses', []))}, heading {info.get('heading_deg')} deg")
    return 0
