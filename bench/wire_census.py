"""What crosses the router, per device and second, by kind (docs/benchmarks.md, "Wire census").

    python bench/wire_census.py                      # 10 subjects (100 devices), make run's settings, 20 s
    python bench/wire_census.py --subjects 20 --seconds 30 -- --no-truth

Starts a real router and the parts ``limbstream up`` starts (its ``plan``, with the Makefile's
RUN_FLAGS and the 10-segment layout; arguments after ``--`` are added to ``up``'s), waits for
the first pose frames, then counts for ``--seconds`` what an observer session sees:

- every sample on ``limbstream/**`` by its key's last chunk (seg, raw, pose, stats, angles, ...);
- the advanced publishers' miss-detection heartbeats (``<key>/@adv/pub/<zid>/<eid>/_``, whose
  ``@adv`` chunk no ``**`` matches) by the kind of the key they serve;
- liveliness token changes (device ``alive`` tokens, advanced publisher/subscriber detection);
- the config poll: one status query asked here as the aggregator asks it, its replies' bytes
  times the poll rate (queries cross the router, but no subscriber sees them).

Bytes are payload bytes (key expressions, Zenoh headers and batching are not counted). Prints a
markdown table: messages and bytes per device per second by kind.
"""
from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from limbstream import wire, zconfig
from limbstream.cli import up
from limbstream.launch import Launcher, free_port, wait_until
from limbstream.services.aggregator.settings import AggregatorSettings

ROOT = Path(__file__).resolve().parent.parent
RUN_FLAGS = ["--imu", "raw", "--imu-model", "icm42688p", "--mounting-deg", "90", "--heading-deg", "180"]
"""The Makefile's RUN_FLAGS (``make run``)."""
LAYOUT = ["--layout", "paper10"]
"""The 10-segment layout the census counts (``up``'s default is ``full``, 15 devices a subject)."""


class Census:
    """Counts (messages, payload bytes) by kind, from Zenoh callbacks (a lock: they run on Zenoh's threads)."""

    def __init__(self) -> None:
        self.msgs: collections.Counter = collections.Counter()
        self.bytes: collections.Counter = collections.Counter()
        self.on = False
        self._lock = threading.Lock()

    def add(self, kind: str, size: int) -> None:
        if self.on:
            with self._lock:
                self.msgs[kind] += 1
                self.bytes[kind] += size

    def sample(self, sample: zenoh.Sample) -> None:
        self.add(kind_of(str(sample.key_expr)), len(sample.payload))

    def token(self, sample: zenoh.Sample) -> None:
        self.add(f"liveliness {kind_of(str(sample.key_expr))}", 0)


def kind_of(key: str) -> str:
    """A message's kind from its key: the last chunk of a limbstream key; for Zenoh's advanced
    publishers' and subscribers' keys (``<key>/@adv/pub|sub/...``) "heartbeat <kind>" or
    "detection <kind>"."""
    if "/@adv/" in key:
        served, rest = key.split("/@adv/", 1)
        role = "heartbeat" if rest.startswith("pub/") else "detection"
        return f"{role} {served.rsplit('/', 1)[-1]}"
    return key.rsplit("/", 1)[-1] if key.startswith(wire.PREFIX + "/") else key


def count_config_replies(session: zenoh.Session) -> tuple[int, int]:
    """(replies, payload bytes) of one status query of every device, asked as the aggregator's poll."""
    replies = session.get(wire.device_selector(wire.CONFIG, "*"), zenoh.handlers.FifoChannel(1 << 14), timeout=5.0)
    n = size = 0
    for reply in replies:
        if reply.ok is not None:
            n += 1
            size += len(reply.ok.payload)
    return n, size


def run(subjects: int, seconds: float, extra: list[str]) -> None:
    parser = argparse.ArgumentParser()
    up.add_arguments(parser)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    args = parser.parse_args([*RUN_FLAGS, *LAYOUT, "--subjects", str(subjects), "--router", endpoint, *extra])
    census = Census()
    with Launcher(Path(tempfile.mkdtemp(prefix="limbstream-census-")), cwd=ROOT) as launcher:
        launcher.router(endpoint)
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        assert session is not None
        keep = [session.declare_subscriber(k, census.sample)
                for k in (f"{wire.PREFIX}/**", f"{wire.PREFIX}/**/@adv/**", f"{wire.PREFIX}/@time/**")]
        keep += [session.liveliness().declare_subscriber(k, census.token)
                 for k in (f"{wire.PREFIX}/**", f"{wire.PREFIX}/**/@adv/**")]
        for name, argv in up.plan(args):
            launcher.start(name, *argv)
        seen: set[str] = set()
        poses = session.declare_subscriber(wire.subject_selector(wire.POSE, "*"),
                                           lambda s: seen.add(str(s.key_expr)))
        wait_until(lambda: len(seen) >= subjects, 120, "a pose frame of every subject", on_fail=launcher.logs)
        poses.undeclare()
        time.sleep(2.0)  # past the start's history queries
        census.on = True
        began = time.monotonic()
        time.sleep(seconds)
        census.on = False
        elapsed = time.monotonic() - began
        replies, reply_bytes = count_config_replies(session)
        for sub in keep:
            sub.undeclare()
        session.close()
    devices = replies or subjects * 10
    poll = 1.0 / AggregatorSettings().config_poll_s
    rows = [(kind, census.msgs[kind] / elapsed, census.bytes[kind] / elapsed) for kind in census.msgs]
    rows.append(("config replies (status poll)", replies * poll, reply_bytes * poll))
    print(f"\n{subjects} subjects, {devices} devices, {elapsed:.1f} s counted; up {' '.join(args_shown(extra))}\n")
    print("| kind | messages/s per device | payload B/s per device | B per message |")
    print("|---|---:|---:|---:|")
    total_m = total_b = 0.0
    for kind, m, b in sorted(rows, key=lambda r: -r[1]):
        total_m, total_b = total_m + m, total_b + b
        print(f"| {kind} | {m / devices:.3f} | {b / devices:.1f} | {b / m if m else 0:.0f} |")
    print(f"| **all** | **{total_m / devices:.3f}** | **{total_b / devices:.1f}** | |")


def args_shown(extra: list[str]) -> list[str]:
    return [*RUN_FLAGS, *LAYOUT, *extra]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--subjects", type=int, default=10, help="subjects emulated (10 devices each; default 10)")
    p.add_argument("--seconds", type=float, default=20.0, help="how long to count (default 20)")
    p.add_argument("extra", nargs="*", help="more `limbstream up` flags (after --)")
    args = p.parse_args(argv)
    run(args.subjects, args.seconds, args.extra)
    return 0


if __name__ == "__main__":
    sys.exit(main())
