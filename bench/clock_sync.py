"""Device clocks and time sync: what the exchange costs, and what clocks do to the frames.

``cost``: two stacks side by side, each an emulator process of ``--devices`` devices (no truth
tap) and its own router, one with the time exchange (and a time service), one without; the CPU
of every process over ``--measure`` seconds after ``--warmup`` (the devices' poll intervals have
grown by then) and the exchanges answered per second. The sync's cost is the difference
(emulator and router) plus the time service.

``hour``: ``--subjects`` subjects for ``--hours`` of device time at ``--speed``, once per clock
setup (perfect clocks; +-2 s / +-100 ppm with sync; the same without sync; no offset but +-100
ppm without sync), the same motion each time; the subjects' alignment-aware frame error
(``frame_aad_deg``, 60 s window) over device time, and for the synced run each sample's
timestamp error against its reference time.

    python bench/clock_sync.py cost                   # 2 x 2,000 devices, 3 + 2 minutes
    python bench/clock_sync.py hour                   # 1 hour at --speed 20 (about 3.5 min per setup)
"""
from __future__ import annotations

import argparse
import collections
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import zenoh  # noqa: E402

from limbstream import wire, zconfig  # noqa: E402
from limbstream.cli.launch import Launcher, free_port  # noqa: E402

sys.path.insert(0, str(ROOT / "bench"))
from soak import cpu_s  # noqa: E402

SETUPS = {
    "perfect": [],
    "synced": ["--clock-offset-ms", "2000", "--clock-drift-ppm", "100"],
    "unsynced": ["--clock-offset-ms", "2000", "--clock-drift-ppm", "100", "--no-sync"],
    "drift-only": ["--clock-drift-ppm", "100", "--no-sync"],
}


def answered(log: Path) -> list[tuple[float, int]]:
    """(log time, answered so far) from a time service's -v lines."""
    out = []
    for m in re.finditer(r"^(\S+ \S+) limbstream\.clock answered (\d+)", log.read_text(), re.M):
        out.append((time.mktime(time.strptime(m[1].split(",")[0], "%Y-%m-%d %H:%M:%S")), int(m[2])))
    return out


