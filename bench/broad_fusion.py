"""VQF on BROAD trials: fusion error against the optical reference (docs/evaluation.md, "Raw
sensors").

First table, the PyPI package with its default parameters: per trial, over its movement phases,
9D (with the magnetometer) total, heading and inclination RMSE; 6D inclination RMSE and heading
drift (deg/min) after aligning the heading once at the start; then the mean and median over the
trials.

Second table (``--chain``), the device: each trial fused as a device fuses it (the kernel's VQF,
the device's filter settings) and compressed at its instants with make run's settings (threshold
9e-4, live bound 5 deg, max_len 25), as ``limbstream eval TRIAL [--mag] --thresholds 9e-4
--live-bound 5 --max-len 25`` scores it: the fusion error of the device's samples and the chain
error of their reconstruction (segment points SLERPed), 9D total and 6D inclination and drift,
with ICR.

Third table (``--precision``), the device's VQF in single and in double precision (the kernel's
VQF, the device's settings, every raw sample): 9D total and 6D total (heading aligned once at the
start) RMSE against the optical truth over the movement phases, single minus double, and the
largest |single - double| over the trials; the firmware's precision is single when that stays
within 0.05 deg on every trial (docs/kernel.md, "VQF's precision").

    python bench/broad_fusion.py ../shared/data/broad [--chain] [--precision]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from limbstream import wire
from limbstream.evaluation import evaluate
from limbstream.evaluation.fusion import VQF_VERSION, fusion_error, reference_vqf
from limbstream.evaluation.raw_streams import recording_streams
from limbstream.kernel import fusion
from limbstream.sources import load_raw



def trial(path: Path) -> list[float]:
    """[9D total, heading, inclination, 6D inclination, 6D heading drift] of one trial."""
    r = load_raw(path)
    nine = reference_vqf(r.gyr, r.acc, r.fs, mag=r.mag)[:, 0]
    six = reference_vqf(r.gyr, r.acc, r.fs)[:, 0]
    e9 = fusion_error(nine, r.truth[:, 0], r.t, r.movement)
    e6 = fusion_error(six, r.truth[:, 0], r.t, r.movement, align_heading=True)
    return [e9.total_deg, e9.heading_deg, e9.inclination_deg, e6.inclination_deg, e6.heading_drift_dpm]


def chain(paths: list[Path]) -> None:
    """The second table: the device's fusion and chain errors per trial."""
    print(f"\nThe device (kernel VQF, rest threshold at the device's), make run's settings (threshold "
          f"{wire.LIVE_MODE['threshold']:g}, live bound {wire.LIVE_MODE['live_bound_deg']:g} deg, max_len 25), the "
          "device's samples (50 Hz) in the movement phases\n")
    print("| trial | 9D fusion total (deg) | 9D chain total | chain - fusion | ICR | 6D fusion incl. (deg) | "
          "6D chain incl. | 6D fusion drift (deg/min) | 6D chain drift |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    worst = -float("inf")
    for path in paths:
        rec = load_raw(path)
        rows = [evaluate(recording_streams(rec, mag), ["fastsw"], [wire.LIVE_MODE["threshold"]], 25,
                         [wire.LIVE_MODE["live_bound_deg"]])[0] for mag in (True, False)]
        nine, six = rows
        worst = max(worst, nine["chain_total"] - nine["fusion_total"])
        print(f"| {path.stem} | {nine['fusion_total']:.2f} | {nine['chain_total']:.2f} | "
              f"{nine['chain_total'] - nine['fusion_total']:+.2f} | {nine['icr']:.3f} | {six['fusion_incl']:.2f} | "
              f"{six['chain_incl']:.2f} | {six['fusion_drift']:+.2f} | {six['chain_drift']:+.2f} |")
    print(f"\nlargest chain - fusion (9D total): {worst:+.3f} deg")


def precision_errors(path: Path, precision: str) -> tuple[float, float]:
    """(9D total, 6D total with the heading aligned at the start) RMSE, deg, of one trial fused by
    the kernel's VQF in ``precision``."""
    r = load_raw(path)
    out = []
    for mag in (r.mag[:, 0], None):
        q = fusion.fuse(r.gyr[:, 0], r.acc[:, 0], mag, rate_hz=r.fs, t=r.t, vqf_precision=precision)
        out.append(fusion_error(q, r.truth[:, 0], r.t, r.movement, align_heading=mag is None).total_deg)
    return out[0], out[1]


def precision(paths: list[Path]) -> None:
    """The third table: single against double precision, per trial."""
    print("\nThe device's VQF (kernel, the device's settings) in single and double precision, every raw sample, "
          "movement phases (total RMSE, deg)\n")
    print("| trial | 9D single | 9D double | 9D single - double | 6D single | 6D double | 6D single - double |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    worst = 0.0
    for path in paths:
        (s9, s6), (d9, d6) = (precision_errors(path, p) for p in ("single", "double"))
        worst = max(worst, abs(s9 - d9), abs(s6 - d6))
        print(f"| {path.stem} | {s9:.4f} | {d9:.4f} | {s9 - d9:+.4f} | {s6:.4f} | {d6:.4f} | {s6 - d6:+.4f} |")
    print(f"\nlargest |single - double|: {worst:.4f} deg")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="a folder of BROAD trials (.mat)")
    parser.add_argument("--chain", action="store_true", help="also the device's fusion and chain errors")
    parser.add_argument("--precision", action="store_true", help="only the device's VQF in single and double precision")
    args = parser.parse_args()
    paths = sorted(args.folder.glob("*.mat"))
    if not paths:
        print(f"{args.folder}: no .mat files", file=sys.stderr)
        return 2
    if args.precision:
        precision(paths)
        return 0
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
    if args.chain:
        chain(paths)
    return 0


if __name__ == "__main__":
    sys.exit(main())
