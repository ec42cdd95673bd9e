"""Live output benchmarks (docs/benchmarks.md): CPU of the `limbstream vmc` and `limbstream
foxglove` processes fed live pose frames, on loopback with a real router process.

    python bench/outputs.py vmc        # one vmc process sending N subjects at 50 Hz
    python bench/outputs.py foxglove   # one foxglove server, N subjects at 50 Hz, one client subscribed to all
    python bench/outputs.py all

This process publishes live pose frames of N subjects at 50 Hz (generated motion, skeleton joint
positions; stats once per second per subject), as an aggregator run with ``--live-rate 50`` does,
and receives what the output sends (VMC bundles on a UDP socket; Foxglove messages on a
WebSocket client), so the output's whole path runs. CPU is the output process's user + system
time over the measured window, in % of one core. Prints a markdown table.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from limbstream import wire, zconfig
from limbstream.launch import Launcher, free_port, wait_until
from limbstream.skeleton import Skeleton
from limbstream.sources import generator

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

RATE_HZ = 50.0


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class PosePublisher:
    """Live pose frames of ``subjects`` at 50 Hz (one tick publishes every subject's frame) and
    stats at 1 Hz, on a thread. ``frames``: pose frames published; ``late``: ticks more than one
    period late."""

    def __init__(self, endpoint: str, subjects: list[str]):
        motion = generator.generate(10.0, seed=1)
        self.q = motion.q.astype(np.float32)
        self.joints = Skeleton().positions(self.q)
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.subjects = subjects
        live, stats = zconfig.publisher_options("pose_live"), zconfig.publisher_options("stats")  # as the aggregator
        self.pose = [self.session.declare_publisher(wire.pose_key(s), **live) for s in subjects]
        self.stats = [self.session.declare_publisher(wire.stats_key(s), **stats) for s in subjects]
        self.frames = self.late = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        period = 1.0 / RATE_HZ
        devices = {s: [{"device": f"{s}/{seg}", "segment": seg, "subject": s, "icr": 0.1} for seg in wire.SEGMENTS]
                   for s in self.subjects}
        n, start = 0, time.monotonic()
        while not self.stop.is_set():
            row = n % len(self.q)
            t_us = time.time_ns() // 1000
            frames = wire.PoseFrames(np.full(len(self.subjects), n), np.full(len(self.subjects), t_us),
                                     wire.KIND_LIVE, np.zeros(len(self.subjects), np.int64),
                                     np.repeat(self.q[row][None], len(self.subjects), 0),
                                     np.repeat(self.joints[row][None], len(self.subjects), 0))
            for pub, payload in zip(self.pose, frames.encode()):
                pub.put(payload)
            self.frames += len(self.subjects)
            if n % int(RATE_HZ) == 0:
                for s, pub in zip(self.subjects, self.stats):
                    pub.put(wire.encode_stats(s, t_us / 1e6, devices[s], seq=n // int(RATE_HZ)))
            n += 1
            wait = start + n * period - time.monotonic()
            if wait < -period:
                self.late += 1
            self.stop.wait(max(0.0, wait))

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()
        self.session.close()


class UdpCounter:
    """Counts datagrams arriving on a UDP socket (on a thread)."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.count = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                self.sock.recv(65536)
                self.count += 1
            except TimeoutError:
                pass

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.sock.close()


class FoxgloveClient:
    """A Foxglove WebSocket client on a thread that subscribes to every channel advertised and
    counts the messages received."""

    def __init__(self, port: int):
        self.port, self.count, self.channels = port, 0, 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self.thread.start()

    async def _run(self) -> None:
        import websockets

        async with websockets.connect(f"ws://127.0.0.1:{self.port}", subprotocols=["foxglove.sdk.v1"],
                                      max_size=None) as ws:
            while not self.stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.2)
                except TimeoutError:
                    continue
                if isinstance(msg, bytes):
                    self.count += 1
                    continue
                data = json.loads(msg)
                if data["op"] == "advertise":
                    subs = [{"id": c["id"], "channelId": c["id"]} for c in data["channels"]]
                    self.channels += len(subs)
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def close(self) -> None:
        self.stop.set()
        self.thread.join()


