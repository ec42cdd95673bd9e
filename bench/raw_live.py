"""Raw sensors live: ``limbstream up --subjects 1 --imu raw --mounting-deg 90 --heading-deg 180``.

Each emulated device reads its sensor (strapped at up to 90 deg, its filter's heading anywhere),
fuses the readings with VQF and runs fastSW with make run's live rule; the aggregator calibrates
every device from the calibration script its stream begins with. From the aggregator's 1 Hz stats:
when all 10 devices were calibrated (seconds of device time after the first frame), and the
subject's alignment-aware frame error ``frame_aad_deg`` (the aggregator's 60 s error window)
over the first minute of frames compared with the truth and over the tenth, once per part:

    python bench/raw_live.py                       # ideal and icm42688p, 10 minutes each, real time
    python bench/raw_live.py --speed 4 --minutes 3 # quicker, not the figures of docs/evaluation.md

It prints one table (markdown) and the commands it ran.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import zenoh

from limbstream import wire, zconfig
from limbstream.launch import Launcher, free_port


class Stats:
    """The subject's stats over device time: (watermark us, frame_aad_deg, frames compared, all
    calibrated)."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.sub = self.session.declare_subscriber(wire.subject_selector("stats"), zenoh.handlers.FifoChannel(1 << 12))
        self.rows: list[tuple[int, float | None, int, bool]] = []
        self.devices: list[dict] = []

    def poll(self) -> None:
        while (s := self.sub.try_recv()) is not None:
            d = wire.decode_stats(s.payload.to_bytes())
            if d.get("watermark_us"):
                calibrated = len(d["devices"]) == 10 and all(x["calibrated"] for x in d["devices"])
                self.rows.append((d["watermark_us"], d.get("frame_aad_deg"), d.get("frame_error_frames") or 0,
                                  calibrated))
                self.devices = d["devices"]

    def close(self) -> None:
        self.session.close()


def run(model: str, args, workdir: Path) -> dict:
    """One ``up`` run; its figures."""
    workdir.mkdir(parents=True, exist_ok=True)
    router, http = free_port(), free_port()
    argv = ["up", "--subjects", "1", "--layout", "paper10", "--imu", "raw", "--imu-model", model, "--mounting-deg", "90",
            "--heading-deg", "180", "--speed", f"{args.speed:g}", "--router", f"tcp/127.0.0.1:{router}",
            "--http", f"127.0.0.1:{http}", "--status-file", str(workdir / "status.json")]
    print("limbstream " + " ".join(argv), flush=True)
    with Launcher(logdir=workdir) as launcher:
        up = launcher.start("up", *argv)
        stats = None
        deadline = time.monotonic() + 60
        while stats is None:
            try:
                stats = Stats(f"tcp/127.0.0.1:{router}")
            except zconfig.ConnectError:
                if time.monotonic() > deadline or not up.alive():
                    raise RuntimeError(f"up did not start: {Path(up.log).read_text()[-2000:]}") from None
                time.sleep(0.5)
        end = time.monotonic() + (args.minutes * 60 + 30) / args.speed + 90
        first = None
        while up.alive() and time.monotonic() < end:
            stats.poll()
            if first is None and stats.rows:
                first = stats.rows[0][0]
            if first is not None and stats.rows[-1][0] >= first + (args.minutes * 60 + 20) * 1e6:
                break
            time.sleep(0.2)
        stats.poll()
        stats.close()
    return {"model": model, "rows": stats.rows, "devices": stats.devices}


def figures(r: dict, minutes: float) -> dict:
    rows = r["rows"]
    if not rows:
        return {"calibrated_s": None, "first": None, "last": None}
    t0 = rows[0][0]
    calibrated = next(((t - t0) / 1e6 for t, _, _, ok in rows if ok), None)
    compared = [(t, aad) for t, aad, n, _ in rows if n > 0 and aad is not None]

    def at(m: float):  # the 60 s window that ends m minutes after the first frame compared
        if not compared:
            return None
        want = compared[0][0] + m * 60e6
        later = [aad for t, aad in compared if t >= want]
        return later[0] if later else None
    return {"calibrated_s": calibrated, "first": at(1.0), "last": at(minutes)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", default="ideal,icm42688p", help="the parts, one run each (default both)")
    parser.add_argument("--minutes", type=float, default=10.0, help="minutes of device time per run (default 10)")
    parser.add_argument("--speed", type=float, default=1.0, help="up --speed (default 1: real time)")
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory(prefix="raw-live-") as tmp:
        for model in args.models.split(","):
            results.append(run(model, args, Path(tmp) / model))
    last = f"minute {args.minutes:g}"
    print(f"\n| part | all 10 calibrated after (s) | frame_aad_deg, first minute | frame_aad_deg, {last} | "
          "gyro bias (deg/s, largest) | bad raw samples |")
    print("|---|---:|---:|---:|---:|---|")
    for r in results:
        f = figures(r, args.minutes)
        bias = max((d["gyro_bias_dps"] or 0.0 for d in r["devices"]), default=float("nan"))
        faults = {}
        for d in r["devices"]:
            for kind, n in (d.get("raw_faults") or {}).items():
                faults[kind] = faults.get(kind, 0) + n

        def cell(v, fmt=".2f"):
            return "–" if v is None else format(v, fmt)
        kinds = ", ".join(f"{kind} {n}" for kind, n in sorted(faults.items()) if n)
        print(f"| {r['model']} | {cell(f['calibrated_s'], '.1f')} | {cell(f['first'])} | {cell(f['last'])} | "
              f"{bias:.3f} | {sum(faults.values())}{f' ({kinds})' if kinds else ''} |")
    print(f"\n(device time, --speed {args.speed:g}; frame_aad_deg: the aggregator's 60 s window of exact frames "
          "against the truth, ending 1 and N minutes after the first frame compared)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
