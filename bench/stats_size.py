"""Size of the aggregator's stats messages, compact form against the JSON form (docs/protocol.md,
"Per-device statistics"): the aggregator without Zenoh takes in the replayed segment points and
truth of generator subjects (bench/pipeline.py replay_events), builds its frames, and encodes each
subject's stats message as it publishes it; each is measured in both forms.

    python bench/stats_size.py                  # one subject (its 10 devices in each message)
    python bench/stats_size.py --subjects 1,20  # rows for more subjects (messages stay per subject)

Prints a Markdown table; tests/test_wire.py checks that docs/protocol.md quotes its ratio.
"""
from __future__ import annotations

import argparse

import numpy as np
from pipeline import replay_events

from limbstream import wire
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
from limbstream.sources import SEGMENTS

WALL0 = 1_800_000_000.0
"""Wall clock of the replay's start, s (the replayed devices' clocks start there too)."""


def stats_sizes(subjects: int = 1, seconds: float = 10.0) -> tuple[int, int, int]:
    """(devices per message, compact bytes, JSON bytes) of the last round of stats messages of
    ``subjects`` replayed generator subjects after ``seconds`` of stream, summed over the subjects."""
    events, m = replay_events(subjects, seconds)
    agg = Aggregator(None, AggregatorSettings())
    sent: dict[str, bytes] = {}
    agg._publish = lambda subject, payload: None
    agg._publish_stats = lambda subject, payload: sent.__setitem__(subject, payload)
    for name in (f"s{s + 1:03d}" for s in range(subjects)):
        for seg in SEGMENTS:
            agg.fusion.set_online(agg.track(name, seg), True)
    i = 0
    for k in range(m):
        now = k / 50.0
        points, raw = [], []
        while i < len(events) and events[i][0] <= k:
            _, kind, key, payload = events[i]
            (points if kind == 0 else raw).append((key, payload))
            i += 1
        agg.take_points([key for key, _ in points], [payload for _, payload in points], now)
        agg.take_raw([key for key, _ in raw], [payload for _, payload in raw], now)
        agg.advance(True, prune=k % 25 == 0, now=now, wall=WALL0 + now)
    agg.publish_stats(m / 50.0, wall=WALL0 + m / 50.0)
    compact = sum(len(p) for p in sent.values())
    text = sum(len(wire.stats_json(p)) for p in sent.values())
    return len(SEGMENTS), compact, text


def ratio_row(subjects: int, seconds: float) -> str:
    devices, compact, text = stats_sizes(subjects, seconds)
    return f"| {subjects} | {devices} | {compact / subjects:,.0f} | {text / subjects:,.0f} | {compact / text:.2f} |"


HEADER = ("| subjects | devices per message | compact bytes per message | JSON bytes per message | compact / JSON |\n"
          "|---:|---:|---:|---:|---:|")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subjects", default="1", help="rows: subject counts, comma-separated")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of stream replayed before the stats")
    args = parser.parse_args(argv)
    print(HEADER)
    for n in (int(v) for v in args.subjects.split(",")):
        print(ratio_row(n, args.seconds))
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    raise SystemExit(main())
