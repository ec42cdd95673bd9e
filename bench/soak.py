"""Load and soak: many emulated devices through one router and one aggregator for minutes.

Starts real processes on free loopback ports (router, aggregator, ``--procs`` emulators that
share the devices), samples the resident memory of each over time, and reads the
aggregator's stats messages. At the end it prints a table: RSS over time per process, the
growth after warm-up, late ticks, the largest per-tick backlog, dropped / gaps / missed
segment points, and frames.

    python bench/soak.py                         # 2,000 devices, 10 minutes
    python bench/soak.py --devices 200 --minutes 1 --check   # CI size; exit 1 if a target fails
    python bench/soak.py --live-rate 50 --hear-frames        # with a subscriber to every frame, as the dashboard

Targets (``--check``): RSS growth after warm-up < 10 % per process (median of the last third
of the samples against the first third: a trend, not one sample's peak; an emulator's from the
first sample at which every device had sent ``--cache`` points, since its recovery caches grow
until then, and "not judged" in a run too short for that), late ticks by the
loop's own work < 1 % (emulators and aggregator), dropped 0, gaps 0, missed 0, no backlog
growth (the last third's max backlog at most twice the first third's, plus a small floor).

Late ticks are printed two ways (limbstream.pacing): on the wall clock, as a deployment sees
them, and by the loop's own work (its ticks' CPU time against their period). The target is the
second: on a machine with more runnable threads than cores every process waits for a core now
and then, and a loop that does nothing but tick is late then too, so the wall-clock figure there
measures the machine; the work a tick costs does not change with it. What waiting for a core
must not do is lose anything or let the backlog grow: those targets hold either way.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from limbstream import wire, zconfig
from limbstream.launch import Launcher, free_port, stop_all


SEGMENTS_PER_SUBJECT = 10
GRACE_S = 20.0  # emulators of 1,000 devices take a while to stop


def rss_mib(pid: int) -> float:
    """Resident set size of a process, MiB (0 if gone)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process."""
    try:
        fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except OSError:
        return 0.0


def thread_cpu_s(pid: int) -> dict[str, float]:
    """CPU seconds of a process by thread name (Python's main thread is "python"; Zenoh's are
    "rx-0", "tx-0", "app-0", ...), {} if it is gone."""
    out: dict[str, float] = {}
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            stat = open(f"/proc/{pid}/task/{tid}/stat").read()
            name = stat[stat.index("(") + 1:stat.rindex(")")]
            fields = stat.rsplit(")", 1)[1].split()
            out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except OSError:
        pass
    return out


class StatsReader:
    """Latest stats per device and per subject from the aggregator's stats messages."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.sub = self.session.declare_subscriber(f"{wire.PREFIX}/*/stats", zenoh.handlers.FifoChannel(1 << 14))
        self.devices: dict[str, dict] = {}
        self.subjects: dict[str, dict] = {}
        self.aggregator: dict = {}
        self.recent_backlog = 0
        self.recent_tick_ms = 0.0

    def poll(self) -> None:
        while (sample := self.sub.try_recv()) is not None:
            data = wire.decode_stats(sample.payload.to_bytes())
            self.subjects[data["subject"]] = data
            agg = data.get("aggregator") or {}
            if agg.get("ticks", 0) >= self.aggregator.get("ticks", 0):
                self.aggregator = agg
            self.recent_backlog = max(self.recent_backlog, agg.get("recent_backlog", 0))
            self.recent_tick_ms = max(self.recent_tick_ms, agg.get("recent_max_tick_ms", 0.0))
            for d in data["devices"]:
                self.devices[d["device"]] = d

    def take_recent(self) -> tuple[int, float]:
        """(most messages drained in one tick, longest tick in ms) since the last call."""
        value, self.recent_backlog = (self.recent_backlog, self.recent_tick_ms), 0
        self.recent_tick_ms = 0.0
        return value

    def close(self) -> None:
        self.session.close()


