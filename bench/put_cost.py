"""What one put costs the publishing thread: a plain publisher against a device's segment point
publisher (Zenoh's advanced publisher with its cache, miss detection and publisher detection:
``limbstream.device.io.point_publisher``), each ``--publishers`` of them putting a 48-byte point in
turn, through a router to a subscriber of everything, printed as a markdown table
(docs/benchmarks.md, "The generator's tree by elementary rotations").

    python bench/put_cost.py
    python bench/put_cost.py --publishers 2000 --rounds 20

Thread CPU per put, the best of ``--repeats`` passes of ``--rounds`` puts by every publisher, after
one pass to warm up; the router and the subscriber run in this process on Zenoh's threads.
"""
from __future__ import annotations

import argparse
import sys
import time

from limbstream import wire, zconfig
from limbstream.device import io
from limbstream.launch import free_port

POINT = bytes(48)
"""A segment point's size on the wire (docs/benchmarks.md, "Wire census")."""


def cost_us(publishers: list, rounds: int, repeats: int) -> float:
    """The least thread CPU per put over ``repeats`` passes, us."""
    for p in publishers:
        p.put(POINT)
    best = float("inf")
    for _ in range(repeats):
        began = time.thread_time()
        for _ in range(rounds):
            for p in publishers:
                p.put(POINT)
        best = min(best, (time.thread_time() - began) / (rounds * len(publishers)))
    return 1e6 * best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--publishers", type=int, default=1000)
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zconfig.open_session(zconfig.ZenohSettings(mode="router", listen=(endpoint,)))
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    sink = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    try:
        sink.declare_subscriber("bench/**", lambda sample: None)
        plain = [session.declare_publisher(f"bench/p{i:04d}/seg", **zconfig.publisher_options(wire.SEG))
                 for i in range(args.publishers)]
        points = [io.point_publisher(session, f"a{i:04d}", "seg", 512, 2.0) for i in range(args.publishers)]
        print(f"\n### One put's thread CPU ({args.publishers} publishers, best of {args.repeats} passes of "
              f"{args.rounds} puts each)\n")
        print("| publisher | us per put |")
        print("|---|---:|")
        print(f"| plain (`declare_publisher`, the points' QoS) | {cost_us(plain, args.rounds, args.repeats):.2f} |")
        print(f"| a device's points (`io.point_publisher`: cache 512, miss detection, publisher detection) | "
              f"{cost_us(points, args.rounds, args.repeats):.2f} |")
    finally:
        for s in (sink, session, router):
            s.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
