"""Peak memory of an emulator's motion feeds: ``emulate --source CLIP``'s feeds made for N subjects,
each configuration in a process of its own, its peak RSS printed as a table (docs/evaluation.md,
"Root translation": a BVH walk plays looped on its own cycle, its subjects sharing its samples).

    python bench/feed_memory.py                                  # 131_01, 1 and 200 subjects, 50 with raw sensors
    python bench/feed_memory.py --source ../shared/data/cmu/02_01.bvh --subjects 1 100
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / ".." / "shared" / "data" / "cmu" / "131_01.bvh"

ONE = """
import argparse, resource, sys
from limbstream.cli import emulate
parser = argparse.ArgumentParser()
emulate.add_arguments(parser)
emulate.build_feeds(parser.parse_args(sys.argv[1:]))
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024)
"""


def peak_mib(*argv: str) -> int:
    """The peak RSS, MiB, of a process that makes ``emulate``'s feeds of ``argv``."""
    out = subprocess.run([sys.executable, "-c", ONE, *argv], check=True, capture_output=True, text=True)
    return int(out.stdout.split()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default=str(CLIP))
    parser.add_argument("--layout", default="full")
    parser.add_argument("--subjects", type=int, nargs="+", default=[1, 200])
    parser.add_argument("--raw-subjects", type=int, nargs="*", default=[50], help="rows with --imu raw")
    args = parser.parse_args()
    rows = [(n, ()) for n in args.subjects] + [(n, ("--imu", "raw")) for n in args.raw_subjects]
    print(f"\n### Feeds of {Path(args.source).name}, layout {args.layout}: peak RSS, MiB\n")
    print("| subjects | sensors | looped (the default) | --once |")
    print("|---:|---|---:|---:|")
    for n, extra in rows:
        base = ("--source", args.source, "--layout", args.layout, "--subjects", str(n), *extra)
        print(f"| {n} | {'raw' if extra else 'orientations'} | {peak_mib(*base)} | {peak_mib(*base, '--once')} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
