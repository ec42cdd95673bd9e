"""``limbstream export IN -o OUT``: one subject of a recording (its exact pose frames) or of a
motion file, as BVH, CSV, npz, OpenSim joint angles (.mot) or OpenSense orientations (.sto)
(services/outputs/export.py; layouts in docs/outputs.md)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from limbstream import wire
from limbstream.cli import flags
from limbstream.services.outputs.export import FORMATS, ExportError, export, read_take

PROG = "limbstream export"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="IN", help="a recording (.mcap), a raw sensor recording (.mat: fused as "
                                                     "devices fuse it) or a motion file/folder limbstream reads "
                                                     "(.npz, .bvh, x-IMU3 .csv, Xsens .txt)")
    parser.add_argument("--subject", default=None,
                        help="subject of a recording, or clip name (or s01, s02, ... in file order) of a motion "
                             "file (default: the only one)")
    parser.add_argument("--format", choices=FORMATS, default=None,
                        help="output format (default: from OUT's extension)")
    parser.add_argument("-o", "--output", required=True, metavar="OUT", help="file to write (replaced if it exists)")
    parser.add_argument("--rest-pose", choices=wire.REST_POSES, default=None,
                        help="override the input's rest pose (default: the data's own: a BVH's from its OFFSETs, "
                             "an npz's entry (tpose without one), standing for IMU files; recordings: their frames' "
                             "flags)")
    parser.add_argument("--rate", type=float, default=None, metavar="HZ",
                        help="frame rate of the export, Hz (SLERP-resampled; default: the source's own)")
    flags.add_names(parser)
    flags.add_source_layout(parser, "default: the layout the source carries (a BVH file: paper10; a recording: "
                                    "its frames')")


def run(args: argparse.Namespace) -> int:
    fmt = args.format or Path(args.output).suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        return flags.fail(PROG, f"--format: say {', '.join(FORMATS)} (OUT {args.output!r} does not tell)")
    try:
        take = read_take(args.source, args.subject, args.rest_pose, args.names, args.rate, args.layout)
        export(take, fmt, args.output)
    except ExportError as exc:
        return flags.fail(PROG, str(exc))
    for note in take.notes + [f"calibration: {take.basis}"]:
        print(f"{PROG}: note: {note}", file=sys.stderr)
    seconds = len(take) * take.period_us / 1e6
    print(f"exported {take.name}: {len(take)} frames at {1e6 / take.period_us:.4g} Hz ({seconds:.1f} s, "
          f"{take.skeleton.rest_pose} rest pose) to {args.output} ({fmt})", flush=True)
    return 0
