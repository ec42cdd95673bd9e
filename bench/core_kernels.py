"""What four of the aggregator's jobs cost, alone (docs/benchmarks.md, "Three core runs a
revision"): decoding a drain's truth-tap batches, the truth's errors against the points, the exact
frames' reconstruction tick after tick, and the stats' order statistics of the error windows.

    python bench/core_kernels.py

Each figure is the best of ``--rounds`` runs in this process, on synthetic data shaped as the core
bench's (2,000 devices; truth batches of 25 samples; windows of 3,000 values, a minute at 50 Hz).
Run it on two revisions (e.g. in a worktree of each) to compare them.
"""
from __future__ import annotations

import argparse

import numpy as np
from generator_cost import best  # (bench/ is the script's folder)

from limbstream import wire
from limbstream.services.aggregator.rings import ErrorRings
from limbstream.services.aggregator.store import PointStore

T0 = 1_790_000_000_000_000


def unit(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    q = rng.normal(size=(*shape, 4))
    return (q / np.linalg.norm(q, axis=-1, keepdims=True)).astype(np.float32)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=9)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    d = args.devices

    payloads = [wire.encode_raw(wire.RawBatch(1, 0, T0 + np.arange(25) * 20_000, unit(rng, (25,)))) for _ in range(d)]
    decode = best(args.rounds, lambda: wire.decode_raws(payloads))

    store = PointStore(128)
    for r in range(d):
        store.add_slot()
        t = T0 + np.cumsum(rng.integers(20_000, 400_000, 60))
        for tk, q, w in zip(t, rng.normal(size=(60, 4)), rng.normal(size=(60, 3))):
            store.append(r, int(tk), q, w)
    slots = np.repeat(np.arange(d), 25)  # a device's truth batch: 25 consecutive samples
    t_us = store.t[slots, 10] + np.tile(np.arange(25) * 20_000, d)
    truth = unit(rng, (len(slots),))
    errors = best(args.rounds, lambda: store.errors(slots, t_us, truth))

    every, ticks = np.arange(d), 20
    within = store.t[:, 30] + 1_000 * np.arange(ticks)[:, None]  # 20 ticks' times, 1 ms apart: within one span
    frames = best(args.rounds, lambda: [store.interpolate(every, within[k]) for k in range(ticks)])

    print(f"\n| job | {d:,} devices |\n|---|---:|")
    print(f"| decode_raws, one batch of 25 samples per device | {1e3 * decode:.2f} ms |")
    print(f"| the truth's errors (runs of 25 samples a device) | {1e9 * errors / len(slots):.0f} ns per sample |")
    print(f"| exact frames' SLERP, every device at a tick's time, {ticks} ticks in turn | "
          f"{1e9 * frames / (ticks * d):.0f} ns per device |")
    rows = np.arange(d // 5)  # a stats batch: a fifth of the devices
    for held in (3000, 1000, 300):
        rings = ErrorRings(3000, rows=d)
        rings.values[:, :held] = rng.gamma(2.0, 1.0, (d, held)).astype(np.float32)
        rings.count[:] = 5000 if held == 3000 else held
        p99 = best(args.rounds, lambda rings=rings: rings.summary(rows, (0.99,)))
        both = best(args.rounds, lambda rings=rings: rings.summary(rows, (0.5, 0.99)))
        print(f"| window summaries of {len(rows)} rows holding {held:,} values: p99 / p50 and p99 | "
              f"{1e3 * p99:.2f} / {1e3 * both:.2f} ms |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
