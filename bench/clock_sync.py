"""Device clocks and time sync: what the exchange costs, and what clocks do to the frames.

``cost``: two stacks side by side, each an emulator process of ``--devices`` devices (no truth
tap) and its own router, one with the time exchange (and a time service), one without; the CPU
of every process in ``--windows`` (seconds after the emulators start: while the devices' poll intervals grow, and once
grown by then) and the exchanges answered per second. The sync's cost is the difference
(emulator and router) plus the time service.

``hour``: ``--subjects`` subjects for ``--hours`` of device time at ``--speed``, once per clock
setup (perfect clocks; +-2 s / +-100 ppm with sync; the same without sync; no offset but +-100
ppm without sync), the same motion each time; the subjects' alignment-aware frame error
(``frame_aad_deg``, 60 s window) over device time, and for the synced run each sample's
timestamp error against its reference time.

``stamp``: the CPU of stamping one tick's samples on the common time base (one C call for all
devices, as the emulator does), warm (back-to-back calls) and after a 2 ms sleep (as in the
emulator, whose tick loop sleeps between ticks: caches and predictors are cold), next to an
empty call, a bare ``numpy`` allocation of the same size and numpy's ``.ctypes.data`` (what a
ctypes call's array argument costs unless its address is taken once) for scale.

    python bench/clock_sync.py cost                   # 2 x 2,000 devices, 25 minutes
    python bench/clock_sync.py hour                   # 1 hour at --speed 20 (about 3.5 min per setup)
    python bench/clock_sync.py stamp                  # a few seconds
    python bench/clock_sync.py outage                 # 10 outages, about 3 minutes
    python bench/clock_sync.py jitter                 # 3 x 400 simulated devices, about a minute

``outage``: router, aggregator, one emulator (``--subjects`` subjects, clocks +-1 s / +-100 ppm,
holdover 4 s) and a time service; the service is stopped until every device reports itself
unsynced, then a new service process is started: the table gives, per outage, when the new
process's queryable was reachable and when every device reported itself synced again (from the
aggregator's 1 Hz stats, so to within a second), both from the new process's launch.

``jitter``: no network: ``--devices`` devices' sync (:class:`limbstream.device.sync.SyncClient`'s
estimator, poll schedule and bounded-slew stamps, exchanges handed in) on a path delayed
``--delay-ms`` +- ``--jitter-ms`` each way (uniform), clocks off by up to +-2 s drifting up to
+-100 ppm, for ``--seconds``; per seed: answers held back as possible service jumps, jumps
followed (the service never jumps here: each one is false), and each device's stamp error p99
from ``--from-s`` on (what tests/test_clock_live.py measures live, on ten devices). Against
another revision's estimator: ``PYTHONPATH=<its checkout> python bench/clock_sync.py jitter``.
"""
from __future__ import annotations

import argparse
import collections
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zenoh

from limbstream import wire, zconfig
from limbstream.launch import Launcher, free_port

from soak import cpu_s


SETUPS = {
    "perfect": [],
    "synced": ["--clock-offset-ms", "2000", "--clock-drift-ppm", "100"],
    "unsynced": ["--clock-offset-ms", "2000", "--clock-drift-ppm", "100", "--no-sync"],
    "drift-only": ["--clock-drift-ppm", "100", "--no-sync"],
}


def log_time(stamp: str) -> float:
    """A log line's time (``%(asctime)s``, local time, to the second), s since the epoch."""
    return time.mktime(time.strptime(stamp.split(",")[0], "%Y-%m-%d %H:%M:%S"))


def answered(log: Path) -> list[tuple[float, int]]:
    """(log time, answered so far) from a time service's -v lines."""
    return [(log_time(m[1]), int(m[2]))
            for m in re.finditer(r"^(\S+ \S+) limbstream\.clock answered (\d+)", log.read_text(), re.M)]


