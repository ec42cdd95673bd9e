"""``limbstream watch <subject>``: a live text view of a subject's pose stream, straight from
Zenoh; and :func:`subscribe_pose`, the same subscription for Python programs."""
from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable
from typing import Self

import zenoh

from limbstream import quat, wire, zconfig
from limbstream.sources import SEGMENTS

KINDS = {"any": None, "exact": wire.KIND_EXACT, "live": wire.KIND_LIVE}
SHOWN_JOINTS = ("head", "l_wrist", "r_wrist", "l_ankle", "r_ankle")


class PoseSubscription:
    """A pose subscription; ``close()`` (or leaving the ``with`` block) undeclares it and closes
    the session if the subscription opened it. ``errors`` counts undecodable frames."""

    def __init__(self, session: zenoh.Session, owns_session: bool):
        self.session = session
        self.owns_session = owns_session
        self.subscriber = None
        self.errors = 0

    def close(self) -> None:
        if self.subscriber is not None:
            self.subscriber.undeclare()
            self.subscriber = None
        if self.owns_session:
            self.session.close()
            self.owns_session = False

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def subscribe_pose(session_or_settings: zenoh.Session | zconfig.ZenohSettings, subject: str,
                   callback: Callable[[str, wire.PoseFrame], None]) -> PoseSubscription:
    """Call ``callback(subject, frame)`` for every pose frame of ``subject`` (or of every subject
    matched when ``subject`` is ``*``).

    Parameters
    ----------
    session_or_settings : an open session (left open by ``close()``) or the settings to open one.
    subject : a subject key chunk, or ``*``.
    callback : runs on a Zenoh thread: keep it short and hand work off (e.g. to a queue).
        Frames that fail to decode are counted in ``errors`` and not passed on.
    """
    if subject != "*":
        wire.check_chunk(subject, "subject")
    if isinstance(session_or_settings, zconfig.ZenohSettings):
        handle = PoseSubscription(zconfig.open_session(session_or_settings), True)
    elif isinstance(session_or_settings, zenoh.Session):
        handle = PoseSubscription(session_or_settings, False)
    else:
        raise TypeError(f"session_or_settings must be a zenoh.Session or ZenohSettings, "
                        f"got {type(session_or_settings).__name__}")

    def on_sample(sample: zenoh.Sample) -> None:
        try:
            name, _ = wire.parse_subject_key(str(sample.key_expr))
            frame = wire.decode_pose(sample.payload.to_bytes())
        except wire.WireError:
            handle.errors += 1
            return
        callback(name, frame)

    handle.subscriber = handle.session.declare_subscriber(wire.subject_selector("pose", subject), on_sample)
    return handle


def render(subject: str, frame: wire.PoseFrame, rate_hz: float) -> str:
    """A few lines describing ``frame``: header, segment rotation angles, key joint positions."""
    flags = [name for bit, name in ((wire.FRAME_GAP, "GAP"), (wire.FRAME_MISSING, "MISSING"))
             if frame.flags & bit]
    kind = "live" if frame.kind == wire.KIND_LIVE else "exact"
    stamp = time.strftime("%H:%M:%S", time.localtime(frame.t_us / 1e6)) + f".{frame.t_us // 1000 % 1000:03d}"
    lines = [f"{subject}  {kind} #{frame.seq}  t={stamp}  {rate_hz:5.1f} frames/s  {' '.join(flags)}".rstrip()]
    identity = [[1.0, 0.0, 0.0, 0.0]] * len(SEGMENTS)
    angles = quat.angle_deg(frame.q.astype(float), identity)
    cells = [f"{name:>11s} {a:6.1f}°" for name, a in zip(SEGMENTS, angles)]
    lines += ["  rotation from rest:"] + ["  " + "  ".join(cells[i:i + 5]) for i in range(0, len(cells), 5)]
    joints = dict(zip(wire.JOINTS, frame.joints.tolist()))
    lines.append("  joints (m, Y up): " + "  ".join(
        f"{j} ({joints[j][0]:+.2f},{joints[j][1]:+.2f},{joints[j][2]:+.2f})" for j in SHOWN_JOINTS))
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("subject", help="subject key chunk, e.g. s01")
    parser.add_argument("--kind", choices=tuple(KINDS), default="exact",
                        help="which frames to show (default exact)")
    parser.add_argument("--refresh", type=float, default=5.0, help="screen updates per second (default 5)")
    parser.add_argument("--count", type=int, default=0, help="exit after this many frames (0: run until Ctrl-C)")
    parser.add_argument("--timeout", type=float, default=0.0,
                        help="exit with status 1 if no frame arrives for this many seconds (0: wait forever)")
    zconfig.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    try:
        wire.check_chunk(args.subject, "subject")
    except ValueError as exc:
        raise SystemExit(f"limbstream watch: {exc}") from None
    if args.refresh <= 0:
        raise SystemExit("limbstream watch: --refresh must be > 0")
    wanted = KINDS[args.kind]
    lock = threading.Lock()
    latest: list = [None, 0]  # frame, frames counted
    arrived = threading.Event()

    def on_frame(_: str, frame: wire.PoseFrame) -> None:
        if wanted is None or frame.kind == wanted:
            with lock:
                latest[0] = frame
                latest[1] += 1
            arrived.set()

    tty = sys.stdout.isatty()
    with subscribe_pose(zconfig.from_args(args), args.subject, on_frame):
        last_count, last_time, last_seen = 0, time.monotonic(), time.monotonic()
        shown = None
        while True:
            arrived.wait(1.0 / args.refresh)
            with lock:
                frame, count = latest
            now = time.monotonic()
            if frame is None or frame is shown:
                if args.timeout and now - last_seen > args.timeout:
                    print(f"limbstream watch: no {args.kind} frame of {args.subject} for {args.timeout:g} s",
                          file=sys.stderr)
                    return 1
                arrived.clear()
                continue
            arrived.clear()
            last_seen = now
            rate = (count - last_count) / max(now - last_time, 1e-6)
            last_count, last_time, shown = count, now, frame
            text = render(args.subject, frame, rate)
            print(("\x1b[H\x1b[2J" if tty else "") + text, flush=True)
            if args.count and count >= args.count:
                return 0
            time.sleep(max(0.0, 1.0 / args.refresh - (time.monotonic() - now)))