def cost(args) -> int:
    """Two independent stacks side by side over the same minutes, so that both see the same load
    from the rest of the machine: A (router, time service, emulator with sync) and B (router,
    emulator without sync); the sync's cost is A's CPU minus B's."""
    with tempfile.TemporaryDirectory(prefix="clock-bench-") as tmp, Launcher(logdir=Path(tmp)) as launcher:
        stacks = {}
        for name, sync in (("A", True), ("B", False)):
            endpoint = f"tcp/127.0.0.1:{free_port()}"
            router = launcher.router(endpoint)
            clock = launcher.start(f"clock{name}", "clock", "--connect", endpoint, "-v") if sync else None
            stacks[name] = {"router": router, "clock": clock, "endpoint": endpoint}
        time.sleep(1.0)
        for name, sync in (("A", True), ("B", False)):
            stacks[name]["emulator"] = launcher.start(
                f"emulate{name}", "emulate", "--connect", stacks[name]["endpoint"], "--subjects",
                str(args.devices // 10), "--no-truth", *(["--sync-poll-s", f"{args.poll:g}"] if sync else ["--no-sync"]))
        time.sleep(args.warmup)
        procs = {(n, k): p for n, st in stacks.items() for k, p in st.items() if k != "endpoint" and p is not None}
        before = {k: cpu_s(p.pid) for k, p in procs.items()}
        t0, wall0 = time.monotonic(), time.time()
        time.sleep(args.measure)
        after = {k: cpu_s(p.pid) for k, p in procs.items()}
        span, wall1 = time.monotonic() - t0, time.time()
        for st in stacks.values():
            st["emulator"].signal(15)
        for st in stacks.values():
            st["emulator"].popen.wait(60)
        texts = {n: Path(st["emulator"].log).read_text() for n, st in stacks.items()}
        text = texts["A"]
        counts = [c for c in answered(Path(stacks["A"]["clock"].log)) if wall0 - 1 <= c[0] <= wall1 + 1]
    cpu = {k: 100 * (after[k] - before[k]) / span for k in after}
    rate = (counts[-1][1] - counts[0][1]) / max(counts[-1][0] - counts[0][0], 1) if len(counts) >= 2 else 0.0
    late = {n: re.search(r"emulator: \d+ ticks, ([\d.]+) % late", t) for n, t in texts.items()}
    late = {n: m[1] if m else "?" for n, m in late.items()}
    started = re.search(r"time sync: (\d+)/(\d+) devices synced at start", text)
    inside = re.search(r"CPU: workers ([\d.]+) s, tick loop ([\d.]+) s", text)
    print(f"\n{args.devices} devices per emulator process; A with sync (--sync-poll-s {args.poll:g}), B without, "
          f"side by side; CPU over "
          f"{args.measure:g} s after a {args.warmup:g} s warm-up (% of one core)\n")
    print("| stack | emulator | time service | router | exchanges/s | per device | late ticks (whole run) |")
    print("|---|---|---|---|---|---|---|")
    print(f"| A (sync) | {cpu['A', 'emulator']:.1f} | {cpu['A', 'clock']:.2f} | {cpu['A', 'router']:.2f} | {rate:.1f} | "
          f"{rate / args.devices:.4f} /s | {late['A']} % |")
    print(f"| B | {cpu['B', 'emulator']:.1f} | – | {cpu['B', 'router']:.2f} | – | – | {late['B']} % |")
    extra = cpu["A", "emulator"] - cpu["B", "emulator"] + cpu["A", "router"] - cpu["B", "router"]
    total = extra + cpu["A", "clock"]
    print(f"\nsync costs {total:.2f} % of a core for {args.devices} devices: emulator {cpu['A', 'emulator'] - cpu['B', 'emulator']:+.2f}, "
          f"router {cpu['A', 'router'] - cpu['B', 'router']:+.2f}, time service {cpu['A', 'clock']:.2f}; "
          f"{1e4 * total / max(rate, 1e-9):.0f} us per exchange")
    if inside:
        print(f"emulator A's own accounting over its whole run (start included): worker threads {inside[1]} s, "
              f"tick loop (results, stamps) {inside[2]} s")
    if started:
        print(started[0])
    return 0


class Watch:
    """Stats of the subjects (frame error over device time) and, for some, truth-tap errors."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.stats = self.session.declare_subscriber(wire.subject_selector("stats"), zenoh.handlers.FifoChannel(1 << 14))
        self.raw = self.session.declare_subscriber(wire.device_selector("raw"), zenoh.handlers.FifoChannel(1 << 16))
        self.series: dict[str, list] = collections.defaultdict(list)  # subject -> (watermark us, frame_aad)
        self.errors: dict[str, list] = collections.defaultdict(list)  # device -> (ref us, stamp - ref us)

    def poll(self) -> None:
        while (s := self.stats.try_recv()) is not None:
            d = wire.decode_stats(s.payload.to_bytes())
            if d.get("watermark_us") and d.get("frame_aad_deg") is not None:
                self.series[d["subject"]].append((d["watermark_us"], d["frame_aad_deg"], d.get("frame_error_frames")))
        while (s := self.raw.try_recv()) is not None:
            subject, segment, _ = wire.parse_device_key(str(s.key_expr))
            b = wire.decode_raw(s.payload.to_bytes())
            if b.ref_us is not None:
                self.errors[f"{subject}/{segment}"].append((int(b.ref_us[-1]), int(b.t_us[-1] - b.ref_us[-1])))

    def close(self) -> None:
        self.session.close()


def hour_run(name: str, flags: list[str], args, workdir: Path) -> dict:
    anchor = time.time()
    workdir.mkdir(parents=True, exist_ok=True)
    with Launcher(logdir=workdir) as launcher:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        launcher.router(endpoint)
        speed = ["--speed", f"{args.speed:g}", "--time-anchor", f"{anchor:.3f}"]
        launcher.start("clock", "clock", "--connect", endpoint, *speed)
        launcher.start("aggregate", "aggregate", "--connect", endpoint)
        watch = Watch(endpoint)
        time.sleep(1.0)
        start_us = anchor * 1e6 + args.speed * (time.time() - anchor) * 1e6
        emulator = launcher.start("emulate", "emulate", "--connect", endpoint, "--subjects", str(args.subjects),
                                  "--source", args.source, "--duration", f"{args.hours * 3600:g}", *speed, *flags)
        end_us = start_us + args.hours * 3600e6 - 5e6
        deadline = time.monotonic() + args.hours * 3600 / args.speed + 120

        def done() -> bool:
            return len(watch.series) == args.subjects and all(s[-1][0] >= end_us for s in watch.series.values())
        while emulator.alive() and time.monotonic() < deadline and not done():
            watch.poll()
            time.sleep(0.05)
        watch.poll()
        watch.close()
    text = Path(emulator.log).read_text()  # (stopped: its last line is out)
    late = re.search(r"emulator: (\d+) ticks, ([\d.]+) % late", text)
    return {"name": name, "series": dict(watch.series), "errors": dict(watch.errors), "start_us": start_us,
            "late": float(late[2]) if late else float("nan")}


def hour(args) -> int:
    runs = []
    with tempfile.TemporaryDirectory(prefix="clock-hour-") as tmp:
        for name in args.setups:
            print(f"running {name} ({args.hours:g} h of device time at x{args.speed:g}) ...", flush=True)
            runs.append(hour_run(name, SETUPS[name], args, Path(tmp) / name))
    marks = [m for m in (1, 2, 5, 10, 15, 20, 30, 40, 50, 60, 90, 120) if m <= args.hours * 60]
    print(f"\nframe_aad_deg (mean of the {args.subjects} subjects; 60 s window of exact frames) at device time t, "
          f"{args.hours:g} h at x{args.speed:g}, source {args.source}\n")
    print("| setup | " + " | ".join(f"{m} min" for m in marks) + " | whole run | late ticks |")
    print("|---|" + "---|" * (len(marks) + 2))
    for r in runs:
        cells, whole = [], []
        for m in marks:
            values = []
            for series in r["series"].values():
                s = np.array([(t, v) for t, v, _ in series], float)
                k = np.searchsorted(s[:, 0], r["start_us"] + m * 60e6)
                values.append(s[min(k, len(s) - 1), 1])
            cells.append(f"{np.mean(values):.3f}")
        for series in r["series"].values():
            whole.append(np.mean([v for _, v, _ in series]))
        print(f"| {r['name']} | " + " | ".join(cells) + f" | {np.mean(whole):.3f} | {r['late']:.2f} % |")
    for r in runs:
        if r["name"] == "synced" and r["errors"]:
            p99 = {d: np.percentile(np.abs([e for t, e in v if t > r["start_us"] + 10e6]), 99)
                   for d, v in r["errors"].items()}
            print(f"\nsynced run: timestamp error (stamp - reference, the last sample of each truth batch) p99 over "
                  f"the run from 10 s: worst device {max(p99.values()):.0f} us, median {np.median(list(p99.values())):.0f}"
                  f" us (device time; at x{args.speed:g} the exchange's round trip is {args.speed:g} x longer)")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    c = sub.add_parser("cost", help="CPU of the time exchange")
    c.add_argument("--devices", type=int, default=2000, help="devices in the emulator process (default 2000)")
    c.add_argument("--warmup", type=float, default=180.0, help="seconds before measuring (default 180)")
    c.add_argument("--measure", type=float, default=120.0, help="seconds measured (default 120)")
    c.add_argument("--poll", type=float, default=256.0,
                   help="the devices' --sync-poll-s (default 256, as deployed; a short one measures the cost "
                        "per exchange with more exchanges)")
    h = sub.add_parser("hour", help="frame error over a long run, per clock setup")
    h.add_argument("--hours", type=float, default=1.0, help="device time per setup, hours (default 1)")
    h.add_argument("--speed", type=float, default=20.0, help="time scale (default 20)")
    h.add_argument("--subjects", type=int, default=2, help="subjects per setup (default 2)")
    h.add_argument("--source", default="generator", help="motion source (default generator)")
    h.add_argument("--setups", nargs="+", default=list(SETUPS), choices=list(SETUPS),
                   help="clock setups to run (default all)")
    args = parser.parse_args(argv)
    return cost(args) if args.what == "cost" else hour(args)


if __name__ == "__main__":
    sys.exit(main())
