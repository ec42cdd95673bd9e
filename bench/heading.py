"""Heading held by the body: the joint angle error per minute, with no correction, with yaw resets
every 2 minutes (drift compensated, today's method) and with heading correction
(docs/evaluation.md, "Heading without resets").

Each CMU clip is looped for ``--minutes`` and joined smoothly (:mod:`limbstream.sources.loop`),
the calibration script first. Each sensor sits on its segment at up to 90 deg with its filter's
heading anywhere. The chain (``--chain raw``, the default): what the part reads
(:mod:`limbstream.imu`, ICM-42688-P at 200 Hz) is fused by VQF 6D (the PyPI package), whose
output the device takes at 50 Hz; ``--bad-day`` doubles the part's gyro offset and its warming
drift. ``--chain simulated`` instead turns each sensor's heading as a 6D filter's drifts
(:mod:`limbstream.heading.simulate`: a vertical bias of up to ``--bias-dps``, wandering, and
inclination noise). Every stream then goes through fastSW (make run's settings) and SLERP, and is
calibrated from the script's rest and mounting poses, as the aggregator does. Two sessions:

- ``loop``: the motion alone after the script (no still pose anywhere);
- ``holds``: the same motion, interrupted every 2 minutes by a 4 s rest hold (what a yaw reset
  needs; heading correction may use it too, unasked).

The joint angle error (the angle between the estimated and the true relative orientation of each
joint, :func:`limbstream.heading.joints.joint_errors_deg`) is averaged per minute over the motion
(not the holds), per joint class:

    python bench/heading.py ../shared/data/cmu_10seg_50hz.npz [--minutes 10] [--bad-day] [--chain simulated]
        [--sessions loop] [--kind hip] [--mislabel]

``--mislabel`` reads each clip as a source whose rest pose is not what it says would give it
(:func:`limbstream.heading.simulate.zero_pose_along_x`): the correction must see its joints'
constraints contradicted and stop (stderr names the clips where it did) instead of following them.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, replace

import numpy as np

from limbstream import calibration, imu, kernel, quat
from limbstream.evaluation.fusion import reference_vqf
from limbstream.heading import HeadingCorrection, Settings
from limbstream.evaluation.body import KINDS
from limbstream.heading.joints import Layout, joint_errors_deg, kind as joint_kind
from limbstream.heading.simulate import DriftModel, zero_pose_along_x
from limbstream.sources import Motion, load
from limbstream.sources.loop import looped

FS = 50.0
RAW_HZ = 200.0
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


def sessions(clip: Motion, minutes: float, segments: tuple[str, ...] | None,
             which: tuple[str, ...] = ("loop", "holds")) -> tuple[dict[str, Session], Layout]:
    """The sessions ``which`` (``loop``, ``holds``) of ``clip`` looped for ``minutes`` (only ``segments``)."""
    names = clip.segments
    keep = [names.index(s) for s in (segments or names)]
    motion = looped([clip], minutes * 60).q[:, keep]
    names = tuple(names[k] for k in keep)
    layout = Layout.of(names, clip.rest_pose)
    q, rest, mounting = calibration.with_script(motion, FS, names)
    start = len(q) - len(motion)
    out = {"loop": Session(q, np.arange(len(q)) >= start, rest, mounting, [], start)}
    if "holds" not in which:
        return out, layout

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


@dataclass(frozen=True)
class Chain:
    """Where the devices' orientations come from: ``raw``, the readings of the part ``model``
    (ICM-42688-P) at 200 Hz fused by VQF 6D (the PyPI package), its gyro offset and warming
    doubled on a ``bad_day``; or ``simulated``, :class:`DriftModel` headings (``drift``)."""

    kind: str
    model: str = "icm42688p"
    bad_day: bool = False
    drift: DriftModel = DriftModel()
    seed: int = 0

    def describe(self) -> str:
        day = "bad day (gyro offset doubled)" if self.bad_day else "typical day"
        if self.kind == "raw":
            return (f"{self.model} readings at {RAW_HZ:g} Hz -> VQF 6D ({day}); mounting <= 90, heading +-180, "
                    f"seed {self.seed}")
        d = self.drift.bad_day() if self.bad_day else self.drift
        return (f"simulated 6D headings ({day}): vertical bias up to +-{d.bias_dps:g} deg/s wandering {d.walk:g} "
                f"deg/s/sqrt(s), tilt {d.tilt_deg:g} deg; mounting <= 90, heading +-180, seed {self.seed}")

    def readings(self, s: Session, names: tuple[str, ...], rest_pose: str, stream: int) -> tuple[np.ndarray, np.ndarray]:
        """(n, S, 4) each device's orientation (Y-up world) at FS Hz over the session, and the
        segments' true orientations (what the sensors really turned through)."""
        t = np.arange(len(s.q)) / FS
        sensors = calibration.SensorModel(90, 180, 0.0, self.seed)
        if self.kind == "simulated":
            drift = self.drift.bad_day() if self.bad_day else self.drift
            drawn = sensors.draw(len(names), stream)
            drifted = drift.draw(t, len(names), stream).apply(s.q)
            return np.stack([drawn.report(k, t, drifted[:, k]) for k in range(len(names))], axis=1), s.q
        part = imu.model(self.model)
        if self.bad_day:
            part = replace(part, gyro_offset_dps=2 * part.gyro_offset_dps, gyro_tempco_dps_c=2 * part.gyro_tempco_dps_c)
        devices = imu.ImuDevices(len(names), part, RAW_HZ, sensors, stream)
        motion = Motion(t[s.start:] - t[s.start], s.q[s.start:], names, "session", rest_pose)
        rec = imu.record(motion, devices)
        step = round(RAW_HZ / FS)
        fused = reference_vqf(rec.gyr, rec.acc, RAW_HZ, start_heading=imu.earth_heading(devices.heading))
        world = quat.multiply(quat.Z_UP_TO_Y_UP, fused[::step])[:len(t)]
        truth = quat.multiply(quat.multiply(quat.Z_UP_TO_Y_UP, rec.truth[::step]),
                              quat.conjugate(devices.mounting))[:len(t)]
        return world, quat.continuous(truth)


