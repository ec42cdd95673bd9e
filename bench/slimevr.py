"""The SlimeVR gateway with simulated trackers (limbstream.device_emulator.slimevr_tracker) through a real router,
time service and aggregator, on loopback. Three parts, each printing a table, and a replay:

    python bench/slimevr.py accuracy --source ../shared/data/cmu_10seg_50hz.npz
    python bench/slimevr.py capacity --trackers 100 --fs 100 --seconds 30
    python bench/slimevr.py latency --seconds 30
    python bench/slimevr.py replay --trackers 100 --fs 100 --seconds 10

accuracy: 10 trackers of one subject send a clip (played once, each tracker its segment) at its
rate; the aggregator's figures once every stream ended: devices seen online, ICR (points over
the larger of grid samples and tracker packets), exact AAD (pooled over the stream, against the
trackers' own packets: the truth tap), worst exact max, live mean / p99 / max (the live view
against every packet), and the gateway's held grid samples; then, from the points and the truth
tap themselves (subscribed to), the truth samples whose live error is over the live bound and
how far each came after the one before it (a packet delayed on its way keeps its arrival stamp
when it is more than half a period late).
capacity: N trackers (N/10 subjects, placed by --assign) at F Hz for S seconds, gateway grid at
F Hz: the gateway process's CPU (user + system, /proc) per second of wall time (loop: its main
thread, the rest is Zenoh's threads sending the points), per tracker,
its late ticks, held samples, datagrams the kernel dropped on its socket (/proc/net/udp) and
packets lost on the way (packet numbers), and how late the sender itself ran.
latency: 10 trackers at 50 Hz; every 0.5 s the hip tracker turns by 90 degrees at once; the
time from sending that packet to the first live pose frame of the subject showing the hip
within 10 degrees of the new orientation (wall clock, one host), p50 / p99, per grid delay.
replay: the gateway alone, in this process: N trackers' rotation datagrams (arrivals 0-2 ms
after their instant) handed straight to it (``handle``: the C path of a datagram read from its
socket, less the read), a tick after each round, on a Zenoh peer session of its own (no socket
reads, no router, no timing): its CPU per packet, steadier than the capacity part, which moves
with the machine's load.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import multiprocessing
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zenoh

from limbstream import quat, wire, zconfig
from limbstream.launch import Launcher, free_port, wait_until
from limbstream.sources import load
from limbstream.device_emulator.slimevr_tracker import Fleet

ROOT = Path(__file__).resolve().parent.parent


def free_udp_port() -> int:
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_s(pid: int, tid: int | None = None) -> float:
    """User + system CPU seconds of a process (or one of its threads) so far."""
    path = f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat"
    fields = Path(path).read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def udp_drops(port: int) -> int:
    """Datagrams the kernel dropped on the UDP socket bound to ``port`` (its receive buffer was full)."""
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        cols = line.split()
        if int(cols[1].split(":")[1], 16) == port:
            return int(cols[-1])
    return 0


def gateway_report(child) -> dict:
    """The gateway's last report line (``slimevr {json}``) from its log."""
    lines = [line for line in Path(child.log).read_text(errors="replace").splitlines()
             if line.startswith("slimevr {") or line.startswith("slimevr final {")]
    return json.loads(lines[-1].split(" ", 2 if lines[-1].startswith("slimevr final") else 1)[-1]) if lines else {}


def fleet_process(server, q, segments, fs, subjects, seconds, ready, stop, counters, spin_s) -> None:
    """A process of trackers (its own interpreter: the bench's polling never delays a packet)."""
    fleet = Fleet(server, q, segments, fs, subjects=subjects)
    fleet.connect(60)
    ready.set()
    fleet.run(stop, seconds, spin_s)
    counters[0], counters[1] = fleet.sent, fleet.late
    fleet.close()


def start_fleet(server, q, segments, fs, subjects=1, seconds=None, spin_s=0.0):
    """(process, ready event, stop event, counters [sent, late]) of a tracker process."""
    ready, stop = multiprocessing.Event(), multiprocessing.Event()
    counters = multiprocessing.Array("q", 2)
    proc = multiprocessing.Process(target=fleet_process, args=(server, np.asarray(q), list(segments), fs, subjects,
                                                               seconds, ready, stop, counters, spin_s), daemon=True)
    proc.start()
    if not ready.wait(90):
        raise RuntimeError("the trackers did not connect")
    return proc, stop, counters


