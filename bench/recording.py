"""Recording benchmarks (docs/benchmarks.md, "Record and replay"), on loopback with a real router.

    python bench/recording.py recorder --subjects 200 --seconds 20   # does one recorder keep up?
    python bench/recording.py size --seconds 60                       # MB per subject-hour, by channel
    python bench/recording.py replay --minutes 60 --speed 20          # replay of a long recording

recorder: a publisher process sends what 200 subjects put on the router — every device's
segment points and truth batches (generator motion through the C kernel), every subject's exact
(50 Hz) and live (50 Hz; 10 Hz with ``--traffic plain``) pose frames and stats (1 Hz) — in real time; the recorder (services/
outputs/record.py) runs in this process, so its CPU is this process's. Dropped = sent - recorded.

size: the real chain (emulator, aggregator, `limbstream record`) for a while; the recording's
channels are then written one per file to give each one's stored (zstd) size per subject-hour.

replay: a recording of one subject of that many minutes is made offline (generator motion through
the C kernel, points logged when a device would send them), `limbstream replay --speed X` plays it
into a router with an aggregator; wall time and the aggregator's exact-frame AAD vs the offline
evaluation of the same motion.
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
from collections import Counter
from pathlib import Path

import numpy as np

from limbstream import evaluation, kernel, wire, zconfig
from limbstream.launch import Launcher, free_port, wait_until
from limbstream.skeleton import Skeleton
from limbstream.sources import SEGMENTS, Motion
from limbstream.sources.generator import GeneratorSource
from limbstream.services.outputs.record import Recorder
from limbstream.services.outputs.recording import KINDS, Recording, RecordingWriter

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

FS = 50.0
START_US = 1_800_000_000_000_000


def cpu_now() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def device_events(name: str, q: np.ndarray, stream: int, truth: bool, start_us: int = START_US,
                  traffic: str = "live") -> list:
    """(tick when sent, kind, key, payload) of the 10 devices of subject ``name`` for motion q (m, 10, 4):
    a segment point is sent one sample after its own, a truth batch every 25 samples (devices
    staggered over the 25 ticks), as emulated devices do; the last point of each stream is FINAL.
    ``traffic``: the devices' settings, "live" (wire.LIVE_MODE, as under `limbstream up`) or
    "plain" (fastSW's defaults: TH 1e-2, live rule off)."""
    settings = wire.DeviceConfig(**wire.LIVE_MODE) if traffic == "live" else wire.DeviceConfig()
    m = len(q)
    t = np.arange(m) / FS
    events = []
    for j, seg in enumerate(SEGMENTS):
        index = kernel.segment(t, q[:, j], settings.threshold, settings.max_len,
                               live_bound_deg=settings.live_bound_deg).index
        for n, idx in enumerate(index):
            last = n == len(index) - 1 and idx == m - 1
            p = wire.SegmentPoint(stream, n, int(idx), start_us + int(idx) * 20_000, tuple(map(float, q[idx, j])),
                                  wire.FLAG_FINAL if last else 0)
            events.append((min(int(idx) + 1, m), "seg", wire.seg_key(name, seg), wire.encode_point(p)))
        if truth:
            for b in range(0, m, 25):
                n = min(25, m - b)
                batch = wire.RawBatch(stream, b, start_us + np.arange(b, b + n) * 20_000, q[b:b + n, j])
                events.append((b + n + (10 * stream + j) % 25, "raw", wire.raw_key(name, seg), wire.encode_raw(batch)))
    return events


# ----------------------------------------------------------------------------- recorder keeps up


QOS_MODES = ("deployed", "block", "drop")
"""Publisher options of the recorder rows: ``deployed`` zconfig.QOS (what the devices and the
aggregator use), ``block`` BLOCK for every message, ``drop`` BLOCK for segment points and DROP for
the rest (the policy before zconfig.QOS)."""


def publisher_qos(kind: str, payload: bytes, mode: str) -> dict:
    """declare_publisher options of a message of ``kind`` (seg, raw, pose, stats) under ``mode``."""
    import zenoh

    if mode == "block":
        return {"congestion_control": zenoh.CongestionControl.BLOCK}
    if mode == "drop":
        return {"congestion_control": zenoh.CongestionControl.BLOCK if kind == "seg" else zenoh.CongestionControl.DROP}
    if kind == "pose":
        kind = "pose_live" if wire.decode_pose(payload).kind == wire.KIND_LIVE else "pose_exact"
    return zconfig.publisher_options(kind)


def publisher_main(endpoint: str, subjects: int, seconds: float, truth: bool, qos: str, traffic: str) -> None:
    """Child process: what ``subjects`` subjects and their aggregator put on the router, in real time."""

    m = int(seconds * FS)
    body = Skeleton()
    events = []
    for s in range(subjects):
        name = f"s{s + 1:03d}"
        q = GeneratorSource(s + 1, FS).chunk(0, m)[1].astype(np.float32)
        events += device_events(name, q, s, truth, traffic=traffic)
        for kind, every in ((wire.KIND_EXACT, 1), (wire.KIND_LIVE, 1 if traffic == "live" else 5)):
            ticks = np.arange(0, m, every)
            frames = wire.PoseFrames(np.arange(len(ticks)), START_US + ticks * 20_000, kind, np.zeros(len(ticks), int),
                                     q[ticks], body.positions(q[ticks]))
            lag = 20 if kind == wire.KIND_EXACT else 0  # exact frames leave about 0.4 s after their time
            events += [(int(k) + lag, "pose", wire.pose_key(name), p) for k, p in zip(ticks, frames.encode())]
        typical = {float: 1.5, int: 7, bool: True, str: "x", dict: {"duplicate": 1}}
        device = {f.name: typical[f.type] for f in wire.DEVICE_FIELDS}
        for k in range(0, m, 50):
            devices = [dict(device, device=f"{name}/{seg}", segment=seg, online=True, samples=k, points=k // 10)
                       for seg in SEGMENTS]
            events.append((k, "stats", wire.stats_key(name), wire.encode_stats(name, k / FS, devices, seq=k // 50)))
    events.sort(key=lambda e: e[0])
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    pubs, which, by_key = {}, [], {}  # publishers by (key, options); each event's; one per key
    for _, kind, key, payload in events:
        options = publisher_qos(kind, payload, qos)
        name = (key, tuple(sorted((k, int(v)) for k, v in options.items())))
        if name not in pubs:
            pubs[name] = by_key[key] = session.declare_publisher(key, **options)
        which.append(pubs[name])
    probes = [by_key[wire.pose_key(f"s{s + 1:03d}")] for s in range(subjects)]
    deadline = time.monotonic() + 60
    while not all(p.matching_status.matching for p in probes) and time.monotonic() < deadline:
        time.sleep(0.05)
    print("publishing", flush=True)
    sent, i, start = Counter(), 0, time.perf_counter()
    late = 0
    for k in range(m + 50):
        due = start + k / FS
        now = time.perf_counter()
        if now < due:
            time.sleep(due - now)
        elif now - due > 1 / FS:
            late += 1
        while i < len(events) and events[i][0] <= k:
            _, kind, key, payload = events[i]
            which[i].put(payload)
            sent[kind] += 1
            i += 1
    time.sleep(0.5)
    print("sent " + json.dumps({"sent": dict(sent), "late_ticks": late, "seconds": time.perf_counter() - start}),
          flush=True)
    session.close()


def run_publisher(launcher: Launcher, endpoint: str, subjects: int, seconds: float, truth: bool,
                  qos: str, traffic: str) -> dict:
    """Start the publisher child, wait until it has sent everything; its report (``sent`` by kind,
    ``late_ticks``); ``started``: time.monotonic() when it began publishing."""
    pub = launcher.start("publisher", "publish", endpoint, str(subjects), str(seconds), str(int(truth)),
                         qos, traffic, command=(sys.executable, os.path.abspath(__file__)))
    wait_until(lambda: "publishing" in "\n".join(pub.tail()), 600, "the publisher to start", interval=0.05)
    started = time.monotonic()
    wait_until(lambda: not pub.alive(), seconds + 120, "the publisher to finish", interval=0.2)
    report = json.loads(next(x for x in pub.tail() if x.startswith("sent "))[5:])
    return {**report, "started": started, "total": sum(report["sent"].values())}


def do_nothing_subscriber(subjects: int, seconds: float, truth: bool, qos: str, traffic: str) -> int:
    """Messages a subscriber that only empties Zenoh's channels misses of the same traffic (the
    baseline: what the publisher and router lose on the way, whoever listens)."""
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Launcher(Path(tempfile.mkdtemp(prefix="limbstream-bench-sink-")), cwd=Path(ROOT)) as launcher:
        launcher.router(endpoint)
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        subs = [session.declare_subscriber(sel, zenoh.handlers.FifoChannel(1 << 18))
                for sel in (wire.device_selector("seg"), wire.device_selector("raw"), wire.subject_selector("pose"), wire.subject_selector("stats"))]
        got, stop = [0], threading.Event()

        def empty():
            while not stop.wait(0.002):
                got[0] += sum(1 for sub in subs for _ in iter(sub.try_recv, None))
        thread = threading.Thread(target=empty)
        thread.start()
        report = run_publisher(launcher, endpoint, subjects, seconds, truth, qos, traffic)
        time.sleep(2.0)  # what is still on its way
        stop.set()
        thread.join()
        session.close()
    return report["total"] - got[0]


def bench_recorder(subject_counts: list[int], seconds: float, truth: bool, qos: str, traffic: str) -> None:
    how = {"block": "BLOCK for every message", "drop": "BLOCK for segment points, DROP for the rest",
           "deployed": "zconfig.QOS, as deployed"}[qos]
    print(f"\n### One recorder ({seconds:g} s of {traffic} traffic per row; truth tap {'on' if truth else 'off'}; congestion "
          f"control {how}; publisher and router in their own processes)\n")
    print("| subjects | devices | messages/s | sent | recorded | not recorded | same traffic, missed by a do-nothing "
          "subscriber | recorder CPU (of one core) | most messages in one pass | MB/s written | publisher late ticks |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for subjects in subject_counts:
        tmp = Path(tempfile.mkdtemp(prefix="limbstream-bench-rec-"))
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        with Launcher(tmp, cwd=Path(ROOT)) as launcher:
            launcher.router(endpoint)
            session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
            writer = RecordingWriter(tmp / "bench.mcap")
            recorder = Recorder(session, writer, "*", truth, config_poll_s=0.0)
            stop = threading.Event()
            thread = threading.Thread(target=recorder.run, args=(stop,))
            thread.start()
            cpu0 = cpu_now()
            report = run_publisher(launcher, endpoint, subjects, seconds, truth, qos, traffic)
            total = report["total"]

            def settled(recorder=recorder, total=total, previous=[-1]):  # noqa: B006 - the last count seen
                done = recorder.written >= total or recorder.written == previous[0]
                previous[0] = recorder.written
                return done
            wait_until(settled, 60, "the recorder to take everything", interval=1.0)
            wall, cpu = time.monotonic() - report["started"], cpu_now() - cpu0
            stop.set()
            thread.join()
            recorder.close()
            session.close()
            summary = recorder.summary()
        baseline = do_nothing_subscriber(subjects, seconds, truth, qos, traffic)
        recorded = sum(summary["messages"].values())
        print(f"| {subjects} | {10 * subjects} | {total / seconds:,.0f} | {total:,} | {recorded:,} | {total - recorded:,} | "
              f"{baseline:,} | {100 * cpu / wall:.0f} % | {summary['max_batch']:,} | "
              f"{summary['bytes'] / 1e6 / seconds:.2f} | {report['late_ticks']} |")
        if total != recorded:
            print(f"\n(sent {report['sent']}, recorded {summary['messages']}, holes by sequence number "
                  f"{summary['missing']}, undecodable {summary['dropped']})\n")
        (tmp / "bench.mcap").unlink()


# ----------------------------------------------------------------------------- size per channel


def bench_size(seconds: float, subjects: int, source: str) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="limbstream-bench-size-"))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    path = tmp / "size.mcap"
    with Launcher(tmp, cwd=Path(ROOT)) as launcher:
        launcher.router(endpoint)
        launcher.start("aggregate", "aggregate", "--connect", endpoint)
        rec = launcher.start("record", "record", str(path), "--connect", endpoint, "--duration", str(seconds))
        time.sleep(1.0)  # the recorder's session opens (its history query covers what it misses anyway)
        launcher.start("emulate", "emulate", "--connect", endpoint, "--subjects", str(subjects), "--source", source,
                       *(["--layout", "paper10"] if source == "generator" else []))
        wait_until(lambda: not rec.alive(), seconds + 60, "the recorder to finish", interval=0.5)
    by_kind: dict[str, list] = {k: [] for k in KINDS}
    for e in Recording(path).entries():
        by_kind[e.kind].append(e)
    exact = [e for e in by_kind["pose"] if wire.decode_pose(e.payload).kind == wire.KIND_EXACT]
    t = np.array([wire.decode_pose(e.payload).t_us for e in exact])
    hours = subjects * (t.max() - t.min()) / 1e6 / 3600 if len(t) > 1 else float("nan")
    print(f"\n### Recording size per subject-hour ({subjects} subjects x {hours * 3600 / subjects:.0f} s of motion, "
          f"{source}; `limbstream record`, zstd chunks)\n")
    print("| channel | messages per subject-hour | payload MB per subject-hour | stored MB per subject-hour |")
    print("|---|---:|---:|---:|")
    groups = {"segment points (seg)": by_kind["seg"], "truth batches (raw)": by_kind["raw"],
              "exact pose frames (pose, 50 Hz)": exact,
              "live pose frames (pose, 10 Hz)": [e for e in by_kind["pose"] if e not in exact],
              "stats": by_kind["stats"]}
    stored = {}
    for name, entries in groups.items():
        part = tmp / "part.mcap"
        writer = RecordingWriter(part, skeleton=False)
        for e in entries:
            writer.add(e.kind, e.key, e.payload, e.log_ns)
        writer.close()
        empty = RecordingWriter(tmp / "empty.mcap", skeleton=False)
        empty.close()
        stored[name] = (part.stat().st_size - empty.size) / 1e6 / hours
        payload = sum(len(e.payload) for e in entries) / 1e6 / hours
        print(f"| {name} | {len(entries) / hours:,.0f} | {payload:.2f} | {stored[name]:.2f} |")
    skel = sum(1 for _ in exact)
    print(f"\nWhole file: {path.stat().st_size / 1e6 / hours:.1f} MB per subject-hour (with the Foxglove skeleton "
          f"of {skel / hours:,.0f} exact frames per subject-hour and config statuses). Exact pose frames take "
          f"{stored['exact pose frames (pose, 50 Hz)'] / stored['segment points (seg)']:.0f}x the space of the "
          f"segment points they are rebuilt from.")


# ----------------------------------------------------------------------------- replay of a long recording


def write_long_recording(path: Path, minutes: float, seed: int = 7) -> Motion:
    """One generator subject (s01) for ``minutes``, as a recorder would have written it."""
    m = int(minutes * 60 * FS)
    q = GeneratorSource(seed, FS).chunk(0, m)[1]
    writer = RecordingWriter(path, {"subjects": "s01", "truth": "true", "made_by": "bench/recording.py"},
                             skeleton=False)
    log0 = START_US * 1000
    for tick, kind, key, payload in sorted(device_events("s01", q.astype(np.float32), 1, True, traffic="plain"), key=lambda e: e[0]):
        log_ns = log0 + tick * 20_000_000 + 5_000_000  # 5 ms after the sample that closes it
        writer.add(kind, key, payload, log_ns)
    writer.close()
    return Motion(np.arange(m) / FS, q.astype(np.float32).astype(np.float64), SEGMENTS, "s01")


def bench_replay(minutes: float, speed: float) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="limbstream-bench-replay-"))
    path = tmp / "long.mcap"
    t0 = time.monotonic()
    motion = write_long_recording(path, minutes)
    made = time.monotonic() - t0
    expected = evaluation.evaluate([motion], ["fastsw"], [1e-2], max_len=25)[0]
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    m = len(motion.t)
    with Launcher(tmp, cwd=Path(ROOT)) as launcher:
        launcher.router(endpoint)
        launcher.start("aggregate", "aggregate", "--connect", endpoint, "--error-window", str(minutes * 60 + 60))
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        import zenoh
        stats = session.declare_subscriber(wire.stats_key("s01"), zenoh.handlers.FifoChannel(4096))
        probe = session.declare_publisher(wire.seg_key("s01", "hip"))
        wait_until(lambda: probe.matching_status.matching, 60, "the aggregator to subscribe")
        probe.undeclare()
        start = time.monotonic()
        replay = launcher.start("replay", "replay", str(path), "--connect", endpoint, "--speed", str(speed),
                                "--hold", "0")
        wait_until(lambda: not replay.alive(), minutes * 60 / speed * 3 + 120, "the replay to finish", interval=0.5)
        wall = time.monotonic() - start
        latest: dict = {}

        def done():
            while (sample := stats.try_recv()) is not None:
                latest.update({d["device"]: d for d in wire.decode_stats(sample.payload.to_bytes())["devices"]})
            return len(latest) == 10 and all(d["error_samples"] == m for d in latest.values())
        wait_until(done, 300, "the aggregator to evaluate every sample", interval=0.2,
                   on_fail=lambda: f"\n{[(d['device'], d['error_samples'], d['samples'], d['final']) for d in latest.values()]}")
        session.close()
    devices = list(latest.values())
    aad = sum(d["aad_all_deg"] * d["error_samples"] for d in devices) / sum(d["error_samples"] for d in devices)
    points = sum(d["points"] for d in devices)
    print(f"\n### Replay of {minutes:g} min of one subject at --speed {speed:g}\n")
    print("| recorded | file | replay wall time | real-time factor | points | exact-frame AAD (aggregator) | "
          "AAD offline (`limbstream eval`) | ICR replayed / offline |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    print(f"| {minutes:g} min | {path.stat().st_size / 1e6:.1f} MB | {wall:.1f} s | {minutes * 60 / wall:.1f}x | "
          f"{points:,} | {aad:.4f} deg | {expected['aad']:.4f} deg | {points / (10 * m):.4f} / {expected['icr']:.4f} |")
    print(f"\n(recording made offline in {made:.1f} s)")
    path.unlink()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "publish":  # the publisher child process
        publisher_main(argv[1], int(argv[2]), float(argv[3]), bool(int(argv[4])), argv[5], argv[6])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("recorder", "size", "replay", "all"))
    parser.add_argument("--subjects", default="20,200", help="recorder rows (subject counts)")
    parser.add_argument("--seconds", type=float, default=20.0, help="traffic per recorder row / size recording, s")
    parser.add_argument("--no-truth", action="store_true", help="recorder rows without truth batches")
    parser.add_argument("--qos", choices=QOS_MODES, default="deployed",
                        help="recorder rows: publisher options (deployed: zconfig.QOS; block: BLOCK for every message; "
                             "drop: BLOCK for points, DROP for the rest, the policy before zconfig.QOS)")
    parser.add_argument("--traffic", choices=("live", "plain"), default="live",
                        help="recorder rows: live (default, as `limbstream up`: devices in live mode, "
                             "wire.LIVE_MODE, live frames 50 Hz) or plain (TH 1e-2, live rule off, live frames 10 Hz)")
    parser.add_argument("--size-subjects", type=int, default=2, help="subjects of the size recording")
    parser.add_argument("--source", default="generator", help="motion of the size recording (emulate --source)")
    parser.add_argument("--minutes", type=float, default=60.0, help="length of the replayed recording")
    parser.add_argument("--speed", type=float, default=20.0, help="replay speed")
    args = parser.parse_args(argv)
    if args.what in ("recorder", "all"):
        bench_recorder([int(n) for n in args.subjects.split(",")], args.seconds, not args.no_truth, args.qos,
                       args.traffic)
    if args.what in ("size", "all"):
        bench_size(args.seconds, args.size_subjects, args.source)
    if args.what in ("replay", "all"):
        bench_replay(args.minutes, args.speed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
