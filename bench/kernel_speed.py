"""Host speed of the C kernels: ns per sample vs average segment length, and binding overhead.

    python bench/kernel_speed.py            # prints the tables of docs/kernel.md

Single core, batch API (limbstream.kernel.segment), piecewise-linear test signals whose
segments have a known length, so the realised average segment length is printed next to
the target. Timing: best of several repeats (time.perf_counter_ns).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from limbstream import kernel

THRESHOLD = 1e-3  # far above float32 noise on these lines, far below a knot's SSR


def piecewise_linear(m: int, length: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(t (m,), y (m, 4)): straight segments of `length` samples with random slopes."""
    rng = np.random.default_rng(seed)
    knots = np.cumsum(rng.normal(0, 0.3, (m // length + 2, 4)), axis=0)
    k = np.arange(m)
    seg, u = np.divmod(k, length)
    y = knots[seg] + (knots[seg + 1] - knots[seg]) * (u / length)[:, None]
    return k * 0.02, y


def best_ns(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter_ns()
        fn()
        best = min(best, time.perf_counter_ns() - start)
    return best


def segment_length_table(m: int, repeats: int) -> list[tuple[int, float, float, float]]:
    rows = []
    for length in (2, 5, 10, 20, 50, 100, 200, 500, 1000):
        t, y = piecewise_linear(m, length)
        result = kernel.segment(t, y, THRESHOLD)
        realised = (m - 1) / max(len(result.index) - 1, 1)
        ns = {
            alg: best_ns(lambda a=alg, t=t, y=y: kernel.segment(t, y, THRESHOLD, algorithm=a), repeats) / m
            for alg in ("fastsw", "sw")
        }
        rows.append((length, realised, ns["fastsw"], ns["sw"]))
    return rows


def overhead_table(m: int) -> list[tuple[str, float]]:
    t, y = piecewise_linear(m, 20)
    y32 = y.astype(np.float32)
    batch = best_ns(lambda: kernel.segment(t, y, 1e-6), 5) / m

    def streamed():
        seg = kernel.Segmenter(threshold=1e-6)
        for ti, yi in zip(t, y32):
            seg.update(ti, yi)

    per_call = best_ns(streamed, 3) / m
    devices = 1000
    bank = kernel.SegmenterBank(devices, threshold=1e-6)
    ticks = kernel.to_ticks(t)
    block = np.repeat(y32[:, None, :], devices, axis=1)

    def banked():
        for i in range(200):
            bank.update(np.full(devices, ticks[i], np.uint32), block[i])

    per_device = best_ns(banked, 3) / (200 * devices)
    return [
        ("batch segment(), per sample", batch),
        ("Segmenter.update(), one ctypes call per sample", per_call),
        (f"SegmenterBank.update(), {devices} devices per call, per device", per_device),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200_000, help="samples per stream")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)

    rows = segment_length_table(args.samples, args.repeats)
    print(f"Host speed, batch API, {args.samples} samples, D = 4, single core (ns per sample)\n")
    print("| target length | realised avg length | fastSW ns/sample | SW ns/sample | SW / fastSW |")
    print("|---:|---:|---:|---:|---:|")
    for length, realised, fast, sw in rows:
        print(f"| {length} | {realised:.1f} | {fast:.1f} | {sw:.1f} | {sw / fast:.1f} |")
    at100 = min(rows, key=lambda r: abs(r[1] - 100))
    print(f"\nSW / fastSW at average length {at100[1]:.0f}: {at100[3] / at100[2]:.1f}x\n")
    print("| Python binding path | ns per sample |")
    print("|---|---:|")
    for name, ns in overhead_table(20_000):
        print(f"| {name} | {ns:.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
