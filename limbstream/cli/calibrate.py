"""``limbstream calibrate s01 --pose rest [--countdown 3]``: calibrate a subject's devices from the
pose it holds (docs/evaluation.md, "Calibration"); the aggregator serving the subject answers."""
from __future__ import annotations

import argparse
import sys
import time

import zenoh

from limbstream import wire, zconfig
from limbstream.cli import zenoh_args

PROG = "limbstream calibrate"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("subject", help="the subject, e.g. s01")
    parser.add_argument("--pose", choices=wire.CALIBRATION_POSES, required=True,
                        help="rest: full reset in the rest pose; mounting: the mounting pose, after rest; "
                             "yaw: heading only, in the rest pose")
    parser.add_argument("--countdown", type=float, default=0.0, metavar="S",
                        help="count down this many seconds first, to get into the pose (default 0)")
    zenoh_args.add_arguments(parser)


def answers(replies, poll_s: float = 0.05) -> list:
    """Every reply of a query, taken without blocking in Zenoh (so that Ctrl-C stops the wait)."""
    got = []
    while True:
        try:
            reply = replies.try_recv()
        except zenoh.ZError:  # the query is over: "channel is empty and closed"
            return got
        if reply is None:
            time.sleep(poll_s)
        else:
            got.append(reply)


def run(args: argparse.Namespace) -> int:
    try:
        key = wire.calibrate_key(args.subject)
    except ValueError as exc:
        print(f"limbstream calibrate: error: {exc}", file=sys.stderr)
        return 2
    if not args.countdown >= 0:
        print(f"limbstream calibrate: error: --countdown must be >= 0, got {args.countdown}", file=sys.stderr)
        return 2
    session = zconfig.open_session(zenoh_args.session_settings(args, PROG))
    try:
        for left in range(int(round(args.countdown)), 0, -1):
            print(f"hold the {args.pose} pose in {left} ...", flush=True)
            time.sleep(1.0)
        print(f"hold the {args.pose} pose still for {wire.CALIBRATION_HOLD_S:g} s", flush=True)
        replies = answers(session.get(key, payload=wire.encode_calibrate_request(args.pose),
                                      timeout=wire.CALIBRATION_ANSWER_TIMEOUT_S))
    finally:
        session.close()
    if not replies:
        print(f"limbstream calibrate: error: no aggregator serving {args.subject} answered", file=sys.stderr)
        return 1
    reply = replies[0]
    if reply.ok is None:
        print(f"limbstream calibrate: error: {reply.err.payload.to_string()}", file=sys.stderr)
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
