"""Dashboard under load: REST latency with concurrent clients and WebSocket fan-out, while the
real stack streams N subjects (router, emulator, aggregator, dashboard as subprocesses).

    python bench/dashboard_load.py [--subjects 20] [--concurrency 16] [--ws-clients 50] [--duration 10]

Load runs in another process (``--client rest|ws``) so it does not share the dashboard's CPU
accounting or event loop. Prints markdown tables (docs/benchmarks.md, "Dashboard").
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from limbstream.launch import Launcher, free_port, wait_until

ROOT = Path(__file__).resolve().parent.parent


def pct(values, q) -> float:
    return float(np.percentile(values, q)) if len(values) else float("nan")


# ----------------------------------------------------------------------------- load clients


async def rest_load(url: str, duration: float, concurrency: int) -> dict:
    import httpx

    async with httpx.AsyncClient(base_url=url, timeout=10) as client:
        devices = (await client.get("/api/devices")).json()
        subjects = [s["subject"] for s in (await client.get("/api/subjects")).json()]
        ids = [d["device"] for d in devices]
        paths = {
            "GET /api/devices": lambda i: "/api/devices",
            "GET /api/devices/{id}": lambda i: f"/api/devices/{ids[i % len(ids)]}",
            "GET /api/devices/{id}/history?seconds=300": lambda i: f"/api/devices/{ids[i % len(ids)]}/history?seconds=300",
            "GET /api/subjects": lambda i: "/api/subjects",
            "GET /api/subjects/{s}/pose": lambda i: f"/api/subjects/{subjects[i % len(subjects)]}/pose",
        }
        names = list(paths)
        lat = {n: [] for n in names}
        errors = 0
        end = time.monotonic() + duration

        async def worker(w: int) -> None:
            nonlocal errors
            i = w
            while time.monotonic() < end:
                name = names[i % len(names)]
                t0 = time.perf_counter()
                r = await client.get(paths[name](i // len(names)))
                lat[name].append((time.perf_counter() - t0) * 1e3)
                errors += r.status_code != 200
                i += 1

        t0 = time.monotonic()
        await asyncio.gather(*(worker(w) for w in range(concurrency)))
        elapsed = time.monotonic() - t0
    return {"elapsed": elapsed, "errors": errors, "devices": len(ids), "subjects": len(subjects),
            "latency_ms": lat}


async def ws_load(url: str, duration: float, clients: int, subject: str) -> dict:
    import websockets

    ws_url = url.replace("http://", "ws://") + f"/ws/pose/{subject}"
    counts = [0] * clients
    delays: list[float] = []
    end = time.monotonic() + duration

    async def client(k: int) -> None:
        async with websockets.connect(ws_url, max_queue=64) as ws:
            while True:
                left = end - time.monotonic()
                if left <= 0:
                    return
                try:
                    text = await asyncio.wait_for(ws.recv(), left)
                except TimeoutError:
                    return
                counts[k] += 1
                delays.append((time.time() - json.loads(text)["rx"]) * 1e3)

    t0 = time.monotonic()
    await asyncio.gather(*(client(k) for k in range(clients)))
    return {"elapsed": time.monotonic() - t0, "counts": counts, "delays_ms": delays}


def client_main(args) -> int:
    if args.client == "rest":
        result = asyncio.run(rest_load(args.url, args.duration, args.concurrency))
    else:
        result = asyncio.run(ws_load(args.url, args.duration, args.ws_clients, args.subject))
    json.dump(result, sys.stdout)
    return 0


# ----------------------------------------------------------------------------- orchestration


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process and its children (Linux /proc)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_client(kind: str, url: str, args) -> dict:
    cmd = [sys.executable, __file__, "--client", kind, "--url", url, "--duration", str(args.duration),
           "--concurrency", str(args.concurrency), "--ws-clients", str(args.ws_clients), "--subject", args.subject]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=args.duration + 120)
    return json.loads(out.stdout)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subjects", type=int, default=20)
    parser.add_argument("--concurrency", type=int, default=16, help="concurrent REST clients")
    parser.add_argument("--ws-clients", type=int, default=50)
    parser.add_argument("--duration", type=float, default=10.0, help="seconds per measurement")
    parser.add_argument("--client", choices=("rest", "ws"), help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    parser.add_argument("--subject", default="s01", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.client:
        return client_main(args)

    import httpx

    def get(path: str):
        return httpx.get(url + path, timeout=5.0).json()

    with tempfile.TemporaryDirectory() as tmp:
        launcher = Launcher(Path(tmp), cwd=ROOT)
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        try:
            launcher.router(endpoint)
            launcher.start("emulate", "emulate", "--connect", endpoint, "--subjects", str(args.subjects),
                           "--layout", "paper10")
            launcher.start("aggregate", "aggregate", "--connect", endpoint)
            dashboard, url = launcher.dashboard(f"127.0.0.1:{free_port()}", endpoint)
            n = args.subjects * 10
            wait_until(lambda: sum(1 for d in get("/api/devices") if d["msgs_per_s"]) == n,
                       120, f"{n} devices streaming", interval=0.5, on_fail=launcher.logs)
            wait_until(lambda: len(get("/api/subjects")) == args.subjects
                       and all(s["pose"] for s in get("/api/subjects")), 60, "pose of every subject")
            dash = dashboard.pid

            c0, t0 = cpu_seconds(dash), time.monotonic()
            time.sleep(args.duration / 2)  # idle baseline: streaming only, no clients
            idle_cpu = (cpu_seconds(dash) - c0) / (time.monotonic() - t0)

            c0, t0 = cpu_seconds(dash), time.monotonic()
            rest = run_client("rest", url, args)
            rest_cpu = (cpu_seconds(dash) - c0) / (time.monotonic() - t0)

            c0, t0 = cpu_seconds(dash), time.monotonic()
            ws = run_client("ws", url, args)
            ws_cpu = (cpu_seconds(dash) - c0) / (time.monotonic() - t0)
            metrics = httpx.get(url + "/metrics", timeout=5.0).text
        finally:
            launcher.stop()

    skipped = next((line.split()[-1] for line in metrics.splitlines()
                    if line.startswith("limbstream_dashboard_frames_skipped_total")), "?")
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}; "
          f"{args.subjects} subjects x 10 devices streaming (emulator + aggregator on the same machine)")
    print(f"dashboard CPU, streaming only: {idle_cpu:.0%} of a core\n")
    total = sum(len(v) for v in rest["latency_ms"].values())
    print(f"REST: {args.concurrency} concurrent clients (another process), {rest['elapsed']:.1f} s, "
          f"{total / rest['elapsed']:.0f} req/s, {rest['errors']} non-200, dashboard CPU {rest_cpu:.0%}\n")
    print("| endpoint | requests | p50 ms | p99 ms | max ms |")
    print("|---|---:|---:|---:|---:|")
    every = []
    for name, values in rest["latency_ms"].items():
        every += values
        print(f"| `{name}` | {len(values)} | {pct(values, 50):.2f} | {pct(values, 99):.2f} | {max(values):.2f} |")
    print(f"| all | {len(every)} | {pct(every, 50):.2f} | {pct(every, 99):.2f} | {max(every):.2f} |\n")
    counts = np.array(ws["counts"]) / ws["elapsed"]
    print(f"WebSocket fan-out: {args.ws_clients} clients on /ws/pose/{args.subject}, {ws['elapsed']:.1f} s, "
          f"dashboard CPU {ws_cpu:.0%}, frames skipped for slow clients: {skipped}\n")
    print("| clients | frames/s per client min / mean / max | delivery delay p50 / p99 / max ms |")
    print("|---:|---|---|")
    d = ws["delays_ms"]
    print(f"| {args.ws_clients} | {counts.min():.1f} / {counts.mean():.1f} / {counts.max():.1f} | "
          f"{pct(d, 50):.1f} / {pct(d, 99):.1f} / {max(d):.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
