"""Emulated sensors through VQF 6D: inclination error and heading drift per segment
(docs/evaluation.md, "Raw sensors").

Every clip is played once after the calibration script (``.bvh``: at its own rate, its root
travelling; ``.npz``: 50 Hz on a fixed root); each segment's sensor reads it at ``--rate``
(:func:`limbstream.imu.record`), and the PyPI ``vqf`` package (6D, default parameters) fuses it
from the first sample with the device's start heading. Against the sensor's true orientation, over
the motion (not the script), heading aligned once over the first second of the script:
inclination RMSE pooled over the clips, heading drift (deg/min, the slope of the heading error
over the motion) as the median over the clips and its largest magnitude, and the share of samples
a real part saturates (a reading at its full scale). A second table groups by clip.

    python bench/imu_fusion.py ../shared/data/cmu
    python bench/imu_fusion.py ../shared/data/cmu_10seg_50hz.npz
    python bench/imu_fusion.py generator --minutes 10     # three subjects of the built-in motion
    python bench/imu_fusion.py ../shared/data/cmu --loop-minutes 10   # each clip looped (fixed root)

With ``--loop-minutes`` the tables also give the heading RMSE (heading aligned once, pooled):
what a drift that is no straight line adds up to.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from limbstream import imu
from limbstream.calibration import SensorModel
from limbstream.evaluation.fusion import fusion_error, reference_vqf
from limbstream.evaluation.raw_streams import looped
from limbstream.sources import bvh, load
from limbstream.sources.generator import generate



def motions(path: str, minutes: float, loop_minutes: float | None = None) -> list:
    """The clips of a folder of .bvh files (native rate, root path), of an npz file, or
    ``generator``: ``minutes`` of the built-in motion (subject seeds 0-2); with ``loop_minutes``
    each clip looped for that long (eval's ``--loop-minutes``)."""
    if path == "generator":
        return [generate(60.0 * minutes, fs=100.0, seed=seed) for seed in range(3)]
    clips = [bvh.load_bvh(p, fs=None) for p in sorted(Path(path).glob("*.bvh"))] if Path(path).is_dir() else load(path)
    return clips if loop_minutes is None else looped(clips, loop_minutes)


def run(clips: list, model: str, rate: float, sensors: SensorModel, params: dict) -> list[dict]:
    """One row per (clip, segment): samples, inclination RMSE (deg), heading drift (deg/min),
    saturated samples (a reading at the part's full scale)."""
    part = imu.model(model)
    rows = []
    for c, motion in enumerate(clips):
        devices = imu.ImuDevices(len(motion.segments), part, rate, sensors, stream=c)
        rec = imu.record(motion, devices)
        estimate = reference_vqf(rec.gyr, rec.acc, rate, start_heading=imu.earth_heading(devices.heading),
                                 params=params)
        for s, segment in enumerate(rec.segments):
            e = fusion_error(estimate[:, s], rec.truth[:, s], rec.t, rec.movement, align_heading=True)
            rows.append({"clip": motion.name, "segment": segment, "n": e.samples, "incl": e.inclination_deg,
                         "heading": e.heading_deg, "drift": e.heading_drift_dpm,
                         "saturated": int(part.at_full_scale(rec.gyr[:, s], rec.acc[:, s]).sum())})
    return rows


def cells(rows: list[dict], heading: bool = False) -> str:
    """Pooled inclination RMSE (and heading RMSE), median and largest drift, saturated share of a
    group of rows."""
    n = np.array([r["n"] for r in rows])
    incl, head = (np.sqrt(np.sum(n * np.array([r[k] for r in rows]) ** 2) / n.sum()) for k in ("incl", "heading"))
    drift = np.array([r["drift"] for r in rows])
    share = 100.0 * sum(r["saturated"] for r in rows) / n.sum()
    return (f"{incl:.2f} | " + (f"{head:.2f} | " if heading else "")
            + f"{np.median(drift):+.2f}, {np.abs(drift).max():.2f} | {share:.2f}")


def table(results: dict[str, list[dict]], key: str, heading: bool = False) -> None:
    """Rows grouped by ``key`` (segment or clip), a column group per part."""
    models = list(results)
    head = " | heading RMSE (deg)" if heading else ""
    print(f"| {key} | " + " | ".join(f"{m}: inclination RMSE (deg){head} | drift median, max abs (deg/min) | "
                                      "saturated (%)" for m in models) + " |")
    print("|---|" + ("---:|" * (4 if heading else 3)) * len(models))
    groups = list(dict.fromkeys(r[key] for r in next(iter(results.values()))))
    for group in [*groups, "all"]:
        picked = [[r for r in results[m] if group in ("all", r[key])] for m in models]
        print(f"| {group} | " + " | ".join(cells(p, heading) for p in picked) + " |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("path", help="a folder of .bvh clips, an npz motion file, or 'generator'")
    parser.add_argument("--minutes", type=float, default=10.0, help="of each generated subject (default 10)")
    parser.add_argument("--loop-minutes", type=float, default=None, metavar="M",
                        help="clips: play each looped for M minutes (seams joined smoothly, fixed root)")
    parser.add_argument("--models", nargs="+", default=["ideal", "icm42688p"], choices=sorted(imu.MODELS))
    parser.add_argument("--rate", type=float, default=imu.DEFAULT_RATE_HZ, help="sensor rate, Hz")
    parser.add_argument("--mounting-deg", type=float, default=0.0)
    parser.add_argument("--heading-deg", type=float, default=0.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--vqf", nargs="*", default=[], metavar="NAME=VALUE",
                        help="VQF parameters to override, e.g. restBiasEstEnabled=0 restThGyr=1.0")
    args = parser.parse_args()
    params = {name: float(value) for name, value in (item.split("=", 1) for item in args.vqf)}
    clips = motions(args.path, args.minutes, args.loop_minutes)
    sensors = SensorModel(args.mounting_deg, args.heading_deg, 0.0, args.seed)
    results = {m: run(clips, m, args.rate, sensors, params) for m in args.models}
    seconds = sum(m.t[-1] - m.t[0] for m in clips)
    print(f"{args.path}: {len(clips)} clips, {seconds:.0f} s of motion; sensors at {args.rate:g} Hz, mounting "
          f"<= {args.mounting_deg:g} deg, start heading +-{args.heading_deg:g} deg, seed {args.seed}; VQF 6D, "
          f"{params or 'default parameters'}\n")
    heading = args.loop_minutes is not None
    table(results, "segment", heading)
    print()
    table(results, "clip", heading)
    return 0


if __name__ == "__main__":
    sys.exit(main())