def sync_cpu(log: Path) -> list[tuple[float, float, float]]:
    """(log time, worker CPU s, tick-loop CPU s) so far, from an emulator's -v sync lines."""
    pattern = r"^(\S+ \S+) limbstream\.emulator\.clock time sync: .*CPU: workers ([\d.]+) s, tick loop ([\d.]+) s"
    return [(log_time(m[1]), float(m[2]), float(m[3])) for m in re.finditer(pattern, log.read_text(), re.M)]


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
        # the processes' own floor before any device exists: what a Zenoh session costs idle
        time.sleep(5.0)
        idle_procs = {(n, k): p for n, st in stacks.items() for k, p in st.items() if k in ("router", "clock") and p}
        before, t0 = {k: cpu_s(p.pid) for k, p in idle_procs.items()}, time.monotonic()
        time.sleep(args.idle)
        idle = {k: 100 * (cpu_s(p.pid) - before[k]) / (time.monotonic() - t0) for k, p in idle_procs.items()}
        for name, sync in (("A", True), ("B", False)):
            stacks[name]["emulator"] = launcher.start(
                f"emulate{name}", "emulate", "--connect", stacks[name]["endpoint"], "--subjects",
                str(args.devices // 10), "--no-truth", "--layout", "paper10",
                *(["--sync-poll-s", f"{args.poll:g}", "-v"] if sync else ["--no-sync"]))
        procs = {(n, k): p for n, st in stacks.items() for k, p in st.items() if k != "endpoint" and p is not None}
        started, samples = time.monotonic(), []  # (window, cpu before, cpu after, wall0, wall1, span)
        for lo, hi in args.windows:
            time.sleep(max(0.0, started + lo - time.monotonic()))
            before, t0, wall0 = {k: cpu_s(p.pid) for k, p in procs.items()}, time.monotonic(), time.time()
            time.sleep(max(0.0, started + hi - time.monotonic()))
            after = {k: cpu_s(p.pid) for k, p in procs.items()}
            samples.append(((lo, hi), before, after, wall0, time.time(), time.monotonic() - t0))
        for st in stacks.values():
            st["emulator"].signal(15)
        for st in stacks.values():
            st["emulator"].popen.wait(60)
        texts = {n: Path(st["emulator"].log).read_text() for n, st in stacks.items()}
        counts_all = answered(Path(stacks["A"]["clock"].log))
        inside_all = sync_cpu(Path(stacks["A"]["emulator"].log))
    late = {n: re.search(r"emulator: \d+ ticks, ([\d.]+) % late", t) for n, t in texts.items()}
    late = {n: m[1] if m else "?" for n, m in late.items()}
    print(f"\n{args.devices} devices per emulator process; A with sync (--sync-poll-s {args.poll:g}), B without, "
          f"side by side; CPU in % of one core per window (seconds after the emulators started); late ticks over "
          f"the whole run: A {late['A']} %, B {late['B']} %\n")
    print("| window | emulator A / B | router A / B | time service | exchanges/s | per device | sync's cost "
          "| per exchange | A's sync threads + tick loop |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (lo, hi), before, after, wall0, wall1, span in samples:
        cpu = {k: 100 * (after[k] - before[k]) / span for k in after}
        counts = [c for c in counts_all if wall0 - 1 <= c[0] <= wall1 + 1]
        rate = (counts[-1][1] - counts[0][1]) / max(counts[-1][0] - counts[0][0], 1) if len(counts) >= 2 else 0.0
        total = (cpu["A", "emulator"] - cpu["B", "emulator"] + cpu["A", "router"] - cpu["B", "router"]
                 + cpu["A", "clock"])
        print(f"| {lo:g}-{hi:g} s | {cpu['A', 'emulator']:.1f} / {cpu['B', 'emulator']:.1f} | "
              f"{cpu['A', 'router']:.2f} / {cpu['B', 'router']:.2f} | {cpu['A', 'clock']:.2f} | {rate:.1f} | "
              f"{rate / args.devices:.4f} /s | {total:.2f} % | {1e4 * total / max(rate, 1e-9):.0f} us | "
              f"{inside_window(inside_all, wall0, wall1)} |")
    print(f"\nbefore the emulators started ({args.idle:g} s, no device): time service {idle['A', 'clock']:.2f} %, "
          f"router A / B {idle['A', 'router']:.2f} / {idle['B', 'router']:.2f} % (a Zenoh session's own floor; "
          f"the time service's is paid once per deployment, whatever the number of devices)")
    inside = re.findall(r"CPU: workers ([\d.]+) s, tick loop ([\d.]+) s", texts["A"])
    if inside:
        workers, tick = (float(x) for x in inside[-1])  # the summary at exit
        run_s = args.windows[-1][1]
        print(f"\nemulator A's own CPU accounting over its whole run ({run_s:g} s, start included): exchange "
              f"worker threads {workers:.2f} s ({100 * workers / run_s:.2f} % of a core), tick loop's "
              f"share (applying answers, stamping in the common time base) {tick:.2f} s "
              f"({100 * tick / run_s:.2f} %); Zenoh's own threads are in the process CPU only")
    synced = re.search(r"time sync: (\d+)/(\d+) devices synced at start", texts["A"])
    if synced:
        print(synced[0])
    return 0


def inside_window(lines: list[tuple[float, float, float]], wall0: float, wall1: float) -> str:
    """Emulator A's own sync CPU between its log lines nearest inside [wall0, wall1], % of a core."""
    inside = [x for x in lines if wall0 - 1 <= x[0] <= wall1 + 1]
    if len(inside) < 2 or inside[-1][0] <= inside[0][0]:
        return "?"
    (t0, w0, k0), (t1, w1, k1) = inside[0], inside[-1]
    return f"{100 * (w1 - w0) / (t1 - t0):.2f} + {100 * (k1 - k0) / (t1 - t0):.2f} %"


class Watch:
    """Stats of the subjects (frame error over device time) and, for some, truth-tap errors."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.stats = self.session.declare_subscriber(wire.subject_selector("stats"), zenoh.handlers.FifoChannel(1 << 14))
        self.raw = self.session.declare_subscriber(wire.subject_selector(wire.TRUTH), zenoh.handlers.FifoChannel(1 << 16))
        self.series: dict[str, list] = collections.defaultdict(list)  # subject -> (watermark us, frame_aad)
        self.errors: dict[str, list] = collections.defaultdict(list)  # device -> (ref us, stamp - ref us)

    def poll(self) -> None:
        while (s := self.stats.try_recv()) is not None:
            d = wire.decode_stats(s.payload.to_bytes())
            if d.get("watermark_us") and d.get("frame_aad_deg") is not None:
                self.series[d["subject"]].append((d["watermark_us"], d["frame_aad_deg"], d.get("frame_error_frames")))
        while (s := self.raw.try_recv()) is not None:  # the emulator's truth tap: a message per subject
            for key, payload in wire.truth_batches(str(s.key_expr), s.payload.to_bytes()):
                subject, segment, _ = wire.parse_device_key(key)
                b = wire.decode_raw(payload)
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
                                  "--source", args.source, "--duration", f"{args.hours * 3600:g}", *speed, *flags,
                                  *(["--layout", "paper10"] if args.source == "generator" else []))
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


def per_call(f, sleep_s: float, calls: int = 500) -> float:
    """Thread CPU of ``f(k)`` per call, us, each call after a ``sleep_s`` sleep (0: back to back)."""
    total = 0.0
    for k in range(calls):
        if sleep_s:
            time.sleep(sleep_s)
        began = time.thread_time()
        f(k)
        total += time.thread_time() - began
    return 1e6 * total / calls


def stamp_row(n: int) -> str:
    """One table row: stamping ``n`` devices, warm and after a 2 ms sleep, with references."""
    from limbstream.device.sync import SLEW
    from limbstream.kernel import Stamper
    st = Stamper(n, SLEW)
    st.ever[:], st.a[:], st.b[:], st.ref[:] = True, 1000.0, 50e-6, 1e9
    slots, local = np.arange(n), np.full(n, 1e9)
    st.stamp(slots, local)
    warm = per_call(lambda k: st.stamp(slots, local + (k + 1) * 20_000.0), 0.0, 5000)
    cold = per_call(lambda k: st.stamp(slots, local + (k + 5001) * 20_000.0), 0.002)
    empty = per_call(lambda k: None, 0.002)
    alloc = per_call(lambda k: np.empty(n), 0.002)
    address = per_call(lambda k: local.ctypes.data, 0.002)
    return f"| {n:,} | {warm:.1f} us | {cold:.1f} us | {empty:.1f} us | {alloc:.1f} us | {address:.1f} us |"


def stamp(args) -> int:
    """Thread CPU per call of the stamper, warm and after a sleep, us."""
    print("| devices | stamp, warm | stamp, after 2 ms sleep | nothing, after sleep | np.empty(devices), after sleep "
          "| an array's .ctypes.data, after sleep |")
    print("|---:|---:|---:|---:|---:|---:|")
    for n in args.devices:
        print(stamp_row(n))
    return 0


def windows(text: str) -> list[tuple[float, float]]:
    """``"180:300,1200:1500"`` -> [(180, 300), (1200, 1500)] (increasing, not overlapping)."""
    spans = [tuple(float(x) for x in part.split(":")) for part in text.split(",")]
    flat = [x for span in spans for x in span]
    if any(len(span) != 2 for span in spans) or flat != sorted(flat) or len(set(flat)) != len(flat):
        raise argparse.ArgumentTypeError(f"windows must be increasing LO:HI pairs, got {text!r}")
    return spans


class SyncWatch:
    """Every device's sync, as its own status says (asked at each look) and as the aggregator's
    stats say (``own``, ``reported``: device -> synced)."""

    def __init__(self, session: zenoh.Session, stats, devices: int):
        self.session, self.stats, self.devices = session, stats, devices
        self.own: dict[str, bool] = {}
        self.reported: dict[str, bool] = {}

    def look(self) -> None:
        for reply in self.session.get(wire.device_selector("config"), timeout=1.0):
            if reply.ok is not None:
                status = wire.decode_status(reply.ok.payload.to_bytes())
                self.own[status.device] = bool(status.clock and status.clock.synced)
        while (s := self.stats.try_recv()) is not None:
            for d in wire.decode_stats(s.payload.to_bytes())["devices"]:
                self.reported[d["device"]] = bool(d["synced"] and d["online"])

    def wait(self, predicate, timeout: float, what: str) -> float:
        """Look every 50 ms until ``predicate()`` holds; the monotonic time it first did."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.look()
            if predicate():
                return time.monotonic()
            time.sleep(0.05)
        raise SystemExit(f"timed out waiting for {what}")

    def every(self, view: dict, value: bool):
        return lambda: len(view) == self.devices and all(v == value for v in view.values())

    def resync(self, service, launched: float) -> list[float]:
        """Seconds from a time service's launch until it is reachable, every device synced by its
        own status, and by the aggregator's stats."""
        times: dict[str, float] = {}
        while len(times) < 3:
            at = self.wait(lambda: True, 1, "")
            if "reachable" not in times and service.matching_status.matching:
                times["reachable"] = at
            if "own" not in times and self.every(self.own, True)():
                times["own"] = at
            if "stats" not in times and self.every(self.reported, True)():
                times["stats"] = at
            if at - launched > 60:
                raise SystemExit("timed out waiting for the resync")
        return [times[x] - launched for x in ("reachable", "own", "stats")]


def outage(args) -> int:
    with tempfile.TemporaryDirectory(prefix="clock-outage-") as tmp, Launcher(logdir=Path(tmp)) as launcher:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        launcher.router(endpoint)
        launcher.start("aggregate", "aggregate", "--connect", endpoint)
        clock = launcher.start("clock", "clock", "--connect", endpoint)
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        stats = session.declare_subscriber(wire.subject_selector("stats"), zenoh.handlers.FifoChannel(1 << 12))
        service = session.declare_querier(wire.time_key(), allowed_destination=zenoh.Locality.REMOTE)
        launcher.start("emulate", "emulate", "--connect", endpoint, "--subjects", str(args.subjects), "--no-truth",
                       "--layout", "paper10", "--clock-offset-ms", "1000", "--clock-drift-ppm", "100", "--sync-holdover-s", "4")
        devices = 10 * args.subjects
        sync = SyncWatch(session, stats, devices)
        sync.wait(sync.every(sync.reported, True), 60, "the first sync")
        rows = []
        for k in range(args.outages):
            clock.signal(15)
            clock.popen.wait(10)
            sync.wait(sync.every(sync.reported, False), 60, "every device unsynced")
            launched = time.monotonic()
            clock = launcher.start("clock", "clock", "--connect", endpoint)
            rows.append(sync.resync(service, launched))
            print(f"outage {k + 1}: service reachable {rows[-1][0]:.2f} s, all {devices} devices synced by their own "
                  f"status {rows[-1][1]:.2f} s, in the aggregator's stats {rows[-1][2]:.2f} s after the launch", flush=True)
        session.close()
    reach, own_s, stats_s = np.array(rows).T
    print(f"\n{len(rows)} outages, {devices} devices (holdover 4 s); seconds from the new time-service "
          f"process's launch (devices' own status asked every 50 ms; the aggregator asks an unsynced device's "
          f"subject every 1 s, stats every 1 s)\n")
    print("| | p50 | max |\n|---|---|---|")
    for name, v in (("service queryable reachable", reach), ("every device synced (its own status)", own_s),
                    ("every device synced (aggregator stats)", stats_s)):
        print(f"| {name} | {np.median(v):.2f} | {v.max():.2f} |")
    print(f"\nevery device synced within 3 s of the launch (own status): {int(np.sum(own_s <= 3.0))} of {len(rows)}")
    return 0


def jitter(args) -> int:
    from limbstream.device.clocks import ClockSettings, DeviceClocks, TimeBase
    from limbstream.device.sync import SyncClient
    from limbstream.timesync import SyncEstimator

    class Counted(SyncEstimator):
        outcomes: collections.Counter = collections.Counter()  # every device's, by outcome

        def add(self, *exchange) -> str:
            outcome = super().add(*exchange)
            self.outcomes[outcome] += 1
            return outcome

    t0 = 1_800_000_000_000_000
    print(f"| seed | devices | answers | held back | jumps (all false) | stamp error p99 from {args.from_s:g} s: median "
          f"| worst | devices over 5 ms |\n|---:|---:|---:|---:|---:|---:|---:|---:|")
    for seed in args.seeds:
        rng = np.random.default_rng(seed)
        n = args.devices
        settings = ClockSettings()
        clocks = DeviceClocks(n, settings, 20_000.0, TimeBase(1.0, t0))
        client = SyncClient(None, clocks, settings, [f"s/d{i}" for i in range(n)])
        offset, drift = rng.uniform(-2e6, 2e6, n), rng.uniform(-100e-6, 100e-6, n)
        counts = Counted.outcomes = collections.Counter()
        client.est = [Counted() for _ in range(n)]
        due = np.zeros(n)  # each device's next exchange, true seconds
        errors: list[np.ndarray] = []
        for k in range(round(args.seconds * 50)):
            t = k / 50.0
            for slot in np.flatnonzero(due <= t).tolist():
                up, down = args.delay_ms + args.jitter_ms * rng.uniform(-1, 1, 2)
                sent = t0 + due[slot] * 1e6
                t2 = sent + up * 1e3
                back = t2 + 50 + down * 1e3
                t1 = round(sent + offset[slot] + drift[slot] * (sent - t0))
                t4 = round(back + offset[slot] + drift[slot] * (back - t0))
                answer = wire.encode_time_answer(wire.TimeAnswer(1, t1, round(t2), round(t2) + 50))
                due[slot] = (back - t0) / 1e6 + client._apply(slot, 1, t1, t4, answer)
            true = t0 + t * 1e6
            stamps = client.stamp(np.arange(n), true + offset + drift * (true - t0))
            if t >= args.from_s:
                errors.append(np.abs(stamps - true))
        p99 = np.percentile(np.array(errors), 99, axis=0)
        print(f"| {seed} | {n} | {sum(counts.values()):,} | {counts['held']} | {counts['jump']} | "
              f"{np.median(p99):.0f} us | {p99.max():.0f} us | {int(np.sum(p99 > 5000))} |")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    c = sub.add_parser("cost", help="CPU of the time exchange")
    c.add_argument("--devices", type=int, default=2000, help="devices in the emulator process (default 2000)")
    c.add_argument("--windows", type=windows, default=windows("180:300,1200:1500"),
                   help="measuring windows, seconds after the emulators start (default 180:300,1200:1500: "
                        "while the poll intervals grow, and settled)")
    c.add_argument("--idle", type=float, default=30.0,
                   help="seconds measured before the emulators start (default 30): the processes' idle floor")
    c.add_argument("--poll", type=float, default=512.0,
                   help="the devices' --sync-poll-s (default 512, the emulator's; a short one measures the cost "
                        "per exchange with more exchanges)")
    h = sub.add_parser("hour", help="frame error over a long run, per clock setup")
    h.add_argument("--hours", type=float, default=1.0, help="device time per setup, hours (default 1)")
    h.add_argument("--speed", type=float, default=20.0, help="time scale (default 20)")
    h.add_argument("--subjects", type=int, default=2, help="subjects per setup (default 2)")
    h.add_argument("--source", default="generator", help="motion source (default generator)")
    h.add_argument("--setups", nargs="+", default=list(SETUPS), choices=list(SETUPS),
                   help="clock setups to run (default all)")
    st = sub.add_parser("stamp", help="CPU of stamping one tick's samples")
    st.add_argument("--devices", type=int, nargs="+", default=[200, 2000, 20000], help="devices per call")
    o = sub.add_parser("outage", help="time from a time service's return to every device synced")
    o.add_argument("--outages", type=int, default=10, help="outages (default 10)")
    o.add_argument("--subjects", type=int, default=1, help="subjects of the emulator (default 1)")
    j = sub.add_parser("jitter", help="simulated devices' sync on a jittery path (no network)")
    j.add_argument("--devices", type=int, default=400, help="devices (default 400)")
    j.add_argument("--seconds", type=float, default=80.0, help="simulated seconds (default 80)")
    j.add_argument("--from-s", type=float, default=60.0, help="stamp errors from this second on (default 60)")
    j.add_argument("--delay-ms", type=float, default=10.0, help="one-way delay, ms (default 10)")
    j.add_argument("--jitter-ms", type=float, default=5.0, help="... plus uniform +- this, ms (default 5)")
    j.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3], help="seeds (default 1 2 3)")
    args = parser.parse_args(argv)
    return {"cost": cost, "hour": hour, "stamp": stamp, "outage": outage, "jitter": jitter}[args.what](args)


if __name__ == "__main__":
    sys.exit(main())
