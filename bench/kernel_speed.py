"""Host speed of the C kernels: ns per sample vs average segment length, the live rule on and
off, and binding overhead.

    python bench/kernel_speed.py            # prints the tables of docs/kernel.md
    python bench/kernel_speed.py --points   # only the cost of encoding a segment point (emulator)

Single core, batch API (limbstream.kernel.segment), piecewise-linear test signals whose
segments have a known length, so the realised average segment length is printed next to
the target. Timing: best of several repeats (time.perf_counter_ns).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from limbstream import kernel, wire

THRESHOLD = 1e-3  # far above float32 noise on these lines, far below a knot's SSR
CMU = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "cmu_10seg_50hz.npz"


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


def cmu_streams() -> list[tuple[np.ndarray, np.ndarray]]:
    """(t, q) of every segment of every clip in the shared CMU file (50 Hz), or [] if absent."""
    if not CMU.exists():
        return []
    data = np.load(CMU)
    return [(np.arange(len(data[k])) * 0.02, data[k][:, s].astype(np.float64))
            for k in data.files if k.startswith("clip_") for s in range(data[k].shape[1])]


def live_table(m: int, repeats: int) -> list[tuple[str, float, float]]:
    """(setting, ICR, ns/sample) of the C batch kernel (fastsw_segment, indices only) on every CMU
    stream one after another, repeated to m samples (one call), max_len 25, TH 1e-3."""
    streams = cmu_streams()
    q = np.concatenate([q for _, q in streams])
    q = np.tile(q, (-(-m // len(q)), 1))[:m]
    t = np.arange(m) * 0.02
    ticks, y = kernel.to_ticks(t), np.ascontiguousarray(q, np.float32)
    index = np.empty(m, np.uint32)
    out = kernel.BatchOut(index.ctypes.data)  # the C kernel alone: indices only
    rows = []
    for bound in (0.0, 10.0, 5.0, 2.0):
        settings = kernel.make_settings(1e-3, 25, 4, bound)
        icr = kernel._lib.fastsw_segment(settings, ticks, y, m, out, None) / m
        ns = best_ns(lambda s=settings: kernel._lib.fastsw_segment(s, ticks, y, m, out, None), repeats) / m
        rows.append(("off" if bound == 0 else f"{bound:g} deg", icr, ns))
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
    live_bank = kernel.SegmenterBank(devices, threshold=1e-3, max_len=25, live_bound_deg=5.0)
    streams = cmu_streams() or [(t, np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1)))]
    turning = np.stack([streams[k % len(streams)][1][:140] for k in range(devices)], axis=1).astype(np.float32)

    def banked_live():
        for i in range(140):
            live_bank.update(np.full(devices, ticks[i], np.uint32), turning[i])
            live_bank.points_omega()

    per_device_live = best_ns(banked_live, 3) / (140 * devices)
    return [
        ("batch segment(), per sample", batch),
        ("Segmenter.update(), one ctypes call per sample", per_call),
        (f"SegmenterBank.update(), {devices} devices per call, per device", per_device),
        (f"SegmenterBank.update() + points_omega(), live rule 5 deg, {devices} devices, per device",
         per_device_live),
    ]


def point_costs(bound: float, q: np.ndarray, repeats: int) -> dict[str, float]:
    """ns per segment point of each encoding path, beyond SegmenterBank.update(), with live bound
    ``bound``; q (ticks, devices, 4) float32 samples, every one a point (threshold 0)."""
    ticks, devices = q.shape[:2]
    bank = kernel.SegmenterBank(devices, threshold=0.0, max_len=25, live_bound_deg=bound, ring=4)
    clock = iter(range(1 << 30))

    def bare():
        bank.update(np.full(devices, next(clock) * 20_000, np.uint32), q[0])

    def python_encoder():  # the emulator's path before the bank encoded: a SegmentPoint per point
        i = next(clock)
        status, index, y = bank.update(np.full(devices, i * 20_000, np.uint32), q[i % ticks])
        omega = bank.points_omega()
        for k in np.flatnonzero(status == kernel.POINT):
            rate = tuple(float(v) for v in omega[k]) if bound else None
            wire.encode_point(wire.SegmentPoint(1, 2, int(index[k]), 4, tuple(float(v) for v in y[k]), 0, rate))

    def c_encoder():
        i = next(clock)
        bank.update_wire(np.full(devices, i * 20_000, np.uint32), q[i % ticks])

    def c_encoder_sliced():  # and the emulator's slice per point
        i = next(clock)
        slots, payload, ends = bank.update_wire(np.full(devices, i * 20_000, np.uint32), q[i % ticks])
        start = 0
        for _, end in zip(slots.tolist(), ends.tolist()):
            payload[start:end]
            start = end

    def per_tick(fn) -> float:
        def run():
            for _ in range(ticks):
                fn()
        return best_ns(run, repeats) / ticks

    base = per_tick(bare)
    return {name: (per_tick(fn) - base) / devices for name, fn in (
        ("wire.encode_point(SegmentPoint(...)) per point (before)", python_encoder),
        ("SegmenterBank.update_wire(), C encoder", c_encoder),
        ("update_wire() + a bytes slice per point (the emulator now)", c_encoder_sliced))}


def point_cost_table(devices: int = 2000, ticks: int = 20, repeats: int = 5) -> list[tuple[str, float, float]]:
    """ns per segment point of the emulator's per-tick path: (path, live rule off, live rule 5 deg)."""
    rng = np.random.default_rng(1)
    q = rng.normal(size=(ticks, devices, 4))
    q = (q / np.linalg.norm(q, axis=2, keepdims=True)).astype(np.float32)
    off, on = point_costs(0.0, q, repeats), point_costs(5.0, q, repeats)
    return [(name, off[name], on[name]) for name in off]


def print_point_costs() -> None:
    print("Segment point encoding, emulator path, 2000 devices per tick, ns per point "
          "(beyond SegmenterBank.update())\n")
    print("| path | live rule off (v1) | live rule 5 deg (v2) |")
    print("|---|---:|---:|")
    for name, off, on in point_cost_table():
        print(f"| {name} | {off:.0f} | {on:.0f} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200_000, help="samples per stream")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--points", action="store_true", help="only the segment point encoding table")
    args = parser.parse_args(argv)
    if args.points:
        print_point_costs()
        return 0

    rows = segment_length_table(args.samples, args.repeats)
    print(f"Host speed, batch API, {args.samples} samples, D = 4, single core (ns per sample)\n")
    print("| target length | realised avg length | fastSW ns/sample | SW ns/sample | SW / fastSW |")
    print("|---:|---:|---:|---:|---:|")
    for length, realised, fast, sw in rows:
        print(f"| {length} | {realised:.1f} | {fast:.1f} | {sw:.1f} | {sw / fast:.1f} |")
    at100 = min(rows, key=lambda r: abs(r[1] - 100))
    print(f"\nSW / fastSW at average length {at100[1]:.0f}: {at100[3] / at100[2]:.1f}x\n")
    print(f"fastSW live rule, C kernel (fastsw_segment), the 60 CMU streams one after another to "
          f"{args.samples} samples (50 Hz), TH 1e-3, max_len 25\n")
    print("| live rule | ICR | fastSW ns/sample |")
    print("|---|---:|---:|")
    for name, icr, ns in live_table(args.samples, args.repeats):
        print(f"| {name} | {icr:.3f} | {ns:.1f} |")
    print()
    print("| Python binding path | ns per sample |")
    print("|---|---:|")
    for name, ns in overhead_table(20_000):
        print(f"| {name} | {ns:.0f} |")
    print()
    print_point_costs()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
