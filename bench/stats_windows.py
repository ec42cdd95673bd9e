"""CPU of the error windows' summaries in a stats round: what ``Scoring.device_figures`` asks of
its windows once a second for every device (the exact error's p99, the live error's p50 and p99,
the live error against the device's own orientation's p99; mean and max of each), with every
window full (any run longer than the window: 60 s at 50 Hz by default), the round spread over 50
ticks as the aggregator spreads it. Prints a Markdown table (docs/benchmarks.md, "Stats windows").

    python bench/stats_windows.py                     # 200 and 2,000 devices, 3,000-value windows
    python bench/stats_windows.py --devices 2000 --window 1500
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from limbstream.services.aggregator.rings import ErrorRings
from limbstream.services.aggregator.settings import AggregatorSettings

ASKED = ((0.99,), (0.5, 0.99), (0.99,))
"""The quantiles each of the three per-device windows is summarised with (exact, live, live_own)."""


def round_cpu(devices: int, window: int, ticks: int = 50, repeats: int = 5) -> float:
    """Least CPU time of one stats round over ``devices`` full windows of ``window`` values, s."""
    rng = np.random.default_rng(1)
    rings = []
    for _ in ASKED:
        r = ErrorRings(window, rows=devices)
        r.values[:] = rng.gamma(2.0, 1.5, r.values.shape)
        r.count[:] = 2 * window
        rings.append(r)
    slots = np.arange(devices)
    best = np.inf
    for _ in range(repeats):
        start = time.process_time()
        for tick in range(ticks):
            part = slots[tick::ticks]
            for r, quantiles in zip(rings, ASKED):
                r.summary(part, quantiles)
        best = min(best, time.process_time() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    settings = AggregatorSettings()
    parser.add_argument("--devices", type=int, nargs="+", default=[200, 2000])
    parser.add_argument("--window", type=int, default=int(settings.error_window_s * settings.rate),
                        help="values per window (default: the aggregator's, error_window_s x rate)")
    args = parser.parse_args()
    print("| devices | window (values) | CPU per stats round, ms | % of a core at one round a second |")
    print("|---:|---:|---:|---:|")
    for devices in args.devices:
        cpu = round_cpu(devices, args.window)
        print(f"| {devices} | {args.window} | {cpu * 1e3:.1f} | {cpu * 100:.1f} |")


if __name__ == "__main__":
    main()
