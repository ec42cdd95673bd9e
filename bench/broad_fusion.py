"""VQF (the PyPI package) on BROAD trials: fusion error against the optical reference
(docs/evaluation.md, "Raw sensors").

Per trial, over its movement phases: 9D (with the magnetometer) total, heading and inclination
RMSE; 6D inclination RMSE and heading drift (deg/min) after aligning the heading once at the
start; then the mean and median over the trials.

    python bench/broad_fusion.py ../shared/data/broad
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from limbstream.evaluation.fusion import VQF_VERSION, fusion_error, reference_vqf  # noqa: E402
from limbstream.sources import load_raw  # noqa: E402


def trial(path: Path) -> list[float]:
    """[9D total, heading, inclination, 6D inclination, 6D heading drift] of one trial."""
    r = load_raw(path)
    nine = reference_vqf(r.gyr, r.acc, r.fs, mag=r.mag)[:, 0]
    six = reference_vqf(r.gyr, r.acc, r.fs)[:, 0]
    e9 = fusion_error(nine, r.truth[:, 0], r.t, r.movement)
    e6 = fusion_error(six, r.truth[:, 0], r.t, r.movement, align_heading=True)
    return [e9.total_deg, e9.heading_deg, e9.inclination_deg, e6.inclination_deg, e6.heading_drift_dpm]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="a folder of BROAD trials (.mat)")
    args = parser.parse_args()
    paths = sorted(args.folder.glob("*.mat"))
    if not paths:
        print(f"{args.folder}: no .mat files", file=sys.stderr)
        return 2
    print(f"VQF {VQF_VERSION} (PyPI, default parameters), {len(paths)} BROAD trials, movement phases\n")
    print("| trial | 9D total RMSE (deg) | 9D heading | 9D inclination | 6D inclination RMSE (deg) | "
          "6D heading drift (deg/min) |")
    print("|---|---:|---:|---:|---:|---:|")
    rows = []
    for path in paths:
        rows.append(trial(path))
        print(f"| {path.stem} | " + " | ".join(f"{v:.2f}" for v in rows[-1][:4]) + f" | {rows[-1][4]:+.2f} |")
    values = np.array(rows)
    for name, stat in (("mean", np.mean), ("median", np.median)):
        drift = stat(np.abs(values[:, 4]))
        print(f"| **{name}** (drift: of its magnitude) | " + " | ".join(f"{stat(values[:, i]):.2f}" for i in range(4))
              + f" | {drift:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
