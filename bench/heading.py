"""Heading held by the body: the joint angle error per minute, with no correction, with yaw resets
every 2 minutes (drift compensated, today's method) and with heading correction
(docs/evaluation.md, "Heading without resets").

The CMU clips are looped for ``--minutes`` and joined smoothly (:mod:`limbstream.sources.loop`);
the calibration script comes first. Each sensor sits on its segment at up to 90 deg with its
heading anywhere, and its heading drifts as a 6D filter's does (:mod:`limbstream.heading.simulate`:
a vertical gyro bias of up to ``--bias-dps`` that wanders, and inclination noise); ``--bad-day``
doubles the bias. Every stream goes through fastSW (make run's settings) and SLERP, and is
calibrated from the script's rest and mounting poses, as the aggregator does. Two sessions:

- ``loop``: the motion alone after the script (no still pose anywhere);
- ``holds``: the same motion, interrupted every 2 minutes by a 4 s rest hold (what a yaw reset
  needs; heading correction may use it too, unasked).

The joint angle error (the angle between the estimated and the true relative orientation of each
joint, :func:`limbstream.heading.joints.joint_errors_deg`) is averaged per minute over the motion
(not the holds), per joint class:

    python bench/heading.py ../shared/data/cmu_10seg_50hz.npz [--minutes 10] [--bad-day]
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from limbstream import calibration, kernel, quat  # noqa: E402
from limbstream.heading import HeadingCorrection, Settings  # noqa: E402
from limbstream.heading.joints import Layout, joint_errors_deg  # noqa: E402
from limbstream.heading.simulate import DriftModel  # noqa: E402
from limbstream.sources import Motion, load  # noqa: E402
from limbstream.sources.loop import looped  # noqa: E402

FS = 50.0
HOLD_S, MOVE_S, EVERY_S = 4.0, 0.5, 120.0
BODIES = {"full": None, "lower": ("l_shank", "r_shank", "l_thigh", "r_thigh", "hip"),
          "upper": ("l_lowerarm", "r_lowerarm", "l_upperarm", "r_upperarm", "neck", "hip")}


@dataclass
class Session:
    """True orientations ``q`` (n, S, 4) at FS Hz, ``motion`` (n,) scored samples, the script's
    still windows ``rest`` and ``mounting``, the later rest holds' still windows ``holds``, and
    ``start``, the index of the first sample after the script."""

    q: np.ndarray
    motion: np.ndarray
    rest: slice
    mounting: slice
    holds: list[slice]
    start: int


def sessions(clip: Motion, minutes: float, segments: tuple[str, ...] | None) -> tuple[dict[str, Session], Layout]:
    """The ``loop`` and ``holds`` sessions of ``clip`` looped for ``minutes`` (only ``segments``)."""
    names = clip.segments
    keep = [names.index(s) for s in (segments or names)]
    motion = looped([clip], minutes * 60).q[:, keep]
    names = tuple(names[k] for k in keep)
    layout = Layout.of(names, clip.rest_pose)
    q, rest, mounting = calibration.with_script(motion, FS, names)
    start = len(q) - len(motion)
    out = {"loop": Session(q, np.arange(len(q)) >= start, rest, mounting, [], start)}

    identity = np.tile([1.0, 0.0, 0.0, 0.0], (len(names), 1))
    n_move, n_hold = round(MOVE_S * FS), round(HOLD_S * FS)
    u = np.repeat((np.arange(1, n_move + 1) / (n_move + 1))[:, None], len(names), axis=1)
    run = round((EVERY_S - HOLD_S - 2 * MOVE_S) * FS)
    margin = round(calibration.STILL_MARGIN_S * FS)
    parts, scored, holds, n, k = [], [], [], 0, 0
    while k < len(motion):
        part = motion[k:k + run]
        parts.append(part)
        scored.append(np.ones(len(part), bool))
        n, k = n + len(part), k + len(part)
        if k >= len(motion):
            break
        parts += [quat.slerp(part[-1:], identity[None], u), np.broadcast_to(identity, (n_hold, *identity.shape)),
                  quat.slerp(identity[None], motion[k:k + 1], u)]
        holds.append(slice(start + n + n_move + margin, start + n + n_move + n_hold - margin))
        scored.append(np.zeros(2 * n_move + n_hold, bool))
        n += 2 * n_move + n_hold
    q = np.concatenate([q[:start]] + parts)
    out["holds"] = Session(q, np.concatenate([np.zeros(start, bool)] + scored), rest, mounting, holds, start)
    return out, layout


def calibrated(s: Session, names: tuple[str, ...], drift: DriftModel,
               stream: int) -> tuple[np.ndarray, list[calibration.Calibration]]:
    """(n, S, 4) what the system holds of each stream after fastSW, SLERP and the script's
    calibration (its heading still drifting), and the calibrations; the sensors are drawn from
    the seeds of ``drift`` and ``stream``."""
    t = np.arange(len(s.q)) / FS
    n_seg = s.q.shape[1]
    sensors = calibration.SensorModel(90, 180, 0.0, drift.seed).draw(n_seg, stream)
    drifted = drift.draw(t, n_seg, stream).apply(s.q)
    pose = calibration.mounting_pose(names)
    out, cals = np.empty_like(s.q), []
    for k in range(n_seg):
        seg = kernel.segment(t, sensors.report(k, t, drifted[:, k]), 9e-4, 25, live_bound_deg=5.0)
        rebuilt = quat.interpolate(seg.t, quat.normalize(seg.q), t)
        cal = calibration.calibrate(rebuilt, s.rest, s.mounting, pose[k], t=t)
        out[:, k] = cal.apply(rebuilt)
        cals.append(cal)
    return out, cals


def with_resets(s: Session, q_cal: np.ndarray, cals: list[calibration.Calibration]) -> np.ndarray:
    """(n, S, 4) ``q_cal`` with a yaw reset at every rest hold, the drift learned from the last
    two and compensated (:meth:`limbstream.calibration.Calibration.with_yaw`)."""
    t = np.arange(len(s.q)) / FS
    bounds = [s.mounting.stop] + [h.stop for h in s.holds] + [len(t)]
    out = q_cal.copy()
    for k, cal in enumerate(cals):
        reading = cal.undo(q_cal[:, k])
        for b in range(1, len(bounds) - 1):
            hold, span = s.holds[b - 1], slice(bounds[b], bounds[b + 1])
            cal = cal.with_yaw(calibration.still_mean(reading[hold], f"segment {k}, hold {b}"), t[hold].mean())
            out[span, k] = cal.apply(reading[span], t[span])
    return out


def corrected(s: Session, q_cal: np.ndarray, layout: Layout, settings: Settings) -> np.ndarray:
    """(n, S, 4) ``q_cal`` corrected by the heading estimator, run from the calibration on."""
    out = q_cal.copy()
    start = s.mounting.stop
    out[start:] = HeadingCorrection.batch(q_cal[start:], layout, FS, settings)
    return out


def per_minute(s: Session, q_est: np.ndarray, layout: Layout) -> dict[str, np.ndarray]:
    """Joint class -> (minutes,) mean joint angle error over the scored samples of each minute
    after the script, degrees."""
    err = joint_errors_deg(q_est[s.motion], s.q[s.motion], layout)
    minute = ((np.flatnonzero(s.motion) - s.start) / FS // 60).astype(int)
    out = {}
    for name, mask in layout.classes().items():
        e = err[:, mask].mean(axis=1)
        out[name] = np.bincount(minute, e) / np.maximum(np.bincount(minute), 1)
    return out


CASES = ("loop: no correction", "loop: heading correction", "holds: no correction",
         "holds: yaw resets, drift compensated", "holds: heading correction")


def clip_rows(clip: Motion, minutes: float, body: str, drift: DriftModel, stream: int,
              settings: Settings) -> tuple[dict[str, dict[str, np.ndarray]], Layout]:
    """Case -> joint class -> (minutes,) mean joint angle error of one clip looped, its sensors
    drawn from stream ``stream``."""
    runs, layout = sessions(clip, minutes, BODIES[body])
    rows: dict[str, dict[str, np.ndarray]] = {}
    for name, s in runs.items():
        q_cal, cals = calibrated(s, layout.segments, drift, stream)
        rows[f"{name}: no correction"] = per_minute(s, q_cal, layout)
        if s.holds:
            rows[f"{name}: yaw resets, drift compensated"] = per_minute(s, with_resets(s, q_cal, cals), layout)
        rows[f"{name}: heading correction"] = per_minute(s, corrected(s, q_cal, layout, settings), layout)
    return rows, layout


def run(path: str, minutes: float, body: str, drift: DriftModel, settings: Settings,
        verbose: bool = False) -> str:
    clips = load(path)
    began = time.perf_counter()
    per_clip = []
    for k, clip in enumerate(clips):
        rows, layout = clip_rows(clip, minutes, body, drift, k, settings)
        per_clip.append(rows)
        if verbose:
            print(clip.name, {k: {c: np.round(v, 1).tolist() for c, v in r.items()} for k, r in rows.items()},
                  file=sys.stderr)
    print(f"({len(clips)} clips in {time.perf_counter() - began:.0f} s)", file=sys.stderr)
    n_min = min(len(v) for rows in per_clip for r in rows.values() for v in r.values())
    lines = [f"{len(clips)} clips, each looped for {minutes:g} min; {body} body ({len(layout.segments)} sensors); "
             f"bias up to +-{drift.bias_dps:g} deg/s wandering {drift.walk:g} deg/s/sqrt(s), tilt "
             f"{drift.tilt_deg:g} deg, seed {drift.seed} (each clip its own sensors); fastSW TH 9e-4, max_len 25, live bound 5. "
             "Joint angle error (deg), mean of the clips, per minute:", ""]
    for cls in layout.classes():
        members = [j for j, h in zip(layout.joints, layout.hinge) if (cls == "hinge") == h]
        lines += [f"**{cls} joints** ({', '.join(members)})", "",
                  "| case | " + " | ".join(str(m + 1) for m in range(n_min)) + " |", "|---|" + "---:|" * n_min]
        for name in CASES:
            mean = np.mean([rows[name][cls][:n_min] for rows in per_clip], axis=0)
            lines.append(f"| {name} | " + " | ".join(f"{v:.2f}" for v in mean) + " |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", help="motion file (e.g. ../shared/data/cmu_10seg_50hz.npz)")
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--body", choices=tuple(BODIES), default="full", help="which sensors (default all 10)")
    parser.add_argument("--bias-dps", type=float, default=DriftModel.bias_dps,
                        help="vertical gyro bias, uniform +-, deg/s (default %(default)s)")
    parser.add_argument("--bad-day", action="store_true", help="bias and its wander doubled")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--verbose", action="store_true", help="also each clip's rows (to stderr)")
    args = parser.parse_args(argv)
    drift = DriftModel(bias_dps=args.bias_dps, seed=args.seed)
    print(run(args.path, args.minutes, args.body, drift.bad_day() if args.bad_day else drift, Settings(),
              args.verbose))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
