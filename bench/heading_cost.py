"""What heading correction costs the aggregator (docs/evaluation.md, "Heading without resets"):
the time of one tick of :class:`limbstream.heading.HeadingCorrection` for 1 to 200 subjects of
ten devices each, fed tick by tick as the aggregator would, and the share of one core that is at
50 Hz. The built-in motion, a different subject per row of the arrays:

    python bench/heading_cost.py [--seconds 20] [--subjects 1 10 50 200]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from limbstream.heading import HeadingCorrection
from limbstream.heading.joints import Layout
from limbstream.sources.generator import generate
from limbstream.wire import SEGMENTS

FS = 50.0


def cost(subjects: int, seconds: float) -> tuple[float, float]:
    """(mean, p99) milliseconds of one tick for ``subjects`` subjects (after a warm-up second)."""
    motions = [generate(seconds + 1.0, FS, seed=s).q for s in range(min(subjects, 8))]
    q = np.stack([motions[s % len(motions)] for s in range(subjects)], axis=1)  # (n, B, 10, 4)
    present = np.ones(q.shape[1:3], bool)
    est = HeadingCorrection(Layout.of(SEGMENTS, "standing"), subjects, FS)
    warm = round(FS)
    times = []
    for k in range(len(q)):
        began = time.perf_counter()
        est.update(q[k], present)
        if k >= warm:
            times.append(time.perf_counter() - began)
    ms = 1e3 * np.array(times)
    return float(ms.mean()), float(np.percentile(ms, 99))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="ticks timed per row, s of motion (default 20)")
    parser.add_argument("--subjects", type=int, nargs="+", default=[1, 10, 50, 200])
    args = parser.parse_args(argv)
    print(f"ten devices per subject, {FS:g} Hz ticks, {args.seconds:g} s timed per row (a block of "
          "ticks is measured every 0.2 s: the p99 is that tick)\n")
    print("| subjects | tick mean (ms) | tick p99 (ms) | one core at 50 Hz (%) |")
    print("|---:|---:|---:|---:|")
    for n in args.subjects:
        mean, p99 = cost(n, args.seconds)
        print(f"| {n} | {mean:.3f} | {p99:.2f} | {mean * FS / 10:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
