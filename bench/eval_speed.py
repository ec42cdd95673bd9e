"""Speed of the offline evaluation (limbstream eval): seconds per algorithm for the paper's sweep.

    python bench/eval_speed.py [PATH ...]     # default: ../shared/data/cmu_10seg_50hz.npz

Prints, per algorithm, the wall time of 206 thresholds (segmentation in C + vectorised SLERP
reconstruction, live error and statistics) and the split between the two; then the time per
threshold of fastSW's live rule with the rate (C) and slope (Python) predictors. Single process.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from limbstream import evaluation, kernel
from limbstream.sources import load

DEFAULT = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "cmu_10seg_50hz.npz"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="*", default=[str(DEFAULT)])
    args = parser.parse_args()
    motions = [m for p in args.paths for m in load(p)]
    streams = evaluation.streams_of(motions)
    pool = evaluation._Pool(streams)
    print(
        f"{len(streams)} streams, {pool.n_samples} samples, {len(evaluation.THRESHOLDS)} thresholds"
    )
    print(f"{'algorithm':<9} {'total s':>8} {'kernel s':>9} {'rest s':>7}")
    grand = 0.0
    for name in evaluation.ALGORITHMS:
        run = kernel.ALGORITHMS[name]
        start = time.perf_counter()
        for th in evaluation.THRESHOLDS:
            for s in streams:
                run(s.t, s.q, th, evaluation.MAX_LEN)
        seg_s = time.perf_counter() - start
        start = time.perf_counter()
        for th in evaluation.THRESHOLDS:
            evaluation.evaluate_threshold(pool, name, th)
        total = time.perf_counter() - start
        grand += total
        print(f"{name:<9} {total:>8.2f} {seg_s:>9.2f} {total - seg_s:>7.2f}")
    print(f"{'all':<9} {grand:>8.2f}")
    for bound, predictor in ((5.0, "rate"), (5.0, "slope")):
        start = time.perf_counter()
        for th in evaluation.THRESHOLDS[::10]:
            evaluation.evaluate_threshold(pool, "fastsw", th, 25, bound, predictor, live=True)
        per_row = (time.perf_counter() - start) / len(evaluation.THRESHOLDS[::10])
        print(f"fastsw, live rule {bound:g} deg, predictor {predictor}, max_len 25: {per_row:.2f} s per threshold")


if __name__ == "__main__":
    main()