def calibrated(s: Session, readings: np.ndarray, names: tuple[str, ...]) -> tuple[np.ndarray, list[calibration.Calibration]]:
    """(n, S, 4) what the system holds of each device's ``readings`` (n, S, 4) after fastSW,
    SLERP and the script's calibration (its heading still drifting), and the calibrations."""
    t = np.arange(len(s.q)) / FS
    pose = calibration.mounting_pose(names)
    out, cals = np.empty_like(s.q), []
    for k in range(len(names)):
        seg = kernel.segment(t, readings[:, k], 9e-4, 25, live_bound_deg=5.0)
        rebuilt = quat.interpolate(seg.t, quat.normalize(seg.q), t)
        cal = calibration.calibrate(rebuilt, s.rest, s.mounting, pose[k], t=t)
        out[:, k] = cal.apply(rebuilt)
        cals.append(cal)
    return out, cals


def with_resets(s: Session, q_cal: np.ndarray, cals: list[calibration.Calibration]) -> tuple[np.ndarray, int]:
    """(n, S, 4) ``q_cal`` with a yaw reset at every rest hold, the drift learned from the last
    two and compensated (:meth:`limbstream.calibration.Calibration.with_yaw`), and how many resets
    were refused. A fusion filter may still settle early in a hold (VQF pulls the inclination back
    within seconds of a fast move): a hold refused as not still is tried again over its second
    half, as a user would press again; refused twice, the device keeps its calibration."""
    t = np.arange(len(s.q)) / FS
    bounds = [s.mounting.stop] + [h.stop for h in s.holds] + [len(t)]
    out, refused = q_cal.copy(), 0
    for k, cal in enumerate(cals):
        reading = cal.undo(q_cal[:, k])
        for b in range(1, len(bounds) - 1):
            hold, span = s.holds[b - 1], slice(bounds[b], bounds[b + 1])
            for window in (hold, slice((hold.start + hold.stop) // 2, hold.stop)):
                try:
                    still = calibration.still_mean(reading[window], f"segment {k}, hold {b}")
                except calibration.CalibrationError:
                    continue
                cal = cal.with_yaw(still, t[window].mean())
                break
            else:
                refused += 1
            out[span, k] = cal.apply(reading[span], t[span])
    return out, refused


def corrected(s: Session, q_cal: np.ndarray, layout: Layout, settings: Settings,
              name: str = "") -> np.ndarray:
    """(n, S, 4) ``q_cal`` corrected by the heading estimator, run from the calibration on; where
    it finds the joints' constraints contradicted and stops (:mod:`limbstream.heading.contradiction`),
    a line to stderr says so (``name``: the clip and session)."""
    out = q_cal.copy()
    start = s.mounting.stop
    out[start:], est = HeadingCorrection.run_over(q_cal[start:], layout, FS, settings)
    if est.contradicted[0]:
        shares = ", ".join(f"{j} {v:.2f}" for j, v in est.contradicted_joints(0).items())
        print(f"({name}: constraints contradicted at {est.stopped_s[0]:.0f} s: {shares}; correction stopped)",
              file=sys.stderr)
    return out


def groups(layout: Layout, kind: str | None) -> dict[str, np.ndarray]:
    """Joint group name -> (J,) mask: the joint classes (hinge, 3-DoF), or the joints of one kind."""
    if kind is None:
        return layout.classes()
    mask = np.array([joint_kind(j) == kind for j in layout.joints])
    if not mask.any():
        raise SystemExit(f"no {kind} joint among {', '.join(layout.joints)}")
    return {kind: mask}


def per_minute(s: Session, q_est: np.ndarray, truth: np.ndarray, layout: Layout,
               kind: str | None = None) -> dict[str, np.ndarray]:
    """Joint group (:func:`groups`) -> (minutes,) mean joint angle error against ``truth`` over
    the scored samples of each minute after the script, degrees."""
    err = joint_errors_deg(q_est[s.motion], truth[s.motion], layout)
    minute = ((np.flatnonzero(s.motion) - s.start) / FS // 60).astype(int)
    out = {}
    for name, mask in groups(layout, kind).items():
        e = err[:, mask].mean(axis=1)
        out[name] = np.bincount(minute, e) / np.maximum(np.bincount(minute), 1)
    return out


CASES = ("loop: no correction", "loop: heading correction", "holds: no correction",
         "holds: yaw resets, drift compensated", "holds: heading correction")


@dataclass(frozen=True)
class Plan:
    """What to run: each clip looped for ``minutes``, the sensors of ``body``, the sessions
    ``which``; the error of joint ``kind`` alone (None: per class); ``mislabel``: each clip read as
    a BVH file whose zero pose has every bone along +X would be, labelled with its rest pose
    (:func:`limbstream.heading.simulate.zero_pose_along_x`)."""

    minutes: float = 10.0
    body: str = "full"
    which: tuple[str, ...] = ("loop", "holds")
    kind: str | None = None
    mislabel: bool = False


def clip_rows(clip: Motion, plan: Plan, chain: Chain, stream: int,
              settings: Settings) -> tuple[dict[str, dict[str, np.ndarray]], Layout]:
    """Case -> joint group -> (minutes,) mean joint angle error of one clip looped, its sensors
    drawn from stream ``stream``."""
    if plan.mislabel:
        clip = replace(clip, q=zero_pose_along_x(clip.q, clip.segments, clip.rest_pose))
    runs, layout = sessions(clip, plan.minutes, BODIES[plan.body], plan.which)
    rows: dict[str, dict[str, np.ndarray]] = {}
    for name, s in runs.items():
        readings, truth = chain.readings(s, layout.segments, clip.rest_pose, stream)
        q_cal, cals = calibrated(s, readings, layout.segments)
        rows[f"{name}: no correction"] = per_minute(s, q_cal, truth, layout, plan.kind)
        if s.holds:
            reset, refused = with_resets(s, q_cal, cals)
            rows[f"{name}: yaw resets, drift compensated"] = per_minute(s, reset, truth, layout, plan.kind)
            if refused:
                print(f"({clip.name}: {refused} of {len(s.holds) * len(layout.segments)} resets refused, not still)",
                      file=sys.stderr)
        rows[f"{name}: heading correction"] = per_minute(s, corrected(s, q_cal, layout, settings, f"{clip.name}, {name}"),
                                                         truth, layout, plan.kind)
    return rows, layout


def run(path: str, plan: Plan, chain: Chain, settings: Settings, verbose: bool = False,
        skip: tuple[str, ...] = ()) -> str:
    clips = [clip for clip in load(path) if clip.name not in skip]
    began = time.perf_counter()
    per_clip = []
    for clip in clips:
        stream = sum(ord(c) for c in clip.name)  # each clip its own sensors, whichever clips are run
        rows, layout = clip_rows(clip, plan, chain, stream, settings)
        per_clip.append(rows)
        if verbose:
            print(clip.name, {k: {c: np.round(v, 1).tolist() for c, v in r.items()} for k, r in rows.items()},
                  file=sys.stderr)
    print(f"({len(clips)} clips in {time.perf_counter() - began:.0f} s)", file=sys.stderr)
    n_min = min(len(v) for rows in per_clip for r in rows.values() for v in r.values())
    skipped = f" (without {', '.join(skip)})" if skip else ""
    labelled = "; read as a zero pose with every bone along +X labelled as their rest pose" if plan.mislabel else ""
    lines = [f"{len(clips)} clips{skipped}{labelled}, each looped for {plan.minutes:g} min; {plan.body} body "
             f"({len(layout.segments)} sensors); {chain.describe()} (each clip its own sensors); fastSW TH 9e-4, "
             "max_len 25, live bound 5. Joint angle error (deg), mean of the clips, per minute:", ""]
    for group, mask in groups(layout, plan.kind).items():
        members = [j for j, m in zip(layout.joints, mask) if m]
        title = f"{group} joints" if plan.kind is None else group
        lines += [f"**{title}** ({', '.join(members)})", "",
                  "| case | " + " | ".join(str(m + 1) for m in range(n_min)) + " |", "|---|" + "---:|" * n_min]
        for name in CASES:
            if name in per_clip[0]:
                mean = np.mean([rows[name][group][:n_min] for rows in per_clip], axis=0)
                lines.append(f"| {name} | " + " | ".join(f"{v:.2f}" for v in mean) + " |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", help="motion file (e.g. ../shared/data/cmu_10seg_50hz.npz)")
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--body", choices=tuple(BODIES), default="full", help="which sensors (default all 10)")
    parser.add_argument("--chain", choices=("raw", "simulated"), default="raw",
                        help="raw: a part's readings through VQF 6D; simulated: drifting headings (default raw)")
    parser.add_argument("--imu-model", default="icm42688p", choices=sorted(imu.MODELS))
    parser.add_argument("--bias-dps", type=float, default=DriftModel.bias_dps,
                        help="simulated: vertical gyro bias, uniform +-, deg/s (default %(default)s)")
    parser.add_argument("--bad-day", action="store_true", help="the gyro offset (simulated: bias and wander) doubled")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--verbose", action="store_true", help="also each clip's rows (to stderr)")
    parser.add_argument("--skip", nargs="*", default=[], metavar="CLIP", help="clips to leave out, by name")
    parser.add_argument("--sessions", choices=("both", "loop"), default="both",
                        help="loop: the motion alone, without the holds session (default both)")
    parser.add_argument("--kind", choices=KINDS, default=None,
                        help="the error of one joint kind (left and right together; default: per joint class)")
    parser.add_argument("--mislabel", action="store_true",
                        help="each clip read as a BVH file whose zero pose has every bone along +X, labelled as its "
                             "rest pose: the error the correction must notice and not follow")
    parser.add_argument("--never-stop", action="store_true",
                        help="the correction goes on however contradicted its joints (what stopping spares)")
    args = parser.parse_args(argv)
    chain = Chain(args.chain, args.imu_model, args.bad_day, DriftModel(bias_dps=args.bias_dps, seed=args.seed),
                  args.seed)
    plan = Plan(args.minutes, args.body, ("loop",) if args.sessions == "loop" else ("loop", "holds"), args.kind,
                args.mislabel)
    settings = Settings(contradiction_share=1.0) if args.never_stop else Settings()  # a share never beyond 1
    print(run(args.path, plan, chain, settings, args.verbose, tuple(args.skip)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
