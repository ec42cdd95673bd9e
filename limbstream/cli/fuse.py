"""``limbstream fuse``: the device's orientation per sample for every sensor of a raw recording.

Each sensor's angular rate and specific force (and with ``--mag`` its magnetic field) go through
the kernel's fusion (:func:`limbstream.kernel.fusion.fuse`: VQF with the device's filter
settings, bad samples handled as on the device), sample by sample, exactly as a device computes
it. The output is the sensor frame in the filter's earth frame (z up; 9D: east, north, up), w x y
z, before any calibration: an ``.npz`` with ``t`` (n,) s, one (n, 4) array per sensor named by
the sensor, and ``quat`` too when the recording has one sensor.
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

from limbstream.cli import flags
from limbstream.kernel import fusion
from limbstream.sources import MotionFileError
from limbstream.sources import raw
from limbstream.sources.raw import load_raw

PROG = "limbstream fuse"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", type=Path, metavar="PATH",
                        help="a raw recording: a BROAD trial or a qmt-style full-body .mat file")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT.npz", help="where to write")
    parser.add_argument("--mag", action="store_true",
                        help="fuse the magnetometer too (9D: heading from the magnetic field); default 6D")
    parser.add_argument("--rest-th-gyr", type=float, default=fusion.REST_TH_GYR_DPS, metavar="DPS",
                        help="VQF's rest threshold on the angular rate, deg/s (default the device's, "
                             f"{fusion.REST_TH_GYR_DPS:g}; VQF's own: {fusion.VQF_REST_TH_GYR_DPS:g})")
    flags.add_vqf_precision(parser)


def run(args: argparse.Namespace) -> int:
    if args.output.suffix.lower() != ".npz":
        return flags.fail(PROG, f"-o {args.output}: must end in .npz")
    if not args.output.parent.resolve().is_dir():
        return flags.fail(PROG, f"-o {args.output}: folder {args.output.parent} does not exist")
    try:
        rec = load_raw(args.path)
        q = raw.fuse(rec, args.mag, args.rest_th_gyr, args.vqf_precision)
    except (MotionFileError, ValueError) as exc:
        return flags.fail(PROG, str(exc))
    arrays = {"t": rec.t}
    for s, name in enumerate(rec.sensors):
        key = re.sub(r"\W", "_", name)
        if key in arrays:
            return flags.fail(PROG, f"{args.path}: two sensors named {key!r}")
        arrays[key] = q[:, s]
    if len(rec.sensors) == 1:
        arrays["quat"] = q[:, 0]
    np.savez(args.output, **arrays)  # type: ignore[arg-type]  # (numpy's stub: savez(file, *args, allow_pickle, **kwds))
    print(f"{args.path}: {len(rec.sensors)} sensor{'s' if len(rec.sensors) != 1 else ''} x {len(rec.t):,} samples "
          f"at {rec.fs:.1f} Hz, {'9D' if args.mag else '6D'}, rest threshold {args.rest_th_gyr:g} deg/s -> "
          f"{args.output} ({', '.join(arrays)})", file=sys.stderr)
    return 0
