"""Live-pipeline benchmarks (docs/benchmarks.md), on loopback with a real router process.

    python bench/pipeline.py emulator     # devices one emulator process sustains at 50 Hz
    python bench/pipeline.py aggregator   # points/s and subjects one aggregator process fuses
    python bench/pipeline.py latency      # segment point publish -> first frame using it
    python bench/pipeline.py all

Every run prints a markdown table. The router is `limbstream router` in its own process;
the component measured runs in this process so its own loop counters can be read.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from limbstream.device_emulator.emulator import Emulator, EmulatorSettings
from limbstream.device.feeds import GeneratorFeed
from limbstream.device.host import HostSettings
from limbstream.device_emulator.main import subject_names
from limbstream import wire, zconfig
from limbstream.launch import Child, Launcher, free_port, stop_all, wait_until
from limbstream.body import Body, builtin_layout
from limbstream.services.aggregator.aggregator import STATS_BATCHES, Aggregator, AggregatorSettings

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class Router:
    """`limbstream router` in a child process on a free port; the other child processes of a
    measurement are started with :meth:`start` and stopped with it. Logs go to a temporary folder."""

    def __enter__(self):
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.launcher = Launcher(Path(tempfile.mkdtemp(prefix="limbstream-bench-")), cwd=ROOT)
        self.proc = self.launcher.router(self.endpoint)
        return self

    def start(self, name: str, *args: str, command=None) -> Child:
        return self.launcher.start(name, *args, command=command)

    def cpu_s(self) -> float:
        return process_cpu_s(self.proc.pid)

    def __exit__(self, *exc):
        self.launcher.stop(10.0)


def process_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a process has used."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def client(endpoint: str) -> zenoh.Session:
    return zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))


def start_emulator_process(router: Router, subjects: int, *extra: str) -> Child:
    """``emulate`` of ``subjects`` generator subjects of the paper's 10 segments each."""
    return router.start("emulator", "emulate", "--connect", router.endpoint, "--subjects", str(subjects),
                        "--layout", "paper10", *extra)


def cpu_now() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


# ----------------------------------------------------------------------------- emulator


SINK = """
import sys, time, zenoh
from limbstream import wire, zconfig
s = zconfig.open_session(zconfig.ZenohSettings(connect=(sys.argv[1],)))
subs = [s.declare_subscriber(k, zenoh.handlers.FifoChannel(1 << 16))
        for k in (wire.device_selector("seg"), wire.device_selector("raw"), wire.subject_selector(wire.TRUTH))]
print("ready", flush=True)
while True:
    got = 0
    for sub in subs:
        while sub.try_recv() is not None:
            got += 1
    if not got:
        time.sleep(0.005)
"""


def start_sink(router: Router) -> Child:
    """A subscriber process that takes every segment point and truth message, per device or per
    subject (so the router routes them)."""
    sink = router.start("sink", router.endpoint, command=(sys.executable, "-c", SINK))
    wait_until(lambda: "ready" in sink.tail(), 30, "the sink to subscribe")
    return sink


