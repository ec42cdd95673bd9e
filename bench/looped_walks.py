"""Root translation over looped walks: minutes of a CMU walk (``eval --loop-minutes``, the clip
looped on its own cycle with its root walking on: docs/evaluation.md, "Root translation"), the
contact rule's root against the looped file's, minute by minute.

    python bench/looped_walks.py                       # the four walks, 10 minutes, make run's raw sensors
    python bench/looped_walks.py --perfect --minutes 5
    python bench/looped_walks.py --sensor-seed 3

It runs ``limbstream eval`` once on the clips (together, so each one's sensors are those of
docs/benchmarks.md's tables) with ``--dump``, aligns each estimate's start as eval does
(:func:`limbstream.evaluation.translation.aligned`: heading and offset once, on the first 0.5 s)
and prints, at each of ``--at`` minutes, the horizontal root error as a percentage of the path
walked so far (the true root's, over 0.1 s steps, as eval sums it), its largest over the run,
and the median over the clips. A looped path turns by the same angle every pass, and an estimate
whose turn per pass differs goes round another circle: its end error rises and falls over the
minutes, so one end figure says little; the largest says more. A last table gives each clip's
largest turn of a segment between samples where the loop joins, against a restart from its first
frame.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from limbstream import quat
from limbstream.evaluation.translation import aligned
from limbstream.sources import load
from limbstream.sources.bvh_loop import looped_motion

sys.path.insert(0, str(Path(__file__).resolve().parent))
from root_path_plot import DATA, RAW, ROW  # noqa: E402  (bench/root_path_plot.py: the same eval rows)

WALKS = ("02_01", "131_01", "131_02", "131_03")
"""The CMU walks of docs/benchmarks.md's root translation tables."""


def errors(dump: dict, at_s: list[float]) -> tuple[list[float], float, float]:
    """(the error at each of ``at_s`` s, % of the path so far; the largest such over the run after
    its first minute, %; the path, m) of one dumped motion."""
    ok = np.isfinite(dump["root"]).all(axis=1)
    t, true_root = dump["t"][ok], dump["true_root"][ok]
    root, _ = aligned(t, dump["root"][ok], dump["feet"][ok], true_root, float(dump["root_heading_rad"]))
    step = max(1, round(0.1 / float(np.median(np.diff(t)))))
    every = np.arange(0, len(t), step)
    walked = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(true_root[every][:, [0, 2]], axis=0), axis=1))])
    off = np.linalg.norm(root[every][:, [0, 2]] - true_root[every][:, [0, 2]], axis=1)
    pct = 100 * off / np.maximum(walked, 1e-9)
    at = [float(pct[min(len(every) - 1, int(np.searchsorted(t[every], t[0] + s)))]) for s in at_s]
    late = t[every] - t[0] >= 60.0
    return at, float(pct[late].max() if late.any() else pct.max()), float(walked[-1])


def seams(data: Path, clips: list[str]) -> None:
    """Per clip, the largest turn of a segment between two samples (50 Hz, ``--layout full``): the
    file's own, over a looped minute (its seams included), and where the clip starts again from
    its first frame (as a plain loop does)."""
    print("\n### Where the loop joins: the largest turn of a segment between samples, degrees\n")
    print("| clip | the file's own | looped on its cycle | started again from its first frame |")
    print("|---|---:|---:|---:|")
    for clip in clips:
        [motion] = load(data / f"{clip}.bvh", layout="full")
        looped = looped_motion(motion, 60.0, "full")[0]
        own = quat.angle_deg(motion.q[1:], motion.q[:-1]).max()
        loop = quat.angle_deg(looped.q[1:], looped.q[:-1]).max()
        again = quat.angle_deg(motion.q[-1], motion.q[0]).max()
        print(f"| {clip} | {own:.1f} | {loop:.1f} | {again:.1f} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA, help="the CMU clips' folder")
    parser.add_argument("--clips", nargs="+", default=list(WALKS))
    parser.add_argument("--minutes", type=float, default=10.0, help="of each looped clip (default 10)")
    parser.add_argument("--at", default="1,2,5,10", help="minutes to report (default 1,2,5,10)")
    parser.add_argument("--perfect", action="store_true", help="perfect sensors (eval's default), not make run's")
    parser.add_argument("--sensor-seed", type=int, default=0)
    args = parser.parse_args()
    at = [float(m) for m in args.at.split(",") if float(m) <= args.minutes]
    missing = [c for c in args.clips if not (args.data / f"{c}.bvh").exists()]
    if missing:
        parser.error(f"no {', '.join(missing)} in {args.data}")
    sensors = () if args.perfect else (*RAW, "--sensor-seed", str(args.sensor_seed))
    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, "-m", "limbstream.cli", "eval", *(str(args.data / f"{c}.bvh") for c in args.clips),
                   *sensors, *ROW, "--loop-minutes", f"{args.minutes:g}", "--dump", folder]
        print("running:", " ".join(["limbstream", *command[3:-1]]), "DIR", file=sys.stderr)
        done = subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        for line in done.stderr.splitlines():
            if "looped" in line:
                print(line.removeprefix("limbstream eval: note: "))
        rows = []
        for clip in args.clips:
            with np.load(Path(folder) / f"loop_{clip}_.npz") as dump:  # (the dump names loop(<clip>) so)
                rows.append((clip, *errors({k: dump[k] for k in dump.files}, [60.0 * m for m in at])))
    print(f"\n### Looped walks, {args.minutes:g} min each, {'perfect sensors' if args.perfect else f'raw ICM-42688-P, seed {args.sensor_seed}'}\n")
    print("| clip | path, m | " + " | ".join(f"{m:g} min, %" for m in at) + " | largest after 1 min, % |")
    print("|---|---:|" + "---:|" * (len(at) + 1))
    for clip, pct, worst, path in rows:
        print(f"| loop({clip}) | {path:.0f} | " + " | ".join(f"{p:.1f}" for p in pct) + f" | {worst:.1f} |")
    med = np.median(np.array([r[1] for r in rows]), axis=0)
    print("| median | | " + " | ".join(f"{p:.1f}" for p in med) + f" | {np.median([r[2] for r in rows]):.1f} |")
    seams(args.data, args.clips + [c for c in ("01_01",) if c not in args.clips and (args.data / f"{c}.bvh").exists()])
    return 0


if __name__ == "__main__":
    sys.exit(main())