class System:
    """Router, time service, aggregator and gateway on free ports, with a stats and pose subscriber."""

    def __init__(self, launcher: Launcher, gateway_args: list[str], live_rate: float = 50.0):
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.port = free_udp_port()
        launcher.router(self.endpoint)
        launcher.start("clock", "clock", "--connect", self.endpoint)
        launcher.start("aggregator", "aggregate", "--connect", self.endpoint, "--live-rate", str(live_rate),
                       "--error-window", "600")
        self.gateway = launcher.start("gateway", "gateway", "slimevr", "--connect", self.endpoint,
                                      "--udp", f"127.0.0.1:{self.port}", "--report-s", "2", "--layout", "paper10",
                                      *gateway_args)
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(self.endpoint,)))
        self.stats = self.session.declare_subscriber(wire.subject_selector("stats"), zenoh.handlers.FifoChannel(8192))
        self.devices: dict[str, dict] = {}
        self.online_seen: dict[str, bool] = {}

    def poll(self) -> dict[str, dict]:
        while (sample := self.stats.try_recv()) is not None:
            for d in wire.decode_stats(sample.payload.to_bytes())["devices"]:
                self.devices[d["device"]] = d
                self.online_seen[d["device"]] = self.online_seen.get(d["device"], False) or d["online"]
        return self.devices


def accuracy(args) -> None:
    motion = load(args.source)[args.clip]
    q = motion.q.astype(np.float64)
    q = np.concatenate([q] * args.loops)
    print(f"clip {motion.name}: {len(motion.q)} samples at {motion.fs:g} Hz x {args.loops}, trackers spin "
          f"{args.spin_ms:g} ms, segments "
          f"{len(motion.segments)}; gateway grid {motion.fs:g} Hz, delay {args.delay_ms:g} ms, live mode "
          f"{wire.LIVE_MODE}")
    with tempfile.TemporaryDirectory() as tmp, Launcher(logdir=Path(tmp)) as launcher:
        system = System(launcher, ["--subject", "s01", "--rate", str(motion.fs), "--delay-ms", str(args.delay_ms)])
        taps = {kind: system.session.declare_subscriber(wire.device_selector(kind), zenoh.handlers.FifoChannel(1 << 16))
                for kind in ("seg", "raw")}
        sender, _, counters = start_fleet(("127.0.0.1", system.port), q, motion.segments, motion.fs,
                                          seconds=len(q) / motion.fs, spin_s=args.spin_ms / 1e3)
        while sender.is_alive():
            system.poll()
            time.sleep(0.2)
        wait_until(lambda: sum(d["final"] for d in system.poll().values()) == 10, 60,
                   "every stream ended (FINAL)", on_fail=launcher.logs)
        time.sleep(3.0)  # the last truth samples evaluated
        devices = list(system.poll().values())
        report = gateway_report(system.gateway)
        over = over_bound(taps, wire.LIVE_MODE["live_bound_deg"], 1e6 / motion.fs)
        system.session.close()
    samples = sum(d["samples"] for d in devices)
    compared = sum(d["error_samples"] for d in devices)
    aad = sum(d["aad_all_deg"] * d["error_samples"] for d in devices) / compared
    held = sum(d["held"] for d in report.get("devices", {}).values())
    print(f"{'online':>7} {'ICR':>7} {'AAD':>6} {'max':>6} {'live mean':>9} {'live p99':>8} {'live max':>8} "
          f"{'compared':>9} {'held':>5} {'dropped':>8} {'jitter p99 ms':>13}")
    print(f"{sum(system.online_seen.values()):>4}/10 {sum(d['points'] for d in devices) / samples:>7.4f} "
          f"{aad:>6.3f} {max(d['max_deg'] for d in devices):>6.2f} "
          f"{statistics.mean(d['live_err_deg'] for d in devices):>9.3f} "
          f"{max(d['live_p99_deg'] for d in devices):>8.3f} {max(d['live_max_deg'] for d in devices):>8.3f} "
          f"{compared:>9} {held:>5} {sum(report.get('dropped', {}).values()):>8} "
          f"{max(d['jitter_p99_ms'] or 0 for d in report['devices'].values()):>13.2f}")
    print(f"from the taps: {len(over)} truth samples over the live bound"
          + "".join(f"\n  {dev}: {err:.2f} deg, {gap / 1e3:.1f} ms after the sample before" for dev, err, gap in over))