def measure(launcher: Launcher, child, publisher: PosePublisher, received, warmup: float, seconds: float) -> dict:
    """CPU % of ``child`` and rates over ``seconds`` after ``warmup``."""
    time.sleep(warmup)
    c0, f0, r0, t0 = cpu_s(child.pid), publisher.frames, received(), time.monotonic()
    time.sleep(seconds)
    c1, f1, r1, t1 = cpu_s(child.pid), publisher.frames, received(), time.monotonic()
    if not child.alive():
        raise SystemExit(f"{child.name} exited: {launcher.logs()}")
    wall = t1 - t0
    return {"cpu": 100 * (c1 - c0) / wall, "in": (f1 - f0) / wall, "out": (r1 - r0) / wall}


def run_vmc(n: int, seconds: float) -> tuple[dict, int]:
    """One vmc process sending ``n`` subjects; (measure() result, publisher late ticks)."""
    subjects = [f"s{i:02d}" for i in range(n)]
    udp = UdpCounter()
    try:
        with Launcher(Path(tempfile.mkdtemp(prefix="limbstream-bench-")), cwd=ROOT) as launcher:
            endpoint = f"tcp/127.0.0.1:{free_port()}"
            launcher.router(endpoint)
            args = [a for s in subjects for a in ("--subject", s, "--to", f"127.0.0.1:{udp.port}")]
            child = launcher.start("vmc", "vmc", *args, "--connect", endpoint, "--wait", "0")
            with PosePublisher(endpoint, subjects) as pub:
                wait_until(lambda: udp.count > 0, 30, "the first VMC bundle")
                return measure(launcher, child, pub, lambda: udp.count, 2.0, seconds), pub.late
    finally:
        udp.close()


def run_foxglove(n: int, seconds: float) -> tuple[dict, int]:
    """One foxglove server with ``n`` subjects and one client; (measure() result, late ticks)."""
    subjects = [f"s{i:02d}" for i in range(n)]
    with Launcher(Path(tempfile.mkdtemp(prefix="limbstream-bench-")), cwd=ROOT) as launcher:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        launcher.router(endpoint)
        port = free_port()
        child = launcher.start("foxglove", "foxglove", "--port", str(port), "--connect", endpoint)
        wait_until(lambda: any("serving" in line for line in child.tail()), 30, "the foxglove server")
        client = FoxgloveClient(port)
        try:
            with PosePublisher(endpoint, subjects) as pub:
                wait_until(lambda: client.channels >= 3 * n, 30, "every topic advertised")
                return measure(launcher, child, pub, lambda: client.count, 2.0, seconds), pub.late
        finally:
            client.close()


def bench_vmc(counts: list[int], seconds: float) -> None:
    print(f"\n### `limbstream vmc`: one process, N subjects of live frames at {RATE_HZ:g} Hz ({seconds:g} s)\n")
    print("| subjects | frames/s in | bundles/s received | vmc CPU (% of one core) | publisher late ticks |")
    print("|---:|---:|---:|---:|---:|")
    for n in counts:
        r, late = run_vmc(n, seconds)
        print(f"| {n} | {r['in']:.0f} | {r['out']:.0f} | {r['cpu']:.1f} % | {late} |", flush=True)


def bench_foxglove(counts: list[int], seconds: float) -> None:
    print(f"\n### `limbstream foxglove`: one server, N subjects of live frames at {RATE_HZ:g} Hz and stats at "
          f"1 Hz, one client subscribed to every topic ({seconds:g} s)\n")
    print("| subjects | frames/s in | messages/s to the client | server CPU (% of one core) | publisher late ticks |")
    print("|---:|---:|---:|---:|---:|")
    for n in counts:
        r, late = run_foxglove(n, seconds)
        print(f"| {n} | {r['in']:.0f} | {r['out']:.0f} | {r['cpu']:.1f} % | {late} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("vmc", "foxglove", "all"))
    parser.add_argument("--subjects", default="1,10", help="comma-separated subject counts (default 1,10)")
    parser.add_argument("--seconds", type=float, default=20.0, help="measured window per run (default 20)")
    args = parser.parse_args(argv)
    counts = [int(c) for c in args.subjects.split(",")]
    if args.what in ("vmc", "all"):
        bench_vmc(counts, args.seconds)
    if args.what in ("foxglove", "all"):
        bench_foxglove(counts, args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
