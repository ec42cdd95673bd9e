"""A subject standing still does not move through the room, live: ``limbstream up`` (one subject,
``--layout full``, make run's raw sensors) on a motion that stands still, and the pose frames'
``root`` (docs/body.md, "Root translation") read over some minutes. Target: the root stays within
5 cm of where it was after the calibration script over 10 minutes.

    python bench/root_still.py [--minutes 10] [-- UP FLAGS (default: make run's sensors,
                               --imu raw --imu-model icm42688p --mounting-deg 90 --heading-deg 180)]

The motion is one frame, the standing rest pose (every segment at identity, ``rest_pose``
``standing``, arms hanging), repeated: an npz motion file this bench writes, a minute longer than
the minutes measured (a device starts every pass of a motion file with the calibration script). Each device reads its modelled sensor at rest (noise, offsets, its fusion's drifting
heading), sends segment points, and the aggregator calibrates it from the script its stream
starts with and tracks the root from the estimated feet. The system runs on this machine (router,
clock, emulator, aggregator; no dashboard) on a free port. A subscriber takes the subject's exact
pose frames; the reference is the root :data:`SETTLE_S` s of device time after every device
reported calibrated, and the minutes count from it in device time. Per minute the table gives the
root's horizontal and vertical distance from the reference, the largest so far and at the minute's
end (cm), and the share of frames with a foot contact.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import zenoh
from heading_live import CALIBRATED_S, UP_FLAGS, Subject

from limbstream import wire, zconfig
from limbstream.body import FULL
from limbstream.launch import Child, ChildExited, Launcher, free_port, port_open, split_endpoint, wait_until

MARGIN_S = 60.0
"""How much longer than the minutes measured the still clip is, s (a device plays a motion file's
calibration script again at the start of every pass: the minutes must fall in the first)."""
SETTLE_S = 2.0
"""Device time after the first exact frame that follows calibration before the reference, s (the
exact frames come about 0.4 s late: the first ones may still be of the script's last pose)."""


def still_motion(folder: Path, seconds: float) -> Path:
    """Write ``folder/still.npz``: one clip of the standing rest pose on ``full`` at 50 Hz for
    ``seconds`` (every segment at identity); returns its path."""
    frames = round(seconds * wire.DEVICE_RATE_HZ)
    q = np.zeros((frames, len(FULL.segment_names), 4))
    q[..., 0] = 1.0
    path = folder / "still.npz"
    np.savez(path, clip_still=q, fs=np.array(wire.DEVICE_RATE_HZ), segment_names=np.array(FULL.segment_names),
             rest_pose=np.array("standing"))
    return path


class Roots:
    """s01's exact pose frames as they come: (t_us, root (3,) m, contacts)."""

    def __init__(self, session: zenoh.Session, up: Child):
        self.sub = session.declare_subscriber(wire.pose_key("s01"), zenoh.handlers.FifoChannel(1 << 16))
        self.up = up
        self.t_us: list[int] = []
        self.root: list[np.ndarray] = []
        self.contacts: list[int] = []

    def poll(self) -> int:
        """Take in what came; returns the newest exact frame's time, us (-1: none yet)."""
        if not self.up.alive():
            raise ChildExited(self.up)
        while (sample := self.sub.try_recv()) is not None:
            frame = wire.decode_pose(sample.payload.to_bytes())
            if frame.kind == wire.KIND_EXACT:
                self.t_us.append(frame.t_us)
                self.root.append(np.asarray(frame.root, np.float64))
                self.contacts.append(frame.contacts)
        return self.t_us[-1] if self.t_us else -1

    def after(self, t_us: int, everything: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frames from ``t_us`` on (``everything``: all of them): times (F,) s from ``t_us``,
        roots (F, 3) m, contacts (F,)."""
        t = np.array(self.t_us, np.int64)
        keep = (t >= t_us) | everything
        return (t[keep] - t_us) / 1e6, np.array(self.root)[keep], np.array(self.contacts)[keep]


def minute_rows(t: np.ndarray, root: np.ndarray, contacts: np.ndarray, minutes: int) -> list[dict]:
    """Per minute: the largest horizontal and vertical distance from ``root[0]`` so far and at the
    minute's last frame (cm), and the share of the minute's frames with a contact."""
    horizontal = 100 * np.hypot(root[:, 0] - root[0, 0], root[:, 2] - root[0, 2])
    vertical = 100 * np.abs(root[:, 1] - root[0, 1])
    rows = []
    for minute in range(1, minutes + 1):
        upto = t <= 60.0 * minute
        last = int(np.flatnonzero(upto)[-1])
        this = upto & (t > 60.0 * (minute - 1))
        rows.append({"minute": minute, "h_max_cm": float(horizontal[upto].max()), "h_end_cm": float(horizontal[last]),
                     "v_max_cm": float(vertical[upto].max()), "v_end_cm": float(vertical[last]),
                     "contact": float(np.mean(contacts[this] != 0)), "frames": int(this.sum())})
    return rows


def run(minutes: int, up_flags: list[str], save: Path | None = None) -> list[dict]:
    """Start ``limbstream up --subjects 1`` on the still motion with ``up_flags``, read s01's roots
    for ``minutes`` of device time after the reference; returns :func:`minute_rows`. ``save``: an
    npz file to write every exact frame received into (``t`` (F,) s from the reference, ``root``
    (F, 3) m, ``contacts`` (F,))."""
    router = f"tcp/127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as tmp, Launcher(logdir=Path(tmp)) as launcher:
        args = ["up", "--subjects", "1", "--router", router, "--no-dashboard", "--source", str(still_motion(Path(tmp), 60.0 * minutes + MARGIN_S)),
                "--layout", "full", *up_flags]
        print("running: limbstream", " ".join(args), file=sys.stderr)
        up = launcher.start("up", *args)
        host, port = split_endpoint(router)
        launcher.wait_ready(up, lambda: port_open(host, port), f"the router of up on {router}", 60.0)
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(router,), connect_timeout_s=60.0))
        try:
            subject, roots = Subject(session, up), Roots(session, up)
            wait_until(lambda: roots.poll() is not None and subject.calibrated(), CALIBRATED_S, "every device of s01 to be calibrated", on_fail=launcher.logs)
            first = len(roots.t_us)
            wait_until(lambda: subject.poll() and roots.poll() >= 0 and len(roots.t_us) > first, 30.0, "an exact frame after calibration",
                       on_fail=launcher.logs)
            reference = roots.t_us[first] + round(SETTLE_S * 1e6)
            end = reference + round(60e6 * minutes)
            print(f"{len(subject.latest['devices'])} devices calibrated; measuring {minutes} min", file=sys.stderr)
            for minute in range(1, minutes + 1):
                # the stats are taken in too (their channel must not fill)
                wait_until(lambda m=minute: subject.poll() and roots.poll() >= reference + round(60e6 * m), 60.0 * minute + 60.0,
                           f"minute {minute} of frames", interval=0.2, on_fail=launcher.logs)
                print(json.dumps(minute_rows(*roots.after(reference), minute)[-1]), file=sys.stderr, flush=True)
            if save is not None:
                t, root, contacts = roots.after(reference, everything=True)
                np.savez(save, t=t, root=root, contacts=contacts)
            t, root, contacts = roots.after(reference)
            keep = t <= (end - reference) / 1e6
            return minute_rows(t[keep], root[keep], contacts[keep], minutes)
        finally:
            session.close()


def table(rows: list[dict]) -> str:
    """The per-minute table (Markdown)."""
    lines = ["| minute | horizontal, max so far (cm) | horizontal at the end (cm) | vertical, max so far (cm) | "
             "vertical at the end (cm) | frames with a contact |", "|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['minute']} | {r['h_max_cm']:.2f} | {r['h_end_cm']:.2f} | {r['v_max_cm']:.2f} | {r['v_end_cm']:.2f} | "
              f"{100 * r['contact']:.0f} % |" for r in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    own, up_flags = (argv[:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv, list(UP_FLAGS))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=int, default=10)
    parser.add_argument("--save", type=Path, metavar="NPZ", help="also write every exact frame's root there")
    args = parser.parse_args(own)
    if args.minutes < 1:
        parser.error("--minutes must be >= 1")
    rows = run(args.minutes, up_flags, args.save)
    print(f"limbstream up --subjects 1 --source still.npz --layout full {' '.join(up_flags)}; the root of the exact "
          f"pose frames against where it was {SETTLE_S:.0f} s after calibration\n")
    print(table(rows))
    worst = max(max(r["h_max_cm"], r["v_max_cm"]) for r in rows)
    held = worst < 5.0
    print(f"\nlargest distance {worst:.2f} cm over {args.minutes} min (< 5 cm: {'holds' if held else 'does not hold'})")
    return 0 if held else 1


if __name__ == "__main__":
    raise SystemExit(main())
