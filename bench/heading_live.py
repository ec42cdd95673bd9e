"""Heading held by the body, live: ``limbstream up`` for some minutes without a reset, and the
subject's joint error (``joint_aad_deg``, the aggregator's 60 s error window) read from its stats
at the end of every minute (docs/evaluation.md, "Heading without resets"). Target: the last
minute's at most the first minute's + 1 deg.

    python bench/heading_live.py [--minutes 10] [--heading-correction joints|off]
                                 [-- UP FLAGS (default: --imu raw --imu-model icm42688p
                                              --mounting-deg 90 --heading-deg 180)]

The system runs on this machine (a router, the clock, the emulator, the aggregator; no dashboard)
on a free port; the emulated subject starts with the calibration script (the aggregator
calibrates every stream from it) and is never reset after. The minutes count from when every
device is calibrated. Any ``limbstream up`` flags after ``--`` replace the default sensors, e.g.
``-- --mounting-deg 90 --heading-deg 180 --yaw-drift-dps 0.05`` for the modelled sensors whose
headings drift at up to 3 deg/min. Run it on an idle machine: a loaded one makes ticks late and
the figures noisy.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import zenoh

from limbstream import wire, zconfig
from limbstream.launch import Child, ChildExited, Launcher, free_port, port_open, split_endpoint, wait_until

UP_FLAGS = ("--imu", "raw", "--imu-model", "icm42688p", "--mounting-deg", "90", "--heading-deg", "180")
"""The sensors of the live target: a named part's raw readings fused by VQF 6D on each device (its
heading drifts with the gyroscope offset), strapped at up to 90 deg, headings anywhere."""
CALIBRATED_S = 180.0
"""How long the devices may take to start and be calibrated."""


class Subject:
    """s01's stats as they come (the latest kept)."""

    def __init__(self, session: zenoh.Session, up: Child):
        self.sub = session.declare_subscriber(wire.stats_key("s01"), zenoh.handlers.FifoChannel(1024))
        self.up = up
        self.latest: dict | None = None

    def poll(self) -> dict | None:
        """The latest stats after taking in what came (ChildExited if ``up`` exited)."""
        if not self.up.alive():
            raise ChildExited(self.up)
        while (sample := self.sub.try_recv()) is not None:
            self.latest = wire.decode_stats(sample.payload.to_bytes())
        return self.latest

    def calibrated(self) -> bool:
        stats = self.poll()
        return bool(stats and stats["devices"] and all(d["calibrated"] for d in stats["devices"]))


def run(minutes: int, heading: str, up_flags: list[str]) -> list[dict]:
    """Start ``limbstream up --subjects 1`` with ``up_flags``, read s01's stats for ``minutes``;
    returns a :func:`minute_row` per minute."""
    router = f"tcp/127.0.0.1:{free_port()}"
    args = ["up", "--subjects", "1", "--layout", "paper10", "--router", router, "--no-dashboard", "--heading-correction", heading, *up_flags]
    print("running: limbstream", " ".join(args), file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp, Launcher(logdir=Path(tmp)) as launcher:
        up = launcher.start("up", *args)
        host, port = split_endpoint(router)
        launcher.wait_ready(up, lambda: port_open(host, port), f"the router of up on {router}", 60.0)
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(router,), connect_timeout_s=60.0))
        try:
            subject = Subject(session, up)
            wait_until(subject.calibrated, CALIBRATED_S, "every device of s01 to be calibrated", on_fail=launcher.logs)
            began = time.monotonic()
            print(f"{len(subject.latest['devices'])} devices calibrated; measuring {minutes} min", file=sys.stderr)
            rows = []
            for minute in range(1, minutes + 1):
                wait_until(lambda m=minute: time.monotonic() - began >= 60.0 * m and subject.poll(), 60.0 * minute + 30,
                           f"minute {minute}", interval=0.2, on_fail=launcher.logs)
                rows.append(minute_row(minute, subject.poll()))
                print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
            return rows
        finally:
            session.close()


def _mean(values: list[float]) -> float:
    return sum(values) / len(values) if values else math.nan


def minute_row(minute: int, stats: dict) -> dict:
    """One minute's figures from the subject's stats at its end: joint_aad_deg, frame_aad_deg (60 s
    windows), the mean |heading offset| (deg) and confidence over the corrected devices, and how
    many there are."""
    corrected = [d for d in stats["devices"] if d.get("heading_offset_deg") is not None]
    return {"minute": minute, "joint_aad_deg": stats.get("joint_aad_deg"), "frame_aad_deg": stats.get("frame_aad_deg"),
            "offset": _mean([abs(d["heading_offset_deg"]) for d in corrected]),
            "confidence": _mean([d["heading_confidence"] for d in corrected]), "corrected": len(corrected)}


def _cell(value: float | None) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.2f}"


def table(rows: list[dict]) -> str:
    """The per-minute table (Markdown)."""
    lines = ["| minute | joint error (deg) | frame error (deg) | mean abs heading correction (deg) | mean confidence |",
             "|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['minute']} | " + " | ".join(_cell(r[k]) for k in ("joint_aad_deg", "frame_aad_deg", "offset",
                                                                      "confidence")) + " |" for r in rows]
    return "\n".join(lines)


def verdict(rows: list[dict]) -> tuple[bool, str]:
    """(the target holds, a line saying so): the last minute's joint error <= the first's + 1 deg."""
    first, last = rows[0]["joint_aad_deg"], rows[-1]["joint_aad_deg"]
    if first is None or last is None:
        return False, "no joint error in the stats (no truth tap?)"
    held = last <= first + 1.0
    return held, f"last minute {last:.2f} deg vs first {first:.2f} deg + 1: {'holds' if held else 'does not hold'}"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    own, up_flags = (argv[:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv, list(UP_FLAGS))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=int, default=10)
    parser.add_argument("--heading-correction", choices=("joints", "off"), default="joints")
    args = parser.parse_args(own)
    if args.minutes < 1:
        parser.error("--minutes must be >= 1")
    rows = run(args.minutes, args.heading_correction, up_flags)
    print(f"limbstream up --subjects 1 {' '.join(up_flags)} --heading-correction {args.heading_correction}; "
          "no reset after the start calibration; the subject's stats at the end of each minute (60 s windows)\n")
    print(table(rows))
    held, line = verdict(rows)
    print("\n" + line)
    return 0 if held else 1


if __name__ == "__main__":
    raise SystemExit(main())
