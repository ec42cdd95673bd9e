"""What Zenoh's receive threads cost a subscriber, by advanced subscriber option (docs/benchmarks.md,
"Late-publisher detection").

    python bench/zenoh_rx.py                                  # 2,000 publishers at 3.5 Hz, 12 s each
    python bench/zenoh_rx.py --publishers 500 --rate 14 --seconds 20

A router, one process of ``--publishers`` advanced publishers (as a device's points: cache, a
sporadic miss-detection heartbeat, publisher detection) putting a 48-byte payload ``--rate`` times
a second each (keys ``bench/sNNN/seg/dN``, ten a subject), and one subscriber process per row,
which drains its FIFO channel every 20 ms as the aggregator does. After ``--warm-up`` s (history
queries answered), the subscriber's CPU over ``--seconds`` is read per thread: its Python thread
(the drain) and Zenoh's (rx, tx, net, app...). One row per subscriber kind:

- ``plain``: ``declare_subscriber``;
- ``history``: an advanced subscriber with history (its initial query) only;
- ``history, recovery``: plus recovery by heartbeat and subscriber detection (the aggregator's);
- ``history + late publishers, recovery``: plus late-publisher detection (the aggregator before).
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

import zenoh
import zenoh.ext as zext

sys.path.insert(0, str(Path(__file__).resolve().parent))
from soak import thread_cpu_s  # noqa: E402

from limbstream.launch import free_port  # noqa: E402

KINDS = ("plain", "history", "history, recovery", "history + late publishers, recovery")
KEYS = "bench/*/seg/*"


def _config(mode: str, endpoint: str, listen: bool = False) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints" if listen else "connect/endpoints", json.dumps([endpoint]))
    return config


def _router(endpoint: str, stop) -> None:
    session = zenoh.open(_config("router", endpoint, listen=True))
    stop.wait()
    session.close()


def _publishers(endpoint: str, n: int, rate: float, stop) -> None:
    session = zenoh.open(_config("client", endpoint))
    pubs = [zext.declare_advanced_publisher(
        session, f"bench/s{i // 10:03d}/seg/d{i % 10}", cache=zext.CacheConfig(max_samples=64),
        sample_miss_detection=zext.MissDetectionConfig(sporadic_heartbeat=2.0),  # type: ignore[call-arg]
        publisher_detection=True) for i in range(n)]
    payload, start, tick = bytes(48), time.monotonic(), 0
    while not stop.is_set():
        tick += 1
        for pub in pubs:
            pub.put(payload)
        time.sleep(max(0.0, start + tick / rate - time.monotonic()))
    session.close()


def _subscribe(session: zenoh.Session, kind: str):
    channel = zenoh.handlers.FifoChannel(1 << 16)
    if kind == "plain":
        return session.declare_subscriber(KEYS, channel)
    options: dict = {"history": zext.HistoryConfig(detect_late_publishers="late" in kind, max_samples=64)}
    if "recovery" in kind:
        options.update(recovery=zext.RecoveryConfig(heartbeat=True), subscriber_detection=True)
    return zext.declare_advanced_subscriber(session, KEYS, channel, **options)


def _subscriber(endpoint: str, kind: str, warm_up: float, seconds: float, out) -> None:
    session = zenoh.open(_config("client", endpoint))
    sub = _subscribe(session, kind)

    def drain(until: float) -> int:
        n = 0
        while time.monotonic() < until:
            while sub.try_recv() is not None:
                n += 1
            time.sleep(0.02)
        return n
    drain(time.monotonic() + warm_up)
    before, t0 = thread_cpu_s(os.getpid()), time.monotonic()
    received = drain(t0 + seconds)
    elapsed, after = time.monotonic() - t0, thread_cpu_s(os.getpid())
    used = {name: 100 * (v - before.get(name, 0.0)) / elapsed for name, v in after.items()}
    out.put((received / elapsed, used.pop("python", 0.0), sum(used.values())))
    session.close()


def run(kind: str, publishers: int, rate: float, warm_up: float, seconds: float) -> tuple[float, float, float]:
    """(samples received per second, the subscriber's Python thread and Zenoh's threads, % of a core)."""
    endpoint, stop, out = f"tcp/127.0.0.1:{free_port()}", mp.Event(), mp.Queue()
    router = mp.Process(target=_router, args=(endpoint, stop))
    router.start()
    time.sleep(0.5)  # the router listening (the clients would retry, but each retry costs 1 s)
    pub = mp.Process(target=_publishers, args=(endpoint, publishers, rate, stop))
    sub = mp.Process(target=_subscriber, args=(endpoint, kind, warm_up, seconds, out))
    pub.start()
    sub.start()
    result = out.get()
    stop.set()
    for p in (sub, pub, router):
        p.join()
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--publishers", type=int, default=2000)
    p.add_argument("--rate", type=float, default=3.5, help="puts per publisher per second")
    p.add_argument("--warm-up", type=float, default=15.0, help="s before the measurement")
    p.add_argument("--seconds", type=float, default=12.0, help="s measured per row")
    a = p.parse_args(argv)
    print(f"{a.publishers} publishers x {a.rate:g} Hz ({a.publishers * a.rate:,.0f} samples/s)\n")
    print("| subscriber | samples/s received | its Python thread, % of a core | Zenoh's threads, % of a core |")
    print("|---|---:|---:|---:|")
    for kind in KINDS:
        received, python, zenoh_threads = run(kind, a.publishers, a.rate, a.warm_up, a.seconds)
        print(f"| {kind} | {received:,.0f} | {python:.1f} | {zenoh_threads:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
