"""``limbstream emulate``: run emulated IMU devices (subjects x segments) in this process."""
from __future__ import annotations

import argparse
import logging
import os
import re
import socket
import threading

from device_emulator.emulator import Emulator, EmulatorSettings
from device_emulator.feeds import GeneratorFeed, LoopFeed
from limbstream.signals import stop_on_signals
from limbstream import wire, zconfig
from limbstream.sources import MotionFileError, load


def host_prefix(hostname: str | None = None) -> str:
    """``<hostname>-s``: a subject prefix unique per container (replicas get distinct hostnames).

    The hostname comes from ``$HOSTNAME`` (set by Docker to the container's) or the system;
    characters not allowed in a key chunk become ``-``.
    """
    hostname = hostname or os.environ.get("HOSTNAME") or socket.gethostname()
    return re.sub(r"[^A-Za-z0-9_.\-]", "-", hostname) + "-s"


def subject_names(count: int, first: int = 1, prefix: str = "s") -> list[str]:
    """``s01, s02, ...`` (valid key chunks); prefix ``auto`` is :func:`host_prefix`."""
    prefix = host_prefix() if prefix == "auto" else prefix
    return [wire.check_chunk(f"{prefix}{k:02d}", "subject") for k in range(first, first + count)]


def build_feeds(args: argparse.Namespace) -> dict:
    """{subject: feed} from --source: the generator (seed = subject number) or a motion file."""
    names = subject_names(args.subjects, args.first_subject, args.subject_prefix)
    if args.source == "generator":
        return {name: GeneratorFeed(seed=args.seed + args.first_subject + i, fs=args.rate, noise_deg=args.noise_deg)
                for i, name in enumerate(names)}
    motions = load(args.source)
    return {name: LoopFeed(motions[i % len(motions)], args.rate, once=args.once) for i, name in enumerate(names)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    env = os.environ.get
    parser.add_argument("--subjects", type=int, default=env("LIMBSTREAM_SUBJECTS", "2"),
                        help="number of subjects (10 IMUs each; env LIMBSTREAM_SUBJECTS, default 2)")
    parser.add_argument("--first-subject", type=int, default=1, help="number of the first subject (s01 = 1)")
    parser.add_argument("--subject-prefix", default=env("LIMBSTREAM_SUBJECT_PREFIX", "s"),
                        help="subject name prefix (env LIMBSTREAM_SUBJECT_PREFIX; default s: s01, s02, ...); "
                             "'auto' = '<hostname>-s', distinct for each scaled container")
    parser.add_argument("--source", default=env("LIMBSTREAM_SOURCE", "generator"),
                        help="'generator' (built-in, default) or a motion file/folder (.npz, .bvh, .csv, .txt) "
                             "(env LIMBSTREAM_SOURCE)")
    parser.add_argument("--once", action="store_true", help="play a file source once, then flush and idle")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds of device time")
    parser.add_argument("--rate", type=float, default=50.0, help="device sample rate, Hz (default 50)")
    parser.add_argument("--speed", type=float, default=1.0, help="time scale (default 1 = real time)")
    wire.add_arguments(parser)  # --threshold, --max-len: the device tunables
    parser.add_argument("--no-truth", dest="truth", action="store_false", help="do not publish the truth tap")
    parser.add_argument("--raw-batch", type=int, default=25, help="samples per truth-tap message (default 25)")
    parser.add_argument("--cache", type=int, default=512, help="segment points kept per device for recovery")
    parser.add_argument("--seed", type=int, default=0, help="generator seed offset")
    parser.add_argument("--noise-deg", type=float, default=0.0, help="generator sensor noise, RMS degrees")
    parser.add_argument("-v", "--verbose", action="store_true")
    zconfig.add_arguments(parser)


def validate(args: argparse.Namespace) -> None:
    """Clear errors for bad flag values (SystemExit with a message)."""
    checks = [
        (args.subjects >= 1, f"--subjects must be >= 1, got {args.subjects}"),
        (args.rate > 0, f"--rate must be > 0, got {args.rate}"),
        (args.speed > 0, f"--speed must be > 0, got {args.speed}"),
        (1 <= args.raw_batch <= wire.MAX_RAW_BATCH, f"--raw-batch must be in 1..{wire.MAX_RAW_BATCH}"),
        (args.cache >= 1, f"--cache must be >= 1, got {args.cache}"),
    ]
    for ok, message in checks:
        if not ok:
            raise SystemExit(f"limbstream emulate: error: {message}")


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(message)s")
    validate(args)
    try:
        feeds = build_feeds(args)
    except (MotionFileError, ValueError) as exc:
        raise SystemExit(f"limbstream emulate: error: {exc}") from None
    settings = EmulatorSettings(fs=args.rate, speed=args.speed, config=wire.config_from_args(args),
                                truth=args.truth, raw_batch=args.raw_batch, cache=args.cache)
    stop = stop_on_signals(stop)
    session = zconfig.open_session(zconfig.from_args(args), stop)
    if session is None:  # stopped while waiting for the router
        return 0
    with session:
        emulator = Emulator(session, feeds, settings)
        emulator.declare()
        print(f"emulating {len(emulator.devices)} devices of {len(feeds)} subjects "
              f"({', '.join(feeds)}) at {args.rate:g} Hz x{args.speed:g}", flush=True)
        ticks = emulator.run(stop, args.duration)
        emulator.undeclare()
    late = 100.0 * ticks.late / max(ticks.ticks, 1)
    print(f"emulator: {ticks.ticks} ticks, {late:.2f} % late, busy {ticks.busy_s:.1f} s", flush=True)
    return 0
