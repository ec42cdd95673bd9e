"""Live mode through a real router, against the truth tap.

Starts a router, an aggregator (live frames at 50 Hz) and one emulator per live bound (subject
s01 runs the first bound, s02 the second, ...), all streaming the same motion once in real time
(``--speed 1``, so the live latency compares the aggregator's wall clock with device times on the
same base), and prints per bound the aggregator's per-device figures once every device finished:

    python bench/live.py --source ../shared/data/cmu_10seg_50hz.npz --bounds 0,2,5

live mean: mean over devices of live_err_deg; live p99 / max: the worst device's live_p99_deg /
live_max_deg; latency p50: median over devices of live_latency_p50_ms, p99: the worst device's
live_latency_p99_ms; ICR: points / samples over the subject; AAD: exact frames, mean over devices.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import zenoh

from limbstream import wire, zconfig
from limbstream.launch import Launcher, free_port, wait_until



def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--source", default="generator", help="motion file (played once) or 'generator'")
    parser.add_argument("--bounds", default="0,5", help="live bounds, degrees, comma-separated (0: off)")
    parser.add_argument("--threshold", default="1e-2")
    parser.add_argument("--max-len", default="25")
    parser.add_argument("--seconds", type=float, default=30.0, help="generator: device seconds to stream")
    parser.add_argument("--speed", default="1", help="time scale (latency is meaningful at 1 only)")
    args = parser.parse_args()
    bounds = [float(b) for b in args.bounds.split(",")]
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as tmp, Launcher(logdir=Path(tmp)) as launcher:
        launcher.router(endpoint)
        launcher.start("aggregator", "aggregate", "--connect", endpoint, "--live-rate", "50")
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        sub = session.declare_subscriber(wire.subject_selector("stats"), zenoh.handlers.FifoChannel(4096))
        probes = [session.declare_publisher(wire.seg_key(f"s{i + 1:02d}", "hip")) for i in range(len(bounds))]
        wait_until(lambda: all(p.matching_status.matching for p in probes), 30, "the aggregator's subscriptions",
                   on_fail=launcher.logs)
        source = ["--source", args.source, "--once"] if args.source != "generator" else [
            "--duration", str(args.seconds)]
        for i, bound in enumerate(bounds):
            launcher.start(f"emulator{i}", "emulate", "--connect", endpoint, "--subjects", "1",
                           "--first-subject", str(i + 1), "--speed", args.speed, "--threshold", args.threshold,
                           "--max-len", args.max_len, "--live-bound-deg", str(bound), *source,
                           *(["--layout", "paper10"] if args.source == "generator" else []))
        devices: dict[str, dict] = {}

        def done():
            while (sample := sub.try_recv()) is not None:
                for d in wire.decode_stats(sample.payload.to_bytes())["devices"]:
                    devices[d["device"]] = d
            finished = [d for d in devices.values() if (d["final"] or d["samples"] and args.source == "generator"
                        and d["samples"] >= args.seconds * 50 - 1) and d["live_bound_deg"] is not None]
            return len(finished) == 10 * len(bounds)
        wait_until(done, 120 + 2 * args.seconds, "every device to finish", on_fail=launcher.logs)
        session.close()
    print(f"source {args.source}, TH {args.threshold}, max_len {args.max_len}, speed {args.speed}, live frames 50 Hz")
    print(f"{'bound':>6} {'ICR':>7} {'AAD':>6} {'live mean':>9} {'live p99':>8} {'live max':>8} "
          f"{'lat p50 ms':>10} {'lat p99 ms':>10}")
    for i, bound in enumerate(bounds):
        mine = [d for k, d in devices.items() if k.startswith(f"s{i + 1:02d}/")]
        icr = sum(d["points"] for d in mine) / sum(d["samples"] for d in mine)
        print(f"{bound:>6g} {icr:>7.4f} {statistics.mean(d['aad_all_deg'] for d in mine):>6.3f} "
              f"{statistics.mean(d['live_err_deg'] for d in mine):>9.3f} {max(d['live_p99_deg'] for d in mine):>8.3f} "
              f"{max(d['live_max_deg'] for d in mine):>8.3f} "
              f"{statistics.median(d['live_latency_p50_ms'] for d in mine):>10.2f} "
              f"{max(d['live_latency_p99_ms'] for d in mine):>10.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