def over_bound(taps: dict, bound_deg: float, period_us: float) -> list[tuple[str, float, float]]:
    """(device, live error deg, us since the truth sample before) of every truth sample whose live
    view (the newest point at or before it, extrapolated: quat.predict) is over ``bound_deg``,
    from the points and truth batches received on ``taps`` (one stream per device)."""
    points: dict[str, list] = {}
    truth: dict[str, list] = {}
    for kind, sub in taps.items():
        while (sample := sub.try_recv()) is not None:
            subject, segment, _ = wire.parse_device_key(str(sample.key_expr))
            payload = sample.payload.to_bytes()
            if kind == "seg":
                points.setdefault(f"{subject}/{segment}", []).append(wire.decode_point(payload))
            else:
                truth.setdefault(f"{subject}/{segment}", []).append(wire.decode_raw(payload))
    over = []
    for dev, ps in sorted(points.items()):
        ps.sort(key=lambda p: p.t_us)
        pt = np.array([p.t_us for p in ps])
        pq = np.array([p.q for p in ps], np.float64)
        pw = np.array([p.omega or (0.0, 0.0, 0.0) for p in ps], np.float64)
        batches = sorted(truth.get(dev, []), key=lambda b: b.first_index)
        if not batches:
            continue
        tt = np.concatenate([b.t_us for b in batches])
        tq = np.concatenate([b.q for b in batches]).astype(np.float64)
        k = np.searchsorted(pt, tt, side="right") - 1
        seen = np.flatnonzero(k >= 0)
        err = quat.angle_deg(quat.predict(pq[k[seen]], pw[k[seen]], (tt[seen] - pt[k[seen]]) / 1e6), tq[seen])
        for i in seen[err > bound_deg + 1e-3]:
            over.append((dev, float(err[np.searchsorted(seen, i)]), float(tt[i] - tt[i - 1]) if i else period_us))
    return over


def after_pkts(report: dict) -> int:
    return sum(t["packets"] for t in report["trackers"].values())


def capacity(args) -> None:
    subjects = args.trackers // 10
    motion = load(args.source)[args.clip] if args.source != "generator" else None
    if motion is None:
        t = np.arange(int(args.fs * 10)) / args.fs
        q = np.zeros((len(t), 10, 4))
        q[..., 0] = np.cos(0.4 * np.sin(t))[:, None]
        q[..., 2] = np.sin(0.4 * np.sin(t))[:, None]
        segments = list(wire.SEGMENTS)
    else:
        q, segments = motion.q, motion.segments
    print(f"{args.trackers} trackers ({subjects} subjects) at {args.fs:g} Hz for {args.seconds:g} s, gateway grid "
          f"{args.fs:g} Hz, delay {args.delay_ms:g} ms, truth {'off' if args.no_truth else 'on'}")
    with tempfile.TemporaryDirectory() as tmp, Launcher(logdir=Path(tmp)) as launcher:
        fleet_macs = Fleet(("127.0.0.1", 9), q[:1], segments, args.fs, subjects=subjects)
        assign = [a for s in range(subjects) for seg in segments
                  for a in ("--assign", f"{fleet_macs.mac(s, seg)}=s{s + 1:02d}/{seg}")]
        fleet_macs.close()
        system = System(launcher, ["--subject", "s01", "--rate", str(args.fs), "--delay-ms", str(args.delay_ms),
                                   *(["--no-truth"] if args.no_truth else []), *assign])
        sender, stop, counters = start_fleet(("127.0.0.1", system.port), q, segments, args.fs, subjects)
        try:
            wait_until(lambda: sum(d["online"] for d in system.poll().values()) == args.trackers, 60,
                       "every tracker online in the stats", on_fail=launcher.logs)
            time.sleep(2.0)
            before = gateway_report(system.gateway)
            pid = system.gateway.pid
            drops0, cpu0, main0, wall0 = udp_drops(system.port), cpu_s(pid), cpu_s(pid, pid), time.monotonic()
            time.sleep(args.seconds)
            cpu1, main1, wall1, drops1 = cpu_s(pid), cpu_s(pid, pid), time.monotonic(), udp_drops(system.port)
            time.sleep(2.5)
            after = gateway_report(system.gateway)
            devices = list(system.poll().values())
        finally:
            stop.set()
            sender.join(10)
            system.session.close()
    cpu = (cpu1 - cpu0) / (wall1 - wall0)
    main = (main1 - main0) / (wall1 - wall0)
    ticks = after["ticks"] - before["ticks"]
    late = after["late"] - before["late"]
    held = sum(d["held"] for d in after["devices"].values()) - sum(d["held"] for d in before["devices"].values())
    grid = ticks * args.trackers
    lost = sum(t["lost"] for t in after["trackers"].values())
    pkts = (after_pkts(after) - after_pkts(before)) / (wall1 - wall0 + 2.5)
    print(f"{'trackers':>8} {'Hz':>4} {'pkts/s':>7} {'CPU %core':>9} {'loop %':>6} {'per tracker %':>13} {'late ticks':>10} "
          f"{'held %':>7} {'udp drops':>9} {'lost':>5} {'online':>6} {'sender late':>11}")
    print(f"{args.trackers:>8} {args.fs:>4g} {pkts:>7.0f} {100 * cpu:>9.1f} {100 * main:>6.1f} "
          f"{100 * cpu / args.trackers:>13.3f} {late:>5}/{ticks:<4} {100 * held / max(grid, 1):>7.2f} "
          f"{drops1 - drops0:>9} {lost:>5} {sum(d['online'] for d in devices):>6} {counters[1]:>11}")


