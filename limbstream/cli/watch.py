"""``limbstream watch <subject>``: a live text view of a subject's pose stream, straight from
Zenoh through the outputs' subscription (:mod:`limbstream.services.outputs.subscription`, which also
holds :func:`subscribe_pose` for Python programs). It shows live frames (``--kind live``, the
default: the aggregator's frames at the devices' "now"), exact frames (``--kind exact``: final,
behind by up to the max segment length) or ``--kind auto`` (live while they come, else exact: the
pose stream API's rule); the header line names the kind of the frame shown. A frame flagged
MISSING says which segments have no data and why (no device, or its device offline), from the
subject's stats. With ``--joints`` the frame's own joint angles follow (paired by seq and time)
(docs/protocol.md, "Joint angles"): a value per angle, ``-`` for one without (its segment missing),
``~`` after one near gimbal lock, or the reason there are none (the subject not calibrated).

A subject without frames (a typo: ``watch s99``) is named after :data:`HINT_S` seconds, with the
subjects that are streaming; ``watch`` then keeps waiting (a subject may start later) until
Ctrl-C, or exits with status 1 after ``--timeout``. ``--timeout 0`` (the default) waits for the
router and the frames however long it takes."""
from __future__ import annotations

import argparse
import collections
import math
import sys
import time

import numpy as np

from limbstream import quat, wire
from limbstream.cli import flags
from limbstream.sources import SEGMENTS
from limbstream.services.outputs.subscription import Subscription, subscribe_pose  # noqa: F401  (re-exported)

KINDS: dict[str, int | None] = {**wire.FRAME_KINDS, wire.AUTO: None}
"""``--kind``: a frame kind, or ``auto`` (the pose stream API's rule: :func:`limbstream.wire.auto_kind`)."""
SHOWN_JOINTS = ("head", "head_top", "l_wrist", "r_wrist", "l_ankle", "r_ankle")
"""The joints shown, those of them the frame's layout has (``paper10``'s top of the head is
``head``, ``full``'s ``head_top``)."""
HINT_S = 3.0
"""Seconds without a frame of the subject after which ``watch`` names the subjects streaming (their
stats come once a second)."""
ASK_STATS_S = 0.3
"""How long ``watch`` waits for the aggregator's answer when it asks which subjects have stats, s
(it answers within a tick)."""
PROG = "limbstream watch"


def why_missing(devices: dict[str, bool] | None, segments: tuple[str, ...] = SEGMENTS) -> str:
    """Which of ``segments`` (the frame's layout's) have no data and why, from the subject's
    devices ({segment: online}; None: no stats yet)."""
    if devices is None:
        return "(no stats yet)"
    absent = [s for s in segments if s not in devices]
    offline = [s for s in segments if devices.get(s) is False]
    parts = ([f"no device: {', '.join(absent)}"] if absent else []) + ([f"offline: {', '.join(offline)}"]
                                                                      if offline else [])
    return f"({'; '.join(parts)})" if parts else ""


def render(subject: str, frame: wire.PoseFrame, rate_hz: float, devices: dict[str, bool] | None = None) -> str:
    """A few lines describing ``frame``: header (with its layout's name), each of its layout's
    segments' rotation angle, key joint positions; ``devices`` ({segment: online}, the subject's
    stats) say why a segment is missing."""
    layout = frame.layout
    segments = tuple(layout.segment_names) if layout is not None else SEGMENTS
    marks = [name for bit, name in ((wire.FRAME_GAP, "GAP"), (wire.FRAME_MISSING, "MISSING"))
             if frame.flags & bit]
    if frame.flags & wire.FRAME_MISSING:
        marks.append(why_missing(devices, segments))
    kind = wire.kind_name(frame.kind)
    stamp = time.strftime("%H:%M:%S", time.localtime(frame.t_us / 1e6)) + f".{frame.t_us // 1000 % 1000:03d}"
    name = layout.name if layout is not None else "paper10"
    lines = [f"{subject}  {kind} #{frame.seq}  t={stamp}  {rate_hz:5.1f} frames/s  {name}  {' '.join(marks)}".rstrip()]
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (len(segments), 1))
    angles = quat.angle_deg(frame.q.astype(float), identity)
    cells = [f"{seg:>11s} {a:6.1f}°" for seg, a in zip(segments, angles)]
    lines += ["  rotation from rest:"] + ["  " + "  ".join(cells[i:i + 5]) for i in range(0, len(cells), 5)]
    joints = dict(zip(layout.joints if layout is not None else wire.JOINTS, frame.joints.tolist()))
    lines.append("  joints (m, Y up): " + "  ".join(
        f"{j} ({joints[j][0]:+.2f},{joints[j][1]:+.2f},{joints[j][2]:+.2f})" for j in SHOWN_JOINTS if j in joints))
    return "\n".join(lines)


