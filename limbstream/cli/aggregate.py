"""``limbstream aggregate``: the flags of an aggregator for a set of subjects (the part:
:mod:`limbstream.services.aggregator.main`)."""
from __future__ import annotations

import argparse
import logging
import threading

from limbstream import wire
from limbstream.cli import flags
from limbstream.skeleton import Skeleton
from limbstream.services.aggregator import main as aggregator
from limbstream.services.aggregator.aggregator import AggregatorSettings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--subjects", default="*",
                        help="comma-separated subject key chunks or patterns this instance serves "
                             "(default '*': all; e.g. 's0*' or 's01,s02' to shard)")
    parser.add_argument("--rate", type=float, default=wire.DEVICE_RATE_HZ,
                        help=f"exact frame rate, Hz (default {wire.DEVICE_RATE_HZ:g})")
    parser.add_argument("--live-rate", type=float, default=wire.DEVICE_RATE_HZ,
                        help=f"live frame rate, Hz (0: none; default {wire.DEVICE_RATE_HZ:g}, the devices' rate)")
    parser.add_argument("--tick", type=float, default=0.02, help="loop period, s (default 0.02)")
    parser.add_argument("--frame-batch", type=float, default=0.0,
                        help="build exact frames at most every this many s (0: every tick)")
    parser.add_argument("--history", type=int, default=512, help="segment points per device fetched when joining (default 512)")
    parser.add_argument("--error-window", type=float, default=60.0, help="angular-error window, s (default 60)")
    parser.add_argument("--rest-pose", choices=wire.REST_POSES, default=wire.DEFAULT_REST_POSE,
                        help="rest pose of subjects whose devices do not announce theirs (devices say it in their "
                             "status: standing for the generator and IMU files, tpose for BVH)")
    for bone, default in (("thigh", 0.45), ("shank", 0.43), ("upperarm", 0.30), ("lowerarm", 0.27),
                          ("spine", 0.50), ("neck", 0.22)):
        parser.add_argument(f"--{bone}", type=float, default=default, help=f"{bone} length, m (default {default})")
    parser.add_argument("--calibrate-on-start", action="store_true",
                        help="calibrate each new stream from the calibration script it begins with (devices "
                             "with a sensor model: emulate --mounting-deg ...; docs/evaluation.md, 'Calibration')")
    parser.add_argument("--calibration-file", default="", metavar="PATH",
                        help="keep the devices' calibrations in this JSON file, so that a restarted aggregator "
                             "has them (default: not kept)")
    parser.add_argument("--no-joint-angles", dest="joint_angles", action="store_false",
                        help="do not publish the subjects' joint angles (limbstream/<subject>/angles; "
                             "docs/protocol.md, 'Joint angles')")
    flags.add_heading_correction(parser)
    parser.add_argument("-v", "--verbose", action="store_true")
    flags.add_zenoh(parser)


def settings_from_args(args: argparse.Namespace) -> AggregatorSettings:
    """AggregatorSettings from the flags; SystemExit with a clear message on bad values."""
    try:
        patterns = tuple(p.strip() for p in args.subjects.split(",") if p.strip())
        for p in patterns:
            wire.subject_pattern(p)  # ValueError naming a bad one
        skeleton = Skeleton(thigh=args.thigh, shank=args.shank, upperarm=args.upperarm, lowerarm=args.lowerarm,
                            spine=args.spine, neck=args.neck, rest_pose=args.rest_pose)
        if not (args.rate > 0 and args.tick > 0 and args.live_rate >= 0 and args.history >= 1
                and args.frame_batch >= 0):
            raise ValueError("--rate and --tick must be > 0, --live-rate, --frame-batch >= 0, --history >= 1")
    except ValueError as exc:
        raise SystemExit(f"limbstream aggregate: error: {exc}") from None
    return AggregatorSettings(subjects=patterns or ("*",), rate=args.rate, live_rate=args.live_rate,
                              tick_s=args.tick, history=args.history, error_window_s=args.error_window,
                              frame_batch_s=args.frame_batch, calibrate_on_start=args.calibrate_on_start,
                              calibration_file=args.calibration_file, joint_angles=args.joint_angles,
                              heading_correction=args.heading_correction == "joints", skeleton=skeleton)


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(message)s")
    settings = settings_from_args(args)
    return aggregator.run(settings, flags.session_settings(args, "limbstream aggregate"), stop)
