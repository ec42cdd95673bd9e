"""``limbstream watch <subject>``: a live text view of a subject's pose stream, straight from
Zenoh through the outputs' subscription (:mod:`limbstream.services.outputs.subscription`, which also
holds :func:`subscribe_pose` for Python programs). It shows live frames (``--kind live``, the
default: the aggregator's frames at the devices' "now"), exact frames (``--kind exact``: final,
behind by up to the max segment length) or both (``--kind any``); the header line names the
kind of the frame shown. A frame flagged MISSING says which segments have no data and why (no
device, or its device offline), from the subject's stats."""
from __future__ import annotations

import argparse
import sys
import time

from limbstream import quat, wire, zconfig
from limbstream.cli import zenoh_args
from limbstream.sources import SEGMENTS
from limbstream.services.outputs.subscription import Subscription, subscribe_pose  # noqa: F401  (re-exported)

KINDS = {"any": None, "exact": wire.KIND_EXACT, "live": wire.KIND_LIVE}
SHOWN_JOINTS = ("head", "l_wrist", "r_wrist", "l_ankle", "r_ankle")


def why_missing(devices: dict[str, bool] | None) -> str:
    """Which segments have no data and why, from the subject's devices ({segment: online}; None:
    no stats yet)."""
    if devices is None:
        return "(no stats yet)"
    absent = [s for s in SEGMENTS if s not in devices]
    offline = [s for s in SEGMENTS if devices.get(s) is False]
    parts = ([f"no device: {', '.join(absent)}"] if absent else []) + ([f"offline: {', '.join(offline)}"]
                                                                      if offline else [])
    return f"({'; '.join(parts)})" if parts else ""


def render(subject: str, frame: wire.PoseFrame, rate_hz: float, devices: dict[str, bool] | None = None) -> str:
    """A few lines describing ``frame``: header, segment rotation angles, key joint positions;
    ``devices`` ({segment: online}, the subject's stats) say why a segment is missing."""
    flags = [name for bit, name in ((wire.FRAME_GAP, "GAP"), (wire.FRAME_MISSING, "MISSING"))
             if frame.flags & bit]
    if frame.flags & wire.FRAME_MISSING:
        flags.append(why_missing(devices))
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
    parser.add_argument("--kind", choices=tuple(KINDS), default="live",
                        help="which frames to show: live (default; at the devices' now), exact (final, "
                             "behind by up to the max segment length) or any")
    parser.add_argument("--refresh", type=float, default=5.0, help="screen updates per second (default 5)")
    parser.add_argument("--count", type=int, default=0, help="exit after this many frames (0: run until Ctrl-C)")
    parser.add_argument("--timeout", type=float, default=0.0,
                        help="exit with status 1 if the router does not answer or no frame arrives for this many "
                             f"seconds (0: wait for frames forever, for the router {zconfig.CONNECT_TIMEOUT_S:g} s)")
    zenoh_args.add_arguments(parser, timeout=False)


def run(args: argparse.Namespace) -> int:
    try:
        wire.check_chunk(args.subject, "subject")
    except ValueError as exc:
        raise SystemExit(f"limbstream watch: {exc}") from None
    if args.refresh <= 0:
        raise SystemExit("limbstream watch: --refresh must be > 0")
    wanted = KINDS[args.kind]
    tty = sys.stdout.isatty()
    count, last_count, last_time, last_seen = 0, 0, time.monotonic(), time.monotonic()
    if not args.timeout >= 0:
        raise SystemExit("limbstream watch: --timeout must be >= 0")
    settings = zenoh_args.session_settings(args, "limbstream watch", args.timeout or zconfig.CONNECT_TIMEOUT_S)
    devices = None  # {segment: online}, from the newest stats
    with Subscription(settings, args.subject, ("pose", "stats")) as sub:
        while True:
            frame = None
            first = sub.get(timeout=1.0 / args.refresh)
            for item in ([first] if first is not None else []) + sub.drain():  # keep the newest
                if item.kind == "stats":
                    devices = {d["segment"]: bool(d["online"]) for d in item.value["devices"]}
                elif wanted is None or item.value.kind == wanted:
                    frame, count = item.value, count + 1
            now = time.monotonic()
            if frame is None:
                if args.timeout and now - last_seen > args.timeout:
                    print(f"limbstream watch: no {args.kind} frame of {args.subject} for {args.timeout:g} s",
                          file=sys.stderr)
                    return 1
                continue
            last_seen = now
            rate = (count - last_count) / max(now - last_time, 1e-6)
            last_count, last_time = count, now
            print(("\x1b[H\x1b[2J" if tty else "") + render(args.subject, frame, rate, devices), flush=True)
            if args.count and count >= args.count:
                return 0
            time.sleep(max(0.0, 1.0 / args.refresh - (time.monotonic() - now)))