def render_angles(angles: wire.JointAngles | None) -> str:
    """The joint angles of a joint-angle message, four to a line, with the calibration they rest on
    (None: none came yet)."""
    if angles is None:
        return "  joint angles: none received yet (an aggregator with --no-joint-angles publishes none)"
    basis = angles.calibration
    if not basis.valid:
        return f"  joint angles: none, calibration {basis.name}: {basis.meaning}"
    facing = f", facing {angles.facing_deg:.1f}°" if math.isfinite(angles.facing_deg) else ""
    cells = []
    for name, value, bits in zip(angles.names, angles.angles.tolist(), angles.flags.tolist()):
        text = "      -" if not math.isfinite(value) else f"{value:6.1f}°"
        cells.append(f"{name:>16s} {text}{'~' if bits & wire.ANGLE_GIMBAL else ' '}")
    lines = [f"  joint angles (deg; calibration {basis.name}{facing}; - no data, ~ near gimbal lock):"]
    return "\n".join(lines + ["  " + " ".join(cells[i:i + 4]) for i in range(0, len(cells), 4)])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("subject", help="subject key chunk, e.g. s01")
    parser.add_argument("--kind", choices=tuple(KINDS), default="live",
                        help="which frames to show: live (default; at the devices' now), exact (final, "
                             "behind by up to the max segment length) or auto (live while they come, else exact)")
    parser.add_argument("--joints", action="store_true",
                        help="also show the subject's joint angles (OpenSim's names, degrees) of the frames of that kind")
    parser.add_argument("--refresh", type=float, default=5.0, help="screen updates per second (default 5)")
    parser.add_argument("--count", type=int, default=0,
                        help="exit after this many frames (with --joints: and a joint-angle message; 0: run until Ctrl-C)")
    parser.add_argument("--timeout", type=float, default=0.0,
                        help="exit with status 1 if the router does not answer or no frame arrives for this many "
                             f"seconds (0, the default: wait for the router and the frames however long it takes; "
                             f"after {HINT_S:g} s without a frame the subjects streaming are named)")
    flags.add_zenoh(parser, timeout=False)


class _Newest:
    """What the screen shows: the newest frame of the kind asked for (``wanted``; None: auto), the
    frames counted, the subject's devices ({segment: online}) from its newest stats, and the joint
    angles of recent frames by the frame they come from (kind, seq, time), so that a frame is
    shown with its own angles (:meth:`paired`)."""

    KEPT = 64  # recent frames and angle messages kept for pairing

    def __init__(self, wanted: int | None):
        self.wanted = wanted
        self.count = 0
        self.devices: dict[str, bool] | None = None
        self.frames: collections.deque[wire.PoseFrame] = collections.deque(maxlen=self.KEPT)
        self.angles: dict[tuple[int, int, int], wire.JointAngles] = {}  # by (kind, seq, t_us) of their frame
        self.last_live = -math.inf  # monotonic time of the newest live frame (auto)

    def take(self, items: list) -> wire.PoseFrame | None:
        """The newest frame to show among ``items`` (None: none), the stats and angles noted."""
        frame = None
        for item in items:
            if item.kind == wire.STATS:
                self.devices = {d["segment"]: bool(d["online"]) for d in item.value["devices"]}
                continue
            if item.kind == wire.ANGLES:
                a = item.value
                self.angles[a.kind, a.seq, a.t_us] = a
                while len(self.angles) > self.KEPT:
                    del self.angles[next(iter(self.angles))]
                continue
            if item.value.kind == wire.KIND_LIVE:
                self.last_live = time.monotonic()
            kind = self.wanted if self.wanted is not None else wire.auto_kind(time.monotonic() - self.last_live)
            if item.value.kind == kind:
                frame, self.count = item.value, self.count + 1
                self.frames.append(frame)
        return frame

    def paired(self) -> tuple[wire.PoseFrame, wire.JointAngles | None]:
        """The newest frame kept whose joint angles came, with them; the newest frame and None if
        none of the frames kept has its angles yet."""
        for frame in reversed(self.frames):
            angles = self.angles.get((frame.kind, frame.seq, frame.t_us))
            if angles is not None:
                return frame, angles
        return self.frames[-1], None


