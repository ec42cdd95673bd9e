"""Where the aggregator's resident memory goes: RSS and glibc's heap figures over time.

Starts a router and emulator processes on a free loopback port and runs the aggregator in this
process (``--live-rate 0``, as bench/soak.py), so glibc's ``mallinfo2`` can be read: ``in use``
is the live heap, ``free`` what the arenas keep of freed blocks (resident unless trimmed).
With ``--trim`` the aggregator's own trimming (limbstream.heap, every 5 s) is on and each
sample also times one extra ``malloc_trim``; without it the trimming is off.

    python bench/heap.py --subjects 200 --seconds 300            # trimming off
    python bench/heap.py --subjects 200 --seconds 300 --trim
"""
from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import sys
import tempfile
import threading
import time
from pathlib import Path

from limbstream import heap, zconfig
from limbstream.launch import Launcher, free_port, stop_all
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings


class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                      "fsmblks", "uordblks", "fordblks", "keepcost")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subjects", type=int, default=200, help="subjects (10 devices each; default 200)")
    parser.add_argument("--seconds", type=float, default=300.0, help="duration, s (default 300)")
    parser.add_argument("--every", type=float, default=30.0, help="sample period, s (default 30)")
    parser.add_argument("--trim", action="store_true", help="aggregator trims its heap (as deployed)")
    args = parser.parse_args(argv)
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    if not hasattr(libc, "mallinfo2"):
        raise SystemExit("bench/heap.py: needs glibc >= 2.33 (mallinfo2)")
    libc.mallinfo2.restype = MallInfo2

    launcher = Launcher(Path(tempfile.mkdtemp(prefix="limbstream-heap-")))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    launcher.router(endpoint)
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    agg = Aggregator(session, AggregatorSettings(live_rate=0.0, trim_s=5.0 if args.trim else float("inf")))
    agg.open()
    halt = threading.Event()
    loop = threading.Thread(target=agg.run, args=(halt,), daemon=True)
    loop.start()
    half = args.subjects // 2
    emulators = [launcher.start(f"emulator{i}", "emulate", "--connect", endpoint, "--subjects", str(n),
                                "--first-subject", str(first), "--no-truth", "--layout", "paper10")
                 for i, (n, first) in enumerate(((args.subjects - half, 1), (half, args.subjects - half + 1))) if n]
    print(f"heap: {args.subjects} subjects, {args.seconds:g} s, trimming {'on' if args.trim else 'off'}\n")
    print("| t (s) | RSS (MiB) | heap in use (MiB) | heap free, kept (MiB) | mmapped (MiB) | trim (ms) | RSS after trim |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < args.seconds:
            time.sleep(args.every)
            m, mib = libc.mallinfo2(), 2**20
            rss = _self_rss()
            trim = after = ""
            if args.trim:
                t1 = time.perf_counter()
                heap.release_free_heap()
                trim, after = f"{1e3 * (time.perf_counter() - t1):.1f}", f"{_self_rss():.1f}"
            print(f"| {time.monotonic() - t0:.0f} | {rss:.1f} | {m.uordblks / mib:.1f} | {m.fordblks / mib:.1f} | "
                  f"{m.hblkhd / mib:.1f} | {trim} | {after} |", flush=True)
    finally:
        halt.set()
        loop.join(5)
        stop_all(emulators, 20.0)
        agg.close()
        session.close()
        launcher.stop()
    print(f"\naggregator: {agg.loop.pacing.ticks} ticks, {100 * agg.loop.pacing.late / max(agg.loop.pacing.ticks, 1):.2f} % late, "
          f"{agg.loop.missed} missed")
    return 0


def _self_rss() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024


if __name__ == "__main__":
    sys.exit(main())
