"""Where the emulator's tick goes, by part: the thread CPU of each part of ``Emulator.step`` over
the ticks after a warm-up, for one emulator of generator subjects in this process, beside a router
and a subscriber taking everything in their own processes (as ``bench/pipeline.py emulator``
runs it), printed as a markdown table (docs/benchmarks.md, "The generator's tree by elementary
rotations").

    python bench/emulator_parts.py                              # 1,000 devices, 30 s, no truth tap
    python bench/emulator_parts.py --devices 2000 --truth

A part's time includes the parts it calls (the generator is inside "taking the samples", the puts
inside "the kernel and its points"); "the rest of the loop" is the tick loop's thread less the
step (pacing, the sync's results). Each timer costs about a microsecond. Last, the points put in
those ticks and the thread CPU of each (``bench/put_cost.py``: a put alone).
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import pipeline  # noqa: E402  (the emulator bench's router and subscriber)

from limbstream import wire  # noqa: E402
from limbstream.device.feeds import GeneratorFeed  # noqa: E402
from limbstream.device.host import HostSettings  # noqa: E402
from limbstream.device_emulator.emulator import Emulator, EmulatorSettings  # noqa: E402
from limbstream.device_emulator.main import subject_names  # noqa: E402

WARMUP_TICKS = 600
"""Ticks left out at the start: the first chunk of every subject, made at once, and the first
cross-over to the next."""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", type=int, default=1000)
    parser.add_argument("--seconds", type=float, default=30.0, help="run, including the warm-up (12 s)")
    parser.add_argument("--truth", action="store_true", help="with the truth tap, per subject as `emulate` sends it")
    args = parser.parse_args()
    spent: dict[str, float] = defaultdict(float)

    def timed(obj, name: str, part: str) -> None:
        call = getattr(obj, name)

        def wrapper(*a, **k):
            began = time.thread_time()
            try:
                return call(*a, **k)
            finally:
                spent[part] += time.thread_time() - began
        setattr(obj, name, wrapper)

    with pipeline.Router() as router:
        sink = pipeline.start_sink(router)
        session = pipeline.client(router.endpoint)
        feeds = {name: GeneratorFeed(i + 1, 50.0) for i, name in enumerate(subject_names(args.devices // 10))}
        emulator = Emulator(session, feeds, EmulatorSettings(HostSettings(
            truth=args.truth, truth_by_subject=True, config=wire.DeviceConfig().validate())))
        emulator.declare()
        parts = [(emulator, "step", "the step"), (emulator, "_take", "taking the samples"),
                 (emulator._feed_rows, "rows", "the feeds' samples"),
                 (emulator.bank, "update", "the kernel and its points"),
                 (emulator.host, "publish_points", "the points' puts"), (emulator, "_tap", "the truth tap"),
                 (emulator.host, "answer_queries", "config queries")]
        parts += [(f.source, "chunk", "the generator") for f in feeds.values()]
        if emulator.sync is not None:
            parts.append((emulator.sync, "stamp", "stamps (time sync)"))
        for obj, name, part in parts:
            timed(obj, name, part)
        puts = emulator.host.publish_points

        def counted_puts(slots, payload, ends):
            spent["puts"] += len(slots)  # (a count, not seconds)
            return puts(slots, payload, ends)
        emulator.host.publish_points = counted_puts  # type: ignore[method-assign]
        start: dict[str, float] = {}
        tick = emulator._tick

        def counted(k: int, now: float) -> bool:
            if k == WARMUP_TICKS:
                spent.clear()
                start["cpu"], start["k"] = time.thread_time(), k
            return tick(k, now)
        emulator._tick = counted  # type: ignore[method-assign]
        stop = threading.Event()
        threading.Timer(args.seconds, stop.set).start()
        ticks = emulator.run(stop).ticks - WARMUP_TICKS
        loop = time.thread_time() - start["cpu"] if start else 0.0
        emulator.undeclare()
        session.close()
        pipeline.stop_all([sink])
    if ticks <= 0:
        raise SystemExit(f"no ticks after the warm-up: run longer than {WARMUP_TICKS / 50:g} s")
    print(f"\n### The emulator's tick by part ({args.devices} devices, {ticks} ticks after {WARMUP_TICKS}, "
          f"truth tap {'on' if args.truth else 'off'})\n")
    count = spent.pop("puts", 0.0)
    print("| part | ms per tick | % of the tick loop's thread |")
    print("|---|---:|---:|")
    rows = [("the tick loop's thread", loop), *sorted(spent.items(), key=lambda item: -item[1]),
            ("the rest of the loop", loop - spent["the step"])]
    for part, seconds in rows:
        print(f"| {part} | {1e3 * seconds / ticks:.3f} | {100 * seconds / loop:.0f} |")
    if count:
        each = spent["the points' puts"] / count
        print(f"\n{count:.0f} points put, {1e6 * each:.1f} us of the thread each")
    return 0


if __name__ == "__main__":
    sys.exit(main())
