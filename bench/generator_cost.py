"""What the built-in generator's motion costs the emulator (docs/benchmarks.md, "The emulator"):
a subject's chunk by its length, and its elementary rotations by ``quat.about_axes`` against
scipy's ``Rotation.from_rotvec``, which it replaced bit for bit.

    python bench/generator_cost.py
    python bench/generator_cost.py --subjects 10 --rounds 5

Each figure is the best of ``--rounds`` over ``--subjects`` subjects (seeds 1..N, paper10, each at
its own place in its schedule: :data:`START`), in this process, after one chunk each to warm up.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream import quat
from limbstream.sources.generator import GeneratorSource

LENGTHS = (250, 500, 1000, 3000)
"""Chunk lengths, samples (the emulator's chunk: 10 s at 50 Hz, 500)."""
START, SPREAD = 10_000, 1_237
"""Subject i's chunk starts at sample START + i * SPREAD: the subjects at different places in their
activity schedules (a cross-fade between two activities costs both)."""


def best(rounds: int, run) -> float:
    """The shortest of ``rounds`` runs of ``run()``, s."""
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subjects", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    sources = [GeneratorSource(seed=s + 1, fs=50.0) for s in range(args.subjects)]
    for source in sources:
        source.chunk(0, 100)
    print(f"\n### A subject's chunk ({args.subjects} subjects, best of {args.rounds})\n")
    print("| samples | ms per chunk | us per sample |")
    print("|---:|---:|---:|")
    for n in LENGTHS:
        seconds = best(args.rounds, lambda n=n: [s.chunk(START + i * SPREAD, n) for i, s in enumerate(sources)]) \
            / len(sources)
        print(f"| {n} | {1e3 * seconds:.2f} | {1e6 * seconds / n:.2f} |")
    rng = np.random.default_rng(0)
    angle = rng.uniform(-np.pi, np.pi, (21, 500))  # a chunk's elementary rotations: 21 joints, 500 samples
    axis = rng.integers(0, 3, 21)

    def scipy_way() -> np.ndarray:
        rotvec = angle[:, :, None] * np.eye(3)[axis][:, None, :]
        return quat.from_rotation(Rotation.from_rotvec(rotvec.reshape(-1, 3))).reshape(21, -1, 4)

    same = np.array_equal(quat.about_axes(angle, axis), scipy_way())
    print(f"\n### A chunk's elementary rotations (21 x 500, best of {10 * args.rounds})\n")
    print("| way | ms | the same bits |")
    print("|---|---:|---|")
    print(f"| scipy `Rotation.from_rotvec` | {1e3 * best(10 * args.rounds, scipy_way):.3f} | |")
    print(f"| `quat.about_axes` | {1e3 * best(10 * args.rounds, lambda: quat.about_axes(angle, axis)):.3f} | "
          f"{'yes' if same else 'NO'} |")
    x = rng.uniform(-10.0, 10.0, 200_000)  # radians, as the half-angles and the activities' phases
    libm = (np.array_equal(np.sin(x), [math.sin(v) for v in x]) and np.array_equal(np.cos(x), [math.cos(v) for v in x]))
    print(f"\nNumPy's float64 sin and cos equal the C library's (`math`) on {len(x):,} values in -10..10 rad: "
          f"{'yes' if libm else 'NO'} (numpy {np.__version__}; the tree in C, firmware_c/host/lsw_gen.c, gives the numpy code's bits only if they do)")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