class FramesHeard:
    """A subscriber to every subject's pose frames and joint angles (what the dashboard hears),
    counting them: with it the aggregator encodes and sends them all; without it (the default)
    it makes them and sends none (docs/protocol.md, "Pose frame")."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.counts = {wire.POSE: 0, wire.ANGLES: 0}
        self.subs = [self.session.declare_subscriber(wire.subject_selector(kind), lambda _, k=kind: self._count(k))
                     for kind in self.counts]

    def _count(self, kind: str) -> None:
        self.counts[kind] += 1  # (a Zenoh thread: a count, nothing more)

    def close(self) -> None:
        self.session.close()


def parse_emulator(text: str) -> tuple[int, float, float]:
    """(ticks, late %, late by its own work %) from an emulator's final line."""
    m = re.search(r"emulator: (\d+) ticks, ([\d.]+) % late \(([\d.]+) % by its own work\)", text)
    return (int(m.group(1)), float(m.group(2)), float(m.group(3))) if m else (0, float("nan"), float("nan"))


def arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", type=int, default=2000, help="devices (multiple of 10; default 2000)")
    parser.add_argument("--minutes", type=float, default=10.0, help="duration, minutes (default 10)")
    parser.add_argument("--procs", type=int, default=2, help="emulator processes sharing the devices (default 2)")
    parser.add_argument("--rate", type=float, default=50.0, help="device sample rate, Hz (default 50)")
    parser.add_argument("--frame-batch", type=float, default=0.0,
                        help="aggregator --frame-batch, s (default 0: frames every tick, as deployed)")
    parser.add_argument("--cache", type=int, default=512,
                        help="emulator --cache: points per device kept for recovery (default 512); the "
                             "caches fill during warm-up (~150 s at 512), so short runs use less")
    parser.add_argument("--truth", action="store_true", help="also stream the truth tap (raw samples)")
    parser.add_argument("--live-rate", type=float, default=0.0,
                        help="the aggregator's live frames per second and subject (default 0: off; make run: 50)")
    parser.add_argument("--no-joint-angles", dest="joint_angles", action="store_false",
                        help="the aggregator without its joint-angle stage (to compare)")
    parser.add_argument("--warmup", type=float, default=None,
                        help="warm-up, s, before the RSS baseline (default: 30 %% of the run, at most "
                             "180 s: the recovery caches fill first)")
    parser.add_argument("--samples", type=int, default=11, help="RSS samples over the run (default 11)")
    parser.add_argument("--hear-frames", action="store_true",
                        help="subscribe to every subject's pose frames and joint angles, as the dashboard does "
                             "(default: none; the aggregator sends no frame nobody hears)")
    parser.add_argument("--check", action="store_true", help="exit 1 if a target is missed")
    parser.add_argument("--json", default="", help="also write the results to this JSON file")
    args = parser.parse_args(argv)
    if args.devices < SEGMENTS_PER_SUBJECT or args.devices % SEGMENTS_PER_SUBJECT:
        parser.error(f"--devices must be a positive multiple of {SEGMENTS_PER_SUBJECT}, got {args.devices}")
    if args.procs < 1 or args.minutes <= 0:
        parser.error("--procs must be >= 1 and --minutes > 0")
    return args


@dataclass
class Run:
    """What a soak run started and what it saw: its processes, and per sample its time, RSS of
    each process, the aggregator's backlog and longest tick; the loss counters at the end of the
    warm-up; each process's CPU share."""

    launcher: Launcher
    workdir: Path
    share: list[int]
    emulators: list = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    rss: dict[str, list[float]] = field(default_factory=dict)
    backlog: list[int] = field(default_factory=list)
    tick_ms: list[float] = field(default_factory=list)
    at_warmup: tuple | None = None
    cache: int = 0                                        # each device's recovery cache, points
    cached: list[float] = field(default_factory=list)     # per sample: share of devices whose cache is full
    cpu: dict[str, float] = field(default_factory=dict)
    threads: dict[str, float] = field(default_factory=dict)