def subjects_with_stats(session, timeout_s: float = ASK_STATS_S) -> set[str]:
    """The subjects whose newest stats message the aggregator holds (its stats queryable's answer
    to ``limbstream/*/stats``; docs/protocol.md, "Stats"): every subject streaming, whether or not
    its stats came while ``watch`` listened. Empty without an answer within ``timeout_s``."""
    subjects = set()
    for reply in session.get(wire.subject_selector(wire.STATS), timeout=timeout_s):
        if reply.ok is not None:
            try:
                subjects.add(wire.parse_subject_key(str(reply.ok.key_expr))[0])
            except wire.WireError:
                continue  # (not a stats key: not an aggregator's answer)
    return subjects


def no_frames(args: argparse.Namespace, seconds: float, streaming: set[str]) -> str:
    """What ``watch`` says when no frame of the subject came for ``seconds``: which subjects do
    stream (their stats came, or the aggregator holds stats of them: :func:`subjects_with_stats`),
    so that a typo shows."""
    what = f"{PROG}: no {args.kind} frame of {args.subject} for {seconds:g} s; "
    if args.subject in streaming:
        return what + f"its stats come, its {args.kind} frames do not (is its aggregator running? try --kind auto)"
    if not streaming:
        return what + "no subject is streaming (is `limbstream up` running?)"
    return what + f"subjects streaming: {', '.join(sorted(streaming))}"


def run(args: argparse.Namespace) -> int:
    try:
        wire.check_chunk(args.subject, "subject")
    except ValueError as exc:
        raise flags.FlagError(str(exc)) from None
    if not args.refresh > 0:
        raise flags.FlagError(f"--refresh must be > 0, got {args.refresh:g}")
    if not args.timeout >= 0 or args.count < 0:
        raise flags.FlagError("--timeout and --count must be >= 0")
    newest = _Newest(KINDS[args.kind])
    tty = sys.stdout.isatty()
    settings = flags.session_settings(args, PROG, args.timeout or None)
    kinds = (wire.POSE, wire.STATS) + ((wire.ANGLES,) if args.joints else ())
    with Subscription(settings, args.subject, kinds) as sub, \
            Subscription(sub.session, "*", (wire.STATS,), capacity=1024) as everyone:
        print(f"{PROG}: waiting for {args.kind} frames of {args.subject}", file=sys.stderr, flush=True)
        last_count, last_time, last_seen = 0, time.monotonic(), time.monotonic()
        streaming: set[str] = set()
        hinted = False
        while True:
            first = sub.get(timeout=1.0 / args.refresh)
            frame = newest.take(([first] if first is not None else []) + sub.drain())  # keep the newest
            streaming.update(item.subject for item in everyone.drain())
            now = time.monotonic()
            if frame is None:
                if args.timeout and now - last_seen > args.timeout:
                    streaming |= subjects_with_stats(sub.session)  # (a stats round may not have come yet)
                    print(no_frames(args, args.timeout, streaming), file=sys.stderr)
                    return 1
                if not hinted and not newest.count and now - last_seen >= HINT_S:
                    streaming |= subjects_with_stats(sub.session)
                    print(no_frames(args, HINT_S, streaming) + "; still waiting (Ctrl-C stops)", file=sys.stderr,
                          flush=True)
                    hinted = True
                continue
            last_seen = now
            rate = (newest.count - last_count) / max(now - last_time, 1e-6)
            last_count, last_time = newest.count, now
            angles = None
            if args.joints:  # the newest frame whose angles came, with its own angles
                frame, angles = newest.paired()
            text = render(args.subject, frame, rate, newest.devices)
            if args.joints:
                text += "\n" + render_angles(angles)
            print(("\x1b[H\x1b[2J" if tty else "") + text, flush=True)
            if args.count and newest.count >= args.count and (angles is not None or not args.joints):
                return 0
            time.sleep(max(0.0, 1.0 / args.refresh - (time.monotonic() - now)))