def bench_emulator(counts: list[int], seconds: float, truth: bool, bounds: list[float] = (0.0,),
                   threshold: float = wire.THRESHOLD.default) -> None:
    """One row per device count and live bound (``live_bound_deg`` of every device, 0: rule off)."""
    print(f"\n### Devices per emulator process ({seconds:g} s at 50 Hz each, truth tap {'on' if truth else 'off'},"
          " router and a subscriber taking everything in their own processes)\n")
    print("| devices | live bound | ticks | late ticks | busy (of 1 core) | emulator CPU | its tick loop's thread | "
          "CPU per tick | router CPU | points/s |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n, bound in ((n, b) for n in counts for b in bounds):
        with Router() as router:
            sink = start_sink(router)
            session = client(router.endpoint)
            feeds = {name: GeneratorFeed(i + 1, 50.0) for i, name in enumerate(subject_names(n // 10))}
            config = wire.DeviceConfig(threshold=threshold, live_bound_deg=bound).validate()
            # the truth tap as `emulate` sends it: one message per subject and batch
            emulator = Emulator(session, feeds, EmulatorSettings(HostSettings(truth=truth, truth_by_subject=True,
                                                                              config=config)))
            emulator.declare()
            stop = threading.Event()
            timer = threading.Timer(seconds, stop.set)
            cpu0, rcpu0, own0 = cpu_now(), router.cpu_s(), time.thread_time()
            timer.start()
            ticks = emulator.run(stop)
            cpu, rcpu, own = cpu_now() - cpu0, router.cpu_s() - rcpu0, time.thread_time() - own0
            points = sum(d.points for d in emulator.devices)
            emulator.undeclare()
            session.close()
            stop_all([sink])
        print(f"| {n} | {bound:g} | {ticks.ticks} | {100 * ticks.late / max(ticks.ticks, 1):.2f} % | "
              f"{100 * ticks.busy_s / seconds:.0f} % | {100 * cpu / seconds:.0f} % | {100 * own / seconds:.1f} % | "
              f"{1e3 * cpu / max(ticks.ticks, 1):.2f} ms | "
              f"{100 * rcpu / seconds:.0f} % | "
              f"{points / seconds:.0f} |")


# ----------------------------------------------------------------------------- aggregator


def bench_aggregator(subject_counts: list[int], seconds: float, record: bool = False, live_rate: float = 0.0) -> None:
    """With ``record``, a ``limbstream record`` process takes everything (so the frames and stats
    leave the aggregator's session, with its congestion control) and says what it missed."""
    consumer = f"; live frames at {live_rate:g} Hz; a `limbstream record` process takes everything" if record else ""
    print(f"\n### One aggregator process ({seconds:g} s; devices in a separate emulator process, 50 Hz, truth tap on"
          f"{consumer})\n")
    print("| subjects | devices | points/s in | frames/s out | expected frames/s | late ticks | "
          "aggregator CPU | emulator CPU | router CPU | max drained per tick | gaps | dropped |"
          + (" recorder: missing pose frames / stats |" if record else ""))
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|" + ("---:|" if record else ""))
    for subjects in subject_counts:
        with Router() as router:
            if record:
                rec = router.start("record", "record", str(Path(router.launcher.logdir) / "bench.mcap"),
                                   "--connect", router.endpoint)
                wait_until(lambda rec=rec: "recording" in "\n".join(rec.tail()), 60, "the recorder to start")
            emu = start_emulator_process(router, subjects)
            session = client(router.endpoint)
            agg = Aggregator(session, AggregatorSettings(live_rate=live_rate))
            agg.open()
            stop = threading.Event()
            thread = threading.Thread(target=agg.run, args=(stop,))
            thread.start()
            deadline = time.monotonic() + 60  # warm-up: every device seen and frames flowing
            while time.monotonic() < deadline and not (
                    len(agg.subjects) == subjects and (agg.fusion.frames.made > 0).all()):
                time.sleep(0.1)
            p0, f0, l0, t0 = agg.loop.points, agg.loop.frames, agg.loop.pacing.late, agg.loop.pacing.ticks
            cpu0, wall0 = cpu_now(), time.monotonic()
            ecpu0, rcpu0 = process_cpu_s(emu.pid), router.cpu_s()
            stop.wait(seconds)
            wall = time.monotonic() - wall0
            cpu = cpu_now() - cpu0
            ecpu, rcpu = process_cpu_s(emu.pid) - ecpu0, router.cpu_s() - rcpu0
            points, frames = agg.loop.points - p0, agg.loop.frames - f0
            late, ticks = agg.loop.pacing.late - l0, agg.loop.pacing.ticks - t0
            stop.set()
            thread.join()
            tracks = [t for f in agg.subjects.values() for t in f.tracks.values()]
            gaps = sum(t.gaps for t in tracks)
            dropped = sum(sum(t.dropped.values()) for t in tracks)
            agg.close()
            session.close()
            stop_all([emu])
            missed = ""
            if record:
                stop_all([rec])
                summary = json.loads(next(x for x in rec.tail() if x.startswith("record: "))[8:])
                missed = f" {summary['missing']['pose']:,} / {summary['missing']['stats']:,} |"
        print(f"| {subjects} | {10 * subjects} | {points / wall:.0f} | {frames / wall:.0f} | {50 * subjects} | "
              f"{100 * late / max(ticks, 1):.2f} % | {100 * cpu / wall:.0f} % | {100 * ecpu / wall:.0f} % | "
              f"{100 * rcpu / wall:.0f} % | {agg.loop.max_backlog} | {gaps} | "
              f"{dropped} |{missed}")


def subject_layouts(subjects: int, layout: str) -> list[str]:
    """Each bench subject's body layout: ``paper10``, ``full``, or ``mixed`` (every other one ``full``)."""
    return ["full" if layout == "full" or (layout == "mixed" and s % 2) else "paper10" for s in range(subjects)]


def replay_events(subjects: int, seconds: float, fs: float = 50.0, layout: str = "paper10") -> tuple[list, int]:
    """Segment points and truth batches of ``subjects`` generator subjects (of ``layout``:
    :func:`subject_layouts`), as the devices would publish them: (sample tick when published, kind
    0 point / 1 raw, key, payload), in order."""
    from limbstream import kernel
    from limbstream.sources.generator import GeneratorSource

    m = int(seconds * fs)
    start_us = 1_800_000_000_000_000
    events = []
    for s, lay in enumerate(subject_layouts(subjects, layout)):
        source = GeneratorSource(s + 1, fs, layout=lay)
        q = source.chunk(0, m)[1].astype(np.float32)
        t = np.arange(m) / fs
        name = f"s{s + 1:03d}"
        for j, seg in enumerate(source.segments):
            r = kernel.segment(t, q[:, j], 1e-2, 25)
            for n, idx in enumerate(r.index):
                p = wire.SegmentPoint(s, n, int(idx), start_us + int(idx) * 20000, tuple(map(float, q[idx, j])))
                events.append((int(idx) + 1, 0, wire.seg_key(name, seg), wire.encode_point(p)))
            for b in range(0, m, 25):
                batch = wire.RawBatch(s, b, start_us + np.arange(b, b + 25) * 20000, q[b:b + 25, j])
                events.append((b + 25, 1, wire.raw_key(name, seg), wire.encode_raw(batch)))
    events.sort(key=lambda e: e[0])
    return events, m


def bench_aggregator_core(subject_counts: list[int], seconds: float, live_rate: float = 50.0,
                          joint_angles: bool = True, heading: bool = False, layout: str = "paper10") -> None:
    """The aggregator's own work without Zenoh: replayed messages taken in tick by tick as a drain
    takes them, frames built and encoded (live frames at ``live_rate`` Hz, a divisor of 50), their
    joint angles (``joint_angles``; the devices say they send their segments' own orientations, as
    the generator's do), stats of every subject once a second, spread over the ticks as the loop
    does; CPU per second of stream = load at real time. With ``heading``, every device is corrected
    by the joints from the start, as a calibrated 6D sensor is (services/aggregator/heading.py).
    ``layout``: the subjects' body layouts (:func:`subject_layouts`; a ``full`` subject's devices
    announce its default body)."""
    every = max(1, round(50.0 / live_rate))
    angles = "joint angles of the live frames" if joint_angles else "no joint angles"
    print(f"\n### Aggregator core, replayed messages ({seconds:g} s of stream, 50 Hz, truth tap on, "
          f"live frames at {50.0 / every:g} Hz, {angles}, heading correction {'on' if heading else 'off'}, "
          f"layout {layout}; "
          "frames, angles and stats encoded, not sent)\n")
    print("| subjects | devices | points/s | truth samples/s | frames/s | CPU per second of stream | "
          "subjects at 100 % of one core |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for subjects in subject_counts:
        events, m = replay_events(subjects, seconds, layout=layout)
        agg = Aggregator(None, AggregatorSettings(live_rate=50.0 / every, joint_angles=joint_angles))
        agg._publish = agg._publish_stats = lambda subject, payload: None
        for s, lay in enumerate(subject_layouts(subjects, layout)):
            name = f"s{s + 1:03d}"
            for seg in builtin_layout(lay).segment_names:
                agg.fusion.set_online(agg.track(name, seg), True)
                agg.track(name, seg).orientations = "segments"  # as the generator's devices say in their status
                if lay != "paper10":  # its devices announce its body (paper10's announce none)
                    agg.fusion.set_body(agg.track(name, seg), Body.default(builtin_layout(lay)))
        i = n_points = 0
        cpu0 = cpu_now()
        for k in range(m):
            now = k / 50.0
            points, raw = [], []
            while i < len(events) and events[i][0] <= k:  # a tick's messages, taken in as a drain does
                _, kind, key, payload = events[i]
                (points if kind == 0 else raw).append((key, payload))
                i += 1
            agg.take_points([key for key, _ in points], [payload for _, payload in points], now)
            agg.take_raw([key for key, _ in raw], [payload for _, payload in raw], now)
            n_points += len(points)
            if heading and k == 1:  # the streams began: every device as if calibrated now
                for track in agg.fusion.tracks:
                    agg.fusion.heading.reset(agg.subjects[track.subject].index, track.segment, track.slot, True, 0.0)
            agg.advance(k % every == 0, prune=k % 25 == 0, now=now)  # live frames every ``every`` ticks
            if k % (50 // STATS_BATCHES) == 0:  # one round a second, in batches as the loop sends it
                agg.publish_stats(now, k // (50 // STATS_BATCHES) % STATS_BATCHES, STATS_BATCHES)
        load = (cpu_now() - cpu0) / seconds
        devices = len(agg.fusion.tracks)
        print(f"| {subjects} | {devices} | {n_points / seconds:.0f} | {50 * devices:.0f} | "
              f"{agg.loop.frames / seconds:.0f} | {100 * load:.1f} % | {subjects / load:.0f} |")


# ----------------------------------------------------------------------------- latency


DATA_RATE_SKIP_S = 8.0
"""The data rate is counted past each stream's first seconds (device time): past the calibration
script a stream of make run's sensors begins with (5.5 s)."""


def points_per_second(points: list[tuple[str, int, float]], skip_s: float) -> float:
    """Mean over the devices of the segment points ((key, device time us, arrival) each) per second
    of device time, past each device's first ``skip_s`` s: the rate the motion and the kernel make,
    whatever the machine's load."""
    rates = []
    for key in {key for key, _, _ in points}:
        t = np.sort(np.array([t_us for k, t_us, _ in points if k == key], np.int64))
        t = t[t >= t[0] + skip_s * 1e6]
        if len(t) > 1:
            rates.append((len(t) - 1) / ((t[-1] - t[0]) / 1e6))
    return float(np.mean(rates)) if rates else float("nan")


RUN_SENSORS = ("--imu", "raw", "--imu-model", "icm42688p", "--mounting-deg", "90", "--heading-deg", "180")
"""The emulator flags of `make run`'s sensors (the Makefile's RUN_FLAGS)."""


def bench_latency(seconds: float, subjects: int, max_len: int, live: bool = False, raw_sensors: bool = False) -> None:
    """Arrival of each segment point vs arrival of the first exact frame at or after its time;
    ``live``: the devices as ``limbstream up`` runs them (TH 9e-4, live bound 5 deg), and the live
    frames' latency (publication - the device time they show) besides; ``raw_sensors``: with
    `make run`'s sensors (RUN_SENSORS; the aggregator calibrates every device on start)."""
    extra = ("--threshold", "9e-4", "--live-bound-deg", "5") if live else ()
    extra += RUN_SENSORS if raw_sensors else ()
    with Router() as router:
        emu = start_emulator_process(router, subjects, "--max-len", str(max_len), *extra)
        agg = router.start("aggregator", "aggregate", "--connect", router.endpoint,
                           *(("--calibrate-on-start",) if raw_sensors else ()))
        session = client(router.endpoint)
        seg = session.declare_subscriber(wire.device_selector("seg", "s01"), zenoh.handlers.FifoChannel(1 << 16))
        pose = session.declare_subscriber(wire.pose_key("s01"), zenoh.handlers.FifoChannel(1 << 16))
        points, frames, live_lag = [], [], []
        end = time.monotonic() + seconds + 5
        while time.monotonic() < end:
            now = time.monotonic()
            while (s := seg.try_recv()) is not None:
                points.append((str(s.key_expr), wire.decode_point(s.payload.to_bytes()).t_us, now))
            while (s := pose.try_recv()) is not None:
                f = wire.decode_pose(s.payload.to_bytes())
                if f.kind == wire.KIND_EXACT:
                    frames.append((f.t_us, now, time.time()))
                else:
                    live_lag.append(time.time() - f.t_us / 1e6)
            time.sleep(0.001)  # poll period of this measuring client (1 ms resolution)
        stop_all([emu, agg])
        session.close()
    frame_t = np.array([f[0] for f in frames])
    frame_arrival = np.array([f[1] for f in frames])
    first, last, previous = [], [], {}
    for i, (key, t_us, arrival) in enumerate(points):
        t_prev = previous.get(key)
        previous[key] = t_us
        if t_prev is None or i < len(points) // 5:  # skip warm-up
            continue
        k0 = np.searchsorted(frame_t, t_prev, side="right")  # first frame inside the point's segment
        k1 = np.searchsorted(frame_t, t_us)                  # first frame at or after the point
        if k1 < len(frame_t):
            first.append(max(frame_arrival[k0] - arrival, 0.0) if k0 < k1 else frame_arrival[k1] - arrival)
            last.append(frame_arrival[k1] - arrival)
    first, last = np.array(first) * 1e3, np.array(last) * 1e3
    sample_lag = np.array([(wall - t_us / 1e6) for t_us, _, wall in frames[len(frames) // 5:]]) * 1e3
    mps = points_per_second(points, DATA_RATE_SKIP_S)
    mode = ("live mode: TH 9e-4, live bound 5 deg" if live else "live rule off") + (
        ", make run's sensors" if raw_sensors else "")
    print(f"\n### Latency ({seconds:g} s, {subjects} subjects, max segment length {max_len}, 50 Hz, {mode})\n")
    print("| measure | p50 | p99 | max |")
    print("|---|---:|---:|---:|")
    for name, lat in (("segment point arrival -> first exact frame using it", first),
                      ("segment point arrival -> exact frame at its own time", last)):
        print(f"| {name} (ms) | {np.percentile(lat, 50):.1f} | {np.percentile(lat, 99):.1f} | {lat.max():.1f} |")
    print(f"| frame time -> frame arrival, i.e. sample to exact frame (ms) | {np.percentile(sample_lag, 50):.1f} | "
          f"{np.percentile(sample_lag, 99):.1f} | {sample_lag.max():.1f} |")
    if live_lag:
        lag = np.array(live_lag[len(live_lag) // 5:]) * 1e3
        print(f"| frame time -> live frame arrival (ms) | {np.percentile(lag, 50):.1f} | "
              f"{np.percentile(lag, 99):.1f} | {lag.max():.1f} |")
    size = wire.POINT_SIZE_RATE if live else wire.POINT_SIZE
    every, bps = 50 * size, mps * size
    print(f"\nData rate per device (device time past its first {DATA_RATE_SKIP_S:g} s): {mps:.2f} msgs/s, "
          f"{bps:.0f} B/s of segment points; streaming every sample "
          f"in the same {size}-byte message would be {every} B/s ({every / bps:.1f}x more); SlimeVR's 31-byte "
          f"packets at 100 Hz: 3100 B/s.")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("emulator", "aggregator", "core", "latency", "live-latency", "all"))
    parser.add_argument("--seconds", type=float, default=20.0, help="measuring time per row")
    parser.add_argument("--devices", default="500,1000,2000,3000", help="emulator rows (device counts)")
    parser.add_argument("--subjects", default="20,100,200", help="aggregator rows (subject counts)")
    parser.add_argument("--no-truth", action="store_true", help="emulator rows without the truth tap")
    parser.add_argument("--live-bound-deg", default="0", help="emulator rows: live bounds of the devices (0: rule off)")
    parser.add_argument("--threshold", type=float, default=wire.THRESHOLD.default,
                        help="emulator rows: the devices' fastSW threshold (make run's live mode: 9e-4)")
    parser.add_argument("--live-rate", type=float, default=50.0,
                        help="core rows, and aggregator rows with --record: live frame rate, Hz (50, 25, 10, ...)")
    parser.add_argument("--no-joint-angles", dest="joint_angles", action="store_false",
                        help="core rows: the aggregator without its joint-angle stage (to compare)")
    parser.add_argument("--heading-correction", choices=("off", "joints"), default="off",
                        help="core rows: every device's heading corrected by the joints (default off)")
    parser.add_argument("--layout", choices=("paper10", "full", "mixed"), default="paper10",
                        help="core rows: the subjects' body layouts (mixed: every other one full)")
    parser.add_argument("--raw-sensors", action="store_true",
                        help="live-latency: the devices read make run's sensors (raw ICM-42688-P, strapped on "
                             "at up to 90 deg, fused on the device), as make run starts them")
    parser.add_argument("--record", action="store_true",
                        help="aggregator rows: a `limbstream record` process subscribes to everything")
    args = parser.parse_args(argv)
    if args.what in ("emulator", "all"):
        bench_emulator([int(n) for n in args.devices.split(",")], args.seconds, not args.no_truth,
                       [float(b) for b in args.live_bound_deg.split(",")], args.threshold)
    if args.what in ("aggregator", "all"):
        bench_aggregator([int(n) for n in args.subjects.split(",")], args.seconds, args.record,
                         args.live_rate if args.record else 0.0)
    if args.what in ("core", "all"):
        bench_aggregator_core([int(n) for n in args.subjects.split(",")], args.seconds, args.live_rate,
                              args.joint_angles, args.heading_correction == "joints", args.layout)
    if args.what in ("latency", "all"):
        for max_len in (25, 1000):
            bench_latency(args.seconds, 2, max_len)
        bench_latency(args.seconds, 2, 25, live=True)
    if args.what == "live-latency":
        bench_latency(args.seconds, 2, 25, live=True, raw_sensors=args.raw_sensors)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