def start(args: argparse.Namespace, endpoint: str) -> Run:
    """Router, aggregator and the emulator processes sharing the subjects."""
    subjects = args.devices // SEGMENTS_PER_SUBJECT
    workdir = Path(tempfile.mkdtemp(prefix="limbstream-soak-"))
    launcher = Launcher(workdir)
    launcher.router(endpoint)
    launcher.start("aggregator", "aggregate", "--connect", endpoint, "--live-rate", f"{args.live_rate:g}",
                   "--frame-batch", str(args.frame_batch), *([] if args.joint_angles else ["--no-joint-angles"]))
    run = Run(launcher, workdir, [subjects // args.procs + (i < subjects % args.procs) for i in range(args.procs)],
              cache=args.cache)
    first = 1
    for i, n in enumerate(run.share):
        if n:
            extra = [] if args.truth else ["--no-truth"]
            run.emulators.append(launcher.start(f"emulator{i}", "emulate", "--connect", endpoint, "--subjects", str(n),
                                                "--first-subject", str(first), "--rate", str(args.rate),
                                                "--cache", str(args.cache), "--layout", "paper10", *extra))
            first += n
    run.rss = {p.name: [] for p in launcher.children}
    print(f"soak: {args.devices} devices ({subjects} subjects, {len(run.emulators)} emulator processes), "
          f"{args.minutes:g} min, truth tap {'on' if args.truth else 'off'}, logs in {workdir}", flush=True)
    return run


def watch(run: Run, reader: StatsReader, duration: float, warmup: float, samples: int) -> None:
    """Sample the processes' RSS and the aggregator's figures over the run (more often at its start)."""
    procs = run.launcher.children
    t0 = time.monotonic()
    sample_at = [warmup + k * (duration - warmup) / max(samples - 1, 1) for k in range(samples)]
    cpu0 = {p.name: cpu_s(p.pid) for p in procs}
    aggregator = next(p for p in procs if p.name == "aggregator")
    threads0 = thread_cpu_s(aggregator.pid)
    for at in sorted({0.0, 10.0, *sample_at}):
        while time.monotonic() - t0 < at:
            reader.poll()
            time.sleep(0.2)
            dead = [p.name for p in procs if not p.alive()]
            if dead:
                raise SystemExit(f"soak: {dead} exited early; logs in {run.workdir}")
        reader.poll()
        run.times.append(time.monotonic() - t0)
        most, longest = reader.take_recent()
        run.backlog.append(most)
        run.tick_ms.append(longest)
        for p in procs:
            run.rss[p.name].append(rss_mib(p.pid))
        points = [d["points"] or 0 for d in reader.devices.values()]
        run.cached.append(sum(n >= run.cache for n in points) / max(len(points), 1))
        if at >= warmup and run.at_warmup is None:  # loss counters at the end of the warm-up
            run.at_warmup = (sum(d["gaps"] or 0 for d in reader.devices.values()),
                             reader.aggregator.get("missed", 0), reader.aggregator.get("late", 0),
                             reader.aggregator.get("late_own", 0), reader.aggregator.get("ticks", 0))
        online = sum(1 for d in reader.devices.values() if d["online"])
        print(f"  t={run.times[-1]:6.0f} s  devices online {online:5d}  RSS MiB "
              + " ".join(f"{p.name} {run.rss[p.name][-1]:.0f}" for p in procs)
              + f"  backlog {run.backlog[-1]}", flush=True)
    run.cpu = {p.name: (cpu_s(p.pid) - cpu0[p.name]) / (time.monotonic() - t0) * 100 for p in procs}
    run.threads = {name: 100 * (v - threads0.get(name, 0.0)) / (time.monotonic() - t0)
                   for name, v in thread_cpu_s(aggregator.pid).items()}
    reader.poll()


def rss_rows(run: Run, base: int) -> list[tuple]:
    """Per process: (name, RSS series, RSS after warm-up, growth %: median of the last third of
    the samples after warm-up vs the first, peak % over the warm-up's). An emulator's growth is
    judged from the first sample at which every device had sent ``--cache`` points (its recovery
    caches full: until then they grow as they should); NaN where fewer than 3 samples are left."""
    rows = []
    full = next((i for i, share in enumerate(run.cached) if i >= base and share >= 1.0), len(run.cached))
    for p in run.launcher.children:
        emulator = p in run.emulators
        if emulator and len(run.rss[p.name]) - full < 3:
            rows.append((p.name, run.rss[p.name], run.rss[p.name][base], float("nan"), float("nan")))
            continue
        after = run.rss[p.name][full if emulator else base:]
        k = max(1, len(after) // 3)
        first, last = statistics.median(after[:k]), statistics.median(after[-k:])
        growth = 100.0 * (last - first) / first if first else float("nan")
        peak = 100.0 * (max(after) - after[0]) / after[0] if after[0] else float("nan")
        rows.append((p.name, run.rss[p.name], after[0], growth, peak))
    return rows


def results(run: Run, reader: StatsReader, base: int, duration: float) -> dict:
    """The run's measures (the table printed and kept in the JSON file)."""
    em_ticks = [parse_emulator(p.log.read_text(errors="replace")) for p in run.emulators]
    em_samples = sum(t * n * SEGMENTS_PER_SUBJECT for (t, _, _), n in zip(em_ticks, [n for n in run.share if n]))
    em_all = max(sum(t for t, _, _ in em_ticks), 1)
    agg, devices = reader.aggregator, reader.devices
    gaps0, missed0, late0, own0, ticks0 = run.at_warmup or (0, 0, 0, 0, 0)
    points = sum(d["points"] or 0 for d in devices.values())
    gaps = sum(d["gaps"] or 0 for d in devices.values())
    third = max(1, (len(run.backlog) - base) // 3)
    return {
        "devices seen": len(devices),
        "segment points received": points,
        "samples taken (emulator ticks x devices)": em_samples,
        "ICR": points / em_samples if em_samples else float("nan"),
        "emulator late ticks %": sum(t * late for t, late, _ in em_ticks) / em_all,
        "emulator late ticks by own work %": sum(t * own for t, _, own in em_ticks) / em_all,
        "aggregator late ticks %": 100.0 * agg.get("late", 0) / max(agg.get("ticks", 1), 1),
        "aggregator late ticks % after warm-up":
            100.0 * (agg.get("late", 0) - late0) / max(agg.get("ticks", 0) - ticks0, 1),
        "aggregator late ticks by own work %": 100.0 * agg.get("late_own", 0) / max(agg.get("ticks", 1), 1),
        "aggregator late ticks by own work % after warm-up":
            100.0 * (agg.get("late_own", 0) - own0) / max(agg.get("ticks", 0) - ticks0, 1),
        "aggregator busy % of wall time (main loop)": 100.0 * agg.get("busy_s", 0.0) / duration,
        "aggregator longest tick after warm-up (ms)": max(run.tick_ms[base + 1:] or [float("nan")]),
        "aggregator max backlog (msgs/tick), first / last third":
            f"{max(run.backlog[base:base + third] or [0])} / {max(run.backlog[-third:] or [0])}",
        "aggregator max backlog overall": agg.get("max_backlog", 0),
        "dropped (all reasons)": sum(d["dropped"] or 0 for d in devices.values()),
        "gaps (lost seq numbers)": gaps,
        "gaps after warm-up": gaps - gaps0,
        "missed (zenoh miss detection)": agg.get("missed", 0),
        "missed after warm-up": agg.get("missed", 0) - missed0,
        "exact frames": sum(s.get("frames", 0) for s in reader.subjects.values()),
        "skipped frames": sum(s.get("skipped_frames", 0) for s in reader.subjects.values()),
    }


def verdict(rows: list[tuple], measures: dict, run: Run, base: int, devices: int) -> list[str]:
    """The targets missed (none: PASS)."""
    failures = [f"{name} RSS grew {g:.1f} %" for name, _, _, g, _ in rows if g >= 10.0]
    failures += [f"{k} = {measures[k]}" for k in ("dropped (all reasons)", "gaps (lost seq numbers)",
                                                  "missed (zenoh miss detection)") if measures[k]]
    failures += [f"{k} = {measures[k]:.2f}" for k in ("emulator late ticks by own work %",
                                                      "aggregator late ticks by own work %")
                 if not measures[k] < 1.0]
    third = max(1, (len(run.backlog) - base) // 3)
    early, late = max(run.backlog[base:base + third] or [0]), max(run.backlog[-third:] or [0])
    if late > 2 * early + 50:
        failures.append(f"backlog grew: {early} -> {late} messages per tick")
    if measures["devices seen"] != devices:
        failures.append(f"{measures['devices seen']} of {devices} devices seen")
    return failures


def main(argv: list[str] | None = None) -> int:
    args = arguments(argv)
    duration = args.minutes * 60
    warmup = args.warmup if args.warmup is not None else min(0.3 * duration, 180.0)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = start(args, endpoint)
    reader = StatsReader(endpoint)
    heard = FramesHeard(endpoint) if args.hear_frames else None
    try:
        watch(run, reader, duration, warmup, args.samples)
    finally:
        stop_all(run.emulators, GRACE_S)
        time.sleep(1.0)
        reader.poll()
        run.launcher.stop(GRACE_S)
        reader.close()
        if heard is not None:
            heard.close()

    base = next(i for i, t in enumerate(run.times) if t >= warmup - 1e-6)
    rows = rss_rows(run, base)
    print("\naggregator CPU % by thread (Python's main thread: its own work; rx/tx: Zenoh's): "
          + ", ".join(f"{name} {v:.1f}" for name, v in sorted(run.threads.items(), key=lambda x: -x[1]) if v >= 0.1))
    print("\nRSS (MiB) at t = " + ", ".join(f"{t:.0f}" for t in run.times) + " s")
    print("| process | RSS after warm-up | max after | growth (median of last vs first third) | peak over "
          "warm-up | CPU % | RSS series |")
    print("|---|---|---|---|---|---|---|")
    for name, series, ref, growth, peak in rows:
        judged = f"{growth:+.1f} %" if growth == growth else "not judged: caches filling"
        print(f"| {name} | {ref:.0f} | {max(series[base:]):.0f} | {judged} | "
              f"{f'{peak:+.1f} %' if peak == peak else '–'} | "
              f"{run.cpu[name]:.0f} | " + " ".join(f"{v:.0f}" for v in series) + " |")
    print(f"\nDevices that had sent --cache ({run.cache}) points, their recovery caches full, at each sample: "
          + ", ".join(f"{100 * c:.0f} %" for c in run.cached) + " (an emulator's RSS growth is judged from the first "
          "sample at 100 % after warm-up)")
    measures = results(run, reader, base, duration)
    measures["pose frames and joint angles heard (--hear-frames)"] = (
        "not subscribed" if heard is None else f"{heard.counts[wire.POSE]} / {heard.counts[wire.ANGLES]}")
    measures["pose frames made, not sent (unheard)"] = reader.aggregator.get("unheard", 0)
    print("\n| measure | value |")
    print("|---|---|")
    for k, v in measures.items():
        print(f"| {k} | {v:.4f} |" if isinstance(v, float) else f"| {k} | {v} |")
    if args.json:
        Path(args.json).write_text(json.dumps({"args": vars(args), "times": run.times, "backlog": run.backlog,
                                               "tick_ms": run.tick_ms, "rss": {n: s for n, s, *_ in rows},
                                               "cpu": run.cpu, "aggregator threads cpu": run.threads,
                                               "results": measures}, indent=1))
    failures = verdict(rows, measures, run, base, args.devices)
    print("\n" + ("PASS" if not failures else "FAIL: " + "; ".join(failures)))
    return 1 if args.check and failures else 0


if __name__ == "__main__":
    sys.exit(main())