def replay(args) -> None:
    import random
    import socket
    import struct

    from limbstream.device.clocks import ClockSettings
    from limbstream.device.host import HostSettings
    from limbstream.services.gateway.slimevr import GatewaySettings, SlimeVRGateway
    from limbstream.device_emulator.slimevr_tracker import handshake_payload, rotation_payload, to_tracker_axes
    segments = list(wire.SEGMENTS)
    macs = [bytes([2, 0x5E, 0, 0, k // len(segments), k % len(segments)]) for k in range(args.trackers)]
    assign = {(":".join(f"{b:02X}" for b in mac), None): (f"s{mac[4] + 1:02d}", segments[mac[5]]) for mac in macs}
    addresses = [(f"127.0.0.{2 + k}", 9) for k in range(args.trackers)]  # the discard port: answers go nowhere
    random.seed(1)
    rng = np.random.default_rng(1)
    ticks = int(args.seconds * args.fs)
    angle = 0.4 * np.sin(np.arange(ticks) / args.fs)
    datagrams = [[struct.pack(">iq", 17, i + 1) + rotation_payload(0, to_tracker_axes(
        (math.cos(a + 0.01 * k), 0.0, math.sin(a + 0.01 * k), 0.0))) for k in range(args.trackers)]
        for i, a in enumerate(angle)]
    arrivals = rng.uniform(0.0, 2000.0, (ticks, args.trackers)).tolist()
    period_us = 1e6 / args.fs
    session = zconfig.open_session(zconfig.ZenohSettings(mode="peer", connect=()))
    with session, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        gateway = SlimeVRGateway(session, sock, GatewaySettings(
            "s01", assign=assign, host=HostSettings(fs=args.fs, config=wire.DeviceConfig(**wire.LIVE_MODE)),
            clock=ClockSettings(sync=False)))
        gateway.declare()
        for address, mac in zip(addresses, macs):
            gateway.handle(struct.pack(">iq", 3, 0) + handshake_payload(mac), address, 0.0, 0.0)
        began = time.thread_time()
        for i in range(ticks):
            for address, datagram, late in zip(addresses, datagrams[i], arrivals[i]):
                gateway.handle(datagram, address, i * period_us + late, i / args.fs)
            gateway.step(i, i / args.fs)  # tick i: grid instant i periods after the start, less the delay
        cpu = time.thread_time() - began
        report = gateway.report()
        gateway.undeclare()
    packets = ticks * args.trackers
    print(f"{args.trackers} trackers at {args.fs:g} Hz, {args.seconds:g} s replayed in-process, delay 30 ms, truth on")
    print(f"{'packets':>8} {'us/packet':>9} {'% core':>6} {'points':>7} {'held':>5} {'dropped':>7}")
    print(f"{packets:>8} {1e6 * cpu / packets:>9.2f} {100 * cpu / args.seconds:>6.1f} "
          f"{sum(d['points'] for d in report['devices'].values()):>7} "
          f"{sum(d['held'] for d in report['devices'].values()):>5} {sum(report['dropped'].values()):>7}")


def stamp_into(frames: list):
    """A Zenoh callback that keeps each sample's arrival (monotonic s) and payload, nothing more."""
    def on_sample(sample) -> None:
        frames.append((time.monotonic(), sample.payload.to_bytes()))
    return on_sample


def latency(args) -> None:
    fs = 50.0
    turned = np.array([math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])
    rows = []
    for delay in [float(d) for d in args.delays.split(",")]:
        with tempfile.TemporaryDirectory() as tmp, Launcher(logdir=Path(tmp)) as launcher:
            system = System(launcher, ["--subject", "s01", "--rate", str(fs), "--delay-ms", str(delay)])
            frames: list[tuple[float, bytes]] = []
            pose = system.session.declare_subscriber(wire.pose_key("s01"), stamp_into(frames))
            q = np.zeros((1, 10, 4))
            q[..., 0] = 1.0
            fleet = Fleet(("127.0.0.1", system.port), q, wire.SEGMENTS, fs)
            fleet.connect(60)
            hip = fleet.trackers[list(wire.SEGMENTS).index("hip")]
            identity = np.array([1.0, 0.0, 0.0, 0.0])
            steps: list[tuple[float, np.ndarray]] = []
            start = time.monotonic()
            k = 0
            target = identity
            stepping_from = None  # tick from which the hip steps: once every device is online
            while stepping_from is None or (k - stepping_from) / fs < args.seconds:
                if stepping_from is None and k % 25 == 0:
                    if sum(d["online"] for d in system.poll().values()) == 10:
                        stepping_from = k
                    elif k / fs > 60:
                        raise RuntimeError(f"not every tracker online after 60 s: {launcher.logs()}")
                if stepping_from is not None and (k - stepping_from) % int(fs / 2) == 0 and k > stepping_from:
                    target = turned if target is identity else identity
                    steps.append((time.monotonic(), target))
                for t in fleet.trackers:
                    t.rotation(0, target if t is hip else identity)
                    t.pump()
                k += 1
                time.sleep(max(0.0, start + k / fs - time.monotonic()))
            time.sleep(1.0)
            pose.undeclare()
            fleet.close()
            system.session.close()
        live = [(t, wire.decode_pose(p)) for t, p in frames]
        live = [(t, f.q[list(wire.SEGMENTS).index("hip")]) for t, f in live if f.kind == wire.KIND_LIVE]
        lat = []
        for sent, target in steps[1:]:
            for t, qh in live:
                if t > sent and abs(float(np.dot(qh, target))) > math.cos(math.radians(5)):
                    lat.append((t - sent) * 1e3)
                    break
        rows.append((delay, len(steps) - 1, len(lat), np.percentile(lat, 50), np.percentile(lat, 99)))
    print("packet sent -> first live pose frame showing it (wall clock, loopback); live frames 50 Hz, grid 50 Hz")
    print(f"{'delay ms':>8} {'steps':>6} {'seen':>5} {'p50 ms':>7} {'p99 ms':>7}")
    for delay, n, seen, p50, p99 in rows:
        print(f"{delay:>8g} {n:>6} {seen:>5} {p50:>7.1f} {p99:>7.1f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="part", required=True)
    a = sub.add_parser("accuracy")
    a.add_argument("--source", default=str(ROOT.parent / "shared" / "data" / "cmu_10seg_50hz.npz"))
    a.add_argument("--clip", type=int, default=0, help="clip index in the file (default 0)")
    a.add_argument("--loops", type=int, default=1, help="play the clip this many times back to back")
    a.add_argument("--delay-ms", type=float, default=30.0)
    a.add_argument("--spin-ms", type=float, default=0.0,
                   help="the trackers busy-wait the last this long before each send (steadier timing)")
    c = sub.add_parser("capacity")
    c.add_argument("--trackers", type=int, default=100)
    c.add_argument("--fs", type=float, default=100.0)
    c.add_argument("--seconds", type=float, default=30.0)
    c.add_argument("--source", default="generator", help="a motion file (its clip --clip, looped) or generator")
    c.add_argument("--clip", type=int, default=0)
    c.add_argument("--delay-ms", type=float, default=30.0)
    c.add_argument("--no-truth", action="store_true")
    lat = sub.add_parser("latency")
    lat.add_argument("--seconds", type=float, default=30.0)
    lat.add_argument("--delays", default="30,10,0", help="grid delays to measure, ms, comma-separated")
    r = sub.add_parser("replay")
    r.add_argument("--trackers", type=int, default=100)
    r.add_argument("--fs", type=float, default=100.0)
    r.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    {"accuracy": accuracy, "capacity": capacity, "latency": latency, "replay": replay}[args.part](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
