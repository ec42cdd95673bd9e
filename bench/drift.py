"""Heading drift and the yaw reset, with and without drift compensation (docs/evaluation.md,
"Calibration").

Ten minutes of motion (the CMU clips, looped) seen through sensors strapped at up to 90 deg, headings
anywhere and drifting at up to +-0.3 deg/s; the subject begins with the calibration script and
stands in the rest pose for 4 s every 2 minutes. Every device's stream goes through fastSW (make
run's settings) and is rebuilt by SLERP, as the aggregator does; it is calibrated from the
script's rest and mounting poses, and its heading reset (yaw) from each later rest hold. The body
error (calibrated reconstruction against the true segments, over the motion, not the holds) with
the heading held between resets, and extrapolated with the drift learned from the last two
(:meth:`limbstream.calibration.Calibration.with_yaw`, as the aggregator does), against perfect
sensors' compression error:

    python bench/drift.py ../shared/data/cmu_10seg_50hz.npz
"""
from __future__ import annotations

import argparse

import numpy as np

from limbstream import calibration, kernel, quat
from limbstream.sources import load


FS = 50.0
HOLD_S, MOVE_S = 4.0, 0.5


def session(path: str, minutes: float, every_s: float) -> tuple[np.ndarray, np.ndarray, slice, slice, list[slice]]:
    """(q (n, 10, 4) true orientations, motion mask (n,), rest and mounting windows of the script,
    the still windows of the later rest holds)."""
    clips = [m.q for m in load(path)]
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (clips[0].shape[1], 1))
    n_move, n_hold = round(MOVE_S * FS), round(HOLD_S * FS)
    u = np.repeat((np.arange(1, n_move + 1) / (n_move + 1))[:, None], identity.shape[0], axis=1)
    length = round((every_s - HOLD_S - 2 * MOVE_S) * FS)  # motion between two holds, samples
    looped = np.concatenate(clips)
    runs = [np.take(looped, np.arange(r * length, (r + 1) * length), axis=0, mode="wrap")
            for r in range(int(np.ceil(minutes * 60 / every_s)))]
    margin = round(calibration.STILL_MARGIN_S * FS)
    parts, motion, holds, n = [], [], [], 0
    for r, run in enumerate(runs):
        parts.append(run)
        motion.append(np.ones(len(run), bool))
        n += len(run)
        if r + 1 == len(runs):
            break
        nxt = runs[r + 1][:1]
        parts += [quat.slerp(run[-1:], identity[None], u), np.broadcast_to(identity, (n_hold, *identity.shape)),
                  quat.slerp(identity[None], nxt, u)]
        holds.append(slice(n + n_move + margin, n + n_move + n_hold - margin))
        motion.append(np.zeros(2 * n_move + n_hold, bool))
        n += 2 * n_move + n_hold
    q, rest, mounting = calibration.with_script(np.concatenate(parts), FS)
    lead = len(q) - n
    holds = [slice(h.start + lead, h.stop + lead) for h in holds]
    return q, np.concatenate([np.zeros(lead, bool)] + motion), rest, mounting, holds


def run(path: str, minutes: float, every_s: float, drift_dps: float, seed: int) -> str:
    q, motion, rest, mounting, holds = session(path, minutes, every_s)
    t = np.arange(len(q)) / FS
    sensors = calibration.SensorModel(90, 180, drift_dps, seed).draw(q.shape[1])
    pose = calibration.mounting_pose()
    errors = {"perfect sensors (compression only)": [], "no reset after the script": [],
              "yaw reset every 2 min, heading held": [], "yaw reset every 2 min, drift compensated": [],
              "drift compensated, from the first yaw reset on": []}
    for s in range(q.shape[1]):
        def rebuilt(samples):
            seg = kernel.segment(t, samples, 9e-4, 25, live_bound_deg=5.0)
            return quat.interpolate(seg.t, quat.normalize(seg.q), t)
        errors["perfect sensors (compression only)"].append(quat.angle_deg(rebuilt(q[:, s])[motion], q[motion, s]))
        reading = rebuilt(sensors.report(s, t, q[:, s]))
        script = calibration.calibrate(reading, rest, mounting, pose[s], t=t)
        errors["no reset after the script"].append(quat.angle_deg(script.apply(reading[motion]), q[motion, s]))
        bounds = [mounting.stop] + [h.stop for h in holds] + [len(t)]
        for compensate, name in ((False, "yaw reset every 2 min, heading held"),
                                 (True, "yaw reset every 2 min, drift compensated")):
            cal, out = script, np.zeros((len(t), 4))
            for k in range(len(bounds) - 1):
                span = slice(bounds[k], bounds[k + 1])
                if k > 0:  # the rest hold just before this span: a yaw reset
                    hold = holds[k - 1]
                    still = calibration.still_mean(reading[hold], f"segment {s}, hold {k}")
                    cal = cal.with_yaw(still, t[hold].mean(), learn_drift=compensate)
                out[span] = cal.apply(reading[span], t[span])
            errors[name].append(quat.angle_deg(out[motion], q[motion, s]))
            if compensate:  # once a drift is learned: from the first yaw reset on
                late = motion & (np.arange(len(t)) >= holds[0].stop)
                errors["drift compensated, from the first yaw reset on"].append(
                    quat.angle_deg(out[late], q[late, s]))
    lines = [f"{minutes:g} min, rest hold every {every_s:g} s, yaw drift up to +-{drift_dps:g} deg/s "
             f"(mounting <= 90, heading +-180, seed {seed}); fastSW TH 9e-4, max_len 25, live bound 5",
             "", "| case | body error mean (deg) | p99 (deg) |", "|---|---:|---:|"]
    for name, parts in errors.items():
        e = np.concatenate(parts)
        lines.append(f"| {name} | {e.mean():.3f} | {np.percentile(e, 99):.3f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", help="motion file (e.g. ../shared/data/cmu_10seg_50hz.npz)")
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--every", type=float, default=120.0, help="a rest hold (and yaw reset) every this many s")
    parser.add_argument("--yaw-drift-dps", type=float, default=0.3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    print(run(args.path, args.minutes, args.every, args.yaw_drift_dps, args.seed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
