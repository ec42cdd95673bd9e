"""Where the aggregator's time goes, by part: a py-spy profile (``--format raw``) summed over
the parts of its work and printed as a markdown table (docs/benchmarks.md, "The aggregator,
three times cheaper").

    py-spy record --format raw -o core.txt -- python bench/pipeline.py core --subjects 200 --live-rate 50
    python bench/profile_parts.py core.txt
    py-spy record --nonblocking --format raw -d 20 -p <aggregator pid> -o soak.txt   # a soak's aggregator, 20 s
    python bench/profile_parts.py soak.txt

Attach to a live process with ``--nonblocking``: without it py-spy stops the process for every sample,
and a soak it watches runs late for that (2,000 devices, every frame heard: 36-51 % of the
aggregator's ticks late with py-spy attached, 0.5-3.9 % in two runs without).

A sample counts toward the first part (in the order of PARTS) that one of its frames names; the
shares are of the samples in the aggregator's own work (the core bench's preparation of its
messages, and the loop's waiting, are left out).
"""
from __future__ import annotations

import argparse
import collections
import sys

PARTS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("stats (figures, encoding, publishing)", ("publish_stats", "subject_stats", "encode_stats")),
    ("truth evaluation", ("evaluate_truth", "evaluate_frames")),
    ("publishing frames (encoding, puts)", ("_publish_frames", "_publish ", "PoseFrames.encode")),
    ("exact and live frames", ("exact_frames", "live_frames", "Fusion.tick", "FrameBuilder")),
    ("drain: points and truth batches taken in", ("drain", "on_point", "on_raw", "take_points", "take_raw")),
    ("pruning", ("prune",)),
)
"""Each part of the work and the function names (as py-spy writes them, part of the frame) that
mark a sample as its; frames with several match the first part listed."""
WORK = ("Aggregator.run", "bench_aggregator_core")
IDLE = ("Event.wait", "Condition.wait", "replay_events", "Aggregator.track", "set_online")


def parts(path: str) -> tuple[collections.Counter, int]:
    """Samples per part of a raw py-spy profile, and the samples of the work in all."""
    counts: collections.Counter = collections.Counter()
    total = 0
    with open(path) as f:
        for line in f:
            stack, _, n = line.rstrip("\n").rpartition(" ")
            frames = stack.split(";")
            if not any(w in frame for frame in frames for w in WORK) or any(
                    i in frame for frame in frames for i in IDLE):
                continue
            total += int(n)
            name = next((part for part, marks in PARTS
                         if any(m in frame for frame in frames for m in marks)), "other (the loop itself)")
            counts[name] += int(n)
    return counts, total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("profiles", nargs="+", help="py-spy raw profiles (one column each)")
    parser.add_argument("--cpu", type=float, nargs="+", default=(),
                        help="each profile's CPU in all, % of a core: the parts then in % of a core too")
    args = parser.parse_args(argv)
    results = [parts(p) for p in args.profiles]
    names = [name for name, _ in PARTS] + ["other (the loop itself)"]
    cpu = list(args.cpu) + [None] * (len(results) - len(args.cpu))

    def cell(count: int, total: int, of: float | None) -> str:
        share = count / max(total, 1)
        return f"{100 * share:.0f} %" + ("" if of is None else f" ({share * of:.1f} % of a core)")

    print("| part | " + " | ".join(args.profiles) + " |")
    print("|---|" + "---:|" * len(results))
    for name in names:
        print(f"| {name} | " + " | ".join(cell(c[name], t, of) for (c, t), of in zip(results, cpu)) + " |")
    print("| samples | " + " | ".join(str(t) for _, t in results) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
