"""The kernel library's VQF against the PyPI ``vqf`` package (double precision) on BROAD's trials:
9D total RMSE against the optical truth, and host speed of the fusion.

    python bench/vqf_broad.py [--data ../shared/data]

BROAD's error: the angle of estimate * truth^-1 (earth frame), RMS over the movement phases where
the markers were seen. Prints one row per trial, the largest difference, and the host cost of
:func:`limbstream.kernel.fusion.fuse` and of :class:`limbstream.kernel.ImuBank` per raw sample, with VQF
in each precision (the kernel's rows: the firmware's precision).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import scipy.io
import vqf

from limbstream import quat
from limbstream.kernel import fusion

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def total_rmse_deg(est: np.ndarray, truth: np.ndarray, movement: np.ndarray) -> float:
    ok = movement & np.isfinite(truth).all(axis=1)
    return float(np.sqrt(np.mean(quat.angle_deg(est[ok], truth[ok]) ** 2)))


def accuracy(data: Path) -> None:
    """9D total RMSE of the kernel with the device's filter settings (rest threshold
    fusion.REST_TH_GYR_DPS) against online VQF with the same settings and with VQF's defaults."""
    print(f"{'trial':<44}{'online VQF':>11}{'kernel':>9}{'diff':>9}{'online, defaults':>18}{'diff':>9}"
          f"   (9D total RMSE, deg; rest threshold {fusion.REST_TH_GYR_DPS:g} deg/s)")
    worst = [0.0, 0.0]
    for path in sorted((data / "broad").glob("*.mat")):
        d = scipy.io.loadmat(path, squeeze_me=True)
        g, a, m = (np.ascontiguousarray(d[k], np.float64) for k in ("imu_gyr", "imu_acc", "imu_mag"))
        rate, truth, movement = float(d["sampling_rate"]), d["opt_quat"], d["movement"].astype(bool)
        same = vqf.VQF(1.0 / rate, restThGyr=fusion.REST_TH_GYR_DPS, restThAcc=fusion.REST_TH_ACC)
        online = total_rmse_deg(same.updateBatch(g, a, m)["quat9D"], truth, movement)
        defaults = total_rmse_deg(vqf.VQF(1.0 / rate).updateBatch(g, a, m)["quat9D"], truth, movement)
        ours = total_rmse_deg(fusion.fuse(g, a, m, rate_hz=rate), truth, movement)
        worst = [max(worst[0], abs(ours - online)), max(worst[1], abs(ours - defaults))]
        print(f"{path.stem:<44}{online:>11.4f}{ours:>9.4f}{ours - online:>+9.4f}{defaults:>18.4f}{ours - defaults:>+9.4f}")
    print(f"largest |difference|: {worst[0]:.4f} deg (same settings), {worst[1]:.4f} deg (VQF's defaults)")


def speed(data: Path) -> None:
    """Host cost per raw sample of fusion.fuse (one device) and ImuBank.update_raw (2,000 devices),
    VQF in each precision, in turns (best of five rounds each)."""
    d = scipy.io.loadmat(sorted((data / "broad").glob("*.mat"))[0], squeeze_me=True)
    g, a = d["imu_gyr"], d["imu_acc"]
    rate = float(d["sampling_rate"])
    count, steps = 2000, 50
    rows = np.arange(steps * count) % len(g)
    gyr, acc = g[rows].reshape(steps, count, 3), a[rows].reshape(steps, count, 3)
    ticks = np.zeros(count, np.int64)

    def bank_run(precision: str) -> float:
        bank = fusion.ImuBank(count, rate_hz=200.0, threshold=9e-4, max_len=25, live_bound_deg=5.0,
                              vqf_precision=precision)
        start = time.perf_counter()
        for s in range(steps):
            bank.update_raw(ticks + s * 5000, gyr[s], acc[s])
        return time.perf_counter() - start

    fuse_best = {p: float("inf") for p in fusion.VQF_PRECISIONS}
    bank_best = dict(fuse_best)
    for _ in range(5):
        for p in fusion.VQF_PRECISIONS:
            fuse_best[p] = min(fuse_best[p], _timed(lambda p=p: fusion.fuse(g, a, rate_hz=rate, vqf_precision=p)))
            bank_best[p] = min(bank_best[p], bank_run(p))
    print("\n| host, ns per raw sample | " + " | ".join(fusion.VQF_PRECISIONS) + " |")
    print("|---|" + "---:|" * len(fusion.VQF_PRECISIONS))
    print("| fuse (6D), one device | " + " | ".join(f"{fuse_best[p] / len(g) * 1e9:.0f}" for p in fusion.VQF_PRECISIONS) + " |")
    print(f"| ImuBank.update_raw, {count} devices | "
          + " | ".join(f"{bank_best[p] / (steps * count) * 1e9:.0f}" for p in fusion.VQF_PRECISIONS) + " |")


def _timed(call) -> float:
    start = time.perf_counter()
    call()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA, help="the shared data folder (with broad/)")
    args = parser.parse_args()
    accuracy(args.data)
    speed(args.data)


if __name__ == "__main__":
    main()
