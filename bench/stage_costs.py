"""The aggregator's CPU per device, stage by stage, in the core bench (``bench/pipeline.py core``)
of each layout given, printed side by side as a markdown table (docs/benchmarks.md, "The whole
body and root translation").

    python bench/stage_costs.py                                  # paper10 then full, 200 subjects each
    python bench/stage_costs.py --subjects 200 134 --seconds 20  # the same devices: 2,000 and 2,010

Each stage's own CPU time (``time.process_time``, the stages it calls left out) over the bench's
measured loop, in microseconds of CPU per second of stream per device; "the rest" is what no
stage listed holds (the bench's loop, the glue of a tick). The timers cost about 1 % of the total.
"""
from __future__ import annotations

import argparse
import functools
import importlib
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import pipeline  # noqa: E402  (bench/pipeline.py: the core bench)

STAGES = (
    ("intake", "Intake", ("take_points", "take_raw")),
    ("fusion", "Fusion", ("evaluate_truth", "device_view", "prune", "stats_table")),
    ("frames", "FrameBuilder", ("start", "plan_exact", "exact_flags", "plan_live", "build", "positions")),
    ("store", "PointStore", ("reconstruct",)),
    ("rooting", "Rooting", ("place",)),
    ("scoring", "Scoring", ("score_later", "evaluate_frames", "add_latency")),
    ("angles", "JointStage", ("__call__",)),
    ("aggregator", "Aggregator", ("_publish_frames", "_subject_fields", "publish_stats")),
)
"""(module of limbstream.services.aggregator, class, methods) timed."""
OTHER = (("limbstream.body.translation", "BodyPoints", ("positions",)),
         ("limbstream.body.translation", "RootTracker", ("frames",)),
         ("limbstream.wire.pose", "PoseFrames", ("encode",)))


class Timers:
    """Each wrapped method's own CPU time while ``on``."""

    def __init__(self) -> None:
        self.own: dict[str, float] = {}
        self.on = False
        self._stack: list[float] = []

    def wrap(self, owner: type, name: str) -> None:
        f = getattr(owner, name)
        label = f"{owner.__name__}.{name}"

        @functools.wraps(f)
        def timed(*args, **kwargs):
            if not self.on:
                return f(*args, **kwargs)
            start = time.process_time()
            self._stack.append(0.0)
            try:
                return f(*args, **kwargs)
            finally:
                spent, inner = time.process_time() - start, self._stack.pop()
                self.own[label] = self.own.get(label, 0.0) + spent - inner
                if self._stack:
                    self._stack[-1] += spent
        setattr(owner, name, timed)


def timed() -> Timers:
    """Timers on every stage of :data:`STAGES` and :data:`OTHER`."""
    timers = Timers()
    for module, cls, names in STAGES:
        owner = getattr(importlib.import_module(f"limbstream.services.aggregator.{module}"), cls)
        for name in names:
            timers.wrap(owner, name)
    for module, cls, names in OTHER:
        for name in names:
            timers.wrap(getattr(importlib.import_module(module), cls), name)
    return timers


def measure(timers: Timers, layout: str, subjects: int, seconds: float) -> tuple[dict[str, float], int]:
    """{stage: us of CPU per second of stream per device} of one core bench run, and its devices."""
    timers.own = {}
    marks: list[float] = []
    cpu_now = pipeline.cpu_now

    def marked() -> float:  # the bench reads the clock at the start and the end of its measured loop
        marks.append(cpu_now())
        timers.on = len(marks) % 2 == 1
        return marks[-1]
    pipeline.cpu_now = marked
    try:
        pipeline.bench_aggregator_core([subjects], seconds, layout=layout)
    finally:
        pipeline.cpu_now = cpu_now
    devices = subjects * len(pipeline.builtin_layout(layout).segments)
    scale = 1e6 / seconds / devices
    out = {label: own * scale for label, own in timers.own.items()}
    out["the rest"] = (marks[1] - marks[0]) * scale - sum(out.values())
    out["total"] = (marks[1] - marks[0]) * scale
    return out, devices


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layouts", nargs="+", default=["paper10", "full"], choices=["paper10", "full"])
    parser.add_argument("--subjects", nargs="+", type=int, default=[200], help="per layout (one: all alike)")
    parser.add_argument("--seconds", type=float, default=10.0, help="of stream per run (default 10)")
    args = parser.parse_args(argv)
    subjects = args.subjects * len(args.layouts) if len(args.subjects) == 1 else args.subjects
    timers = timed()
    runs = [measure(timers, layout, n, args.seconds) for layout, n in zip(args.layouts, subjects)]
    names = sorted({k for r, _ in runs for k in r if k not in ("the rest", "total")},
                   key=lambda k: -max(r.get(k, 0.0) for r, _ in runs)) + ["the rest", "total"]
    print(f"\n| stage (us of CPU per second of stream per device) | "
          f"{' | '.join(f'{lay}, {d:,} devices' for lay, (_, d) in zip(args.layouts, runs))} |")
    print("|---|" + "---:|" * len(runs))
    for name in names:
        print(f"| {name} | {' | '.join(f'{r.get(name, 0.0):.1f}' for r, _ in runs)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
