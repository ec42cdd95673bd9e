"""``limbstream eval``: evaluate segmentation algorithms on motion files (table with its legend, JSON
rows, Fig. 4 plot; with ``--live-bound``, fastSW's live rule and the frontier plot).

The computation is :mod:`limbstream.evaluation`; this module parses, prints and draws.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from limbstream import calibration, kernel
from limbstream.wire import DEVICE_RATE_HZ as DEVICE_RATE
from limbstream.calibration import CalibrationError
from limbstream.cli import flags
from limbstream.evaluation import (ALGORITHMS, CALIBRATIONS, ICR_TARGETS, MAX_LEN, PREDICTORS, THRESHOLDS, evaluate,
                                   format_heading_stopped, format_joint_errors, format_joint_kinds, format_positions, format_table,
                                   format_translation, frontier, streams_of, write_json)
from limbstream.evaluation.body import layout_of
from limbstream.evaluation.table import Progress
from limbstream.kernel import fusion
from limbstream.sources import Motion, MotionFileError, load
from limbstream.sources.bvh_loop import looped_motion, walks_on
from limbstream.sources.raw import RawRecording, load_raw, raw_files


def plot(
    rows: Sequence[dict], algorithms: Sequence[str], path: str | Path, title: str = ""
) -> None:
    """The two panels of the paper's Fig. 4 as a PNG: reconstruction and segment-point deviation vs ICR."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for n, a in enumerate(algorithms):
        own = sorted(
            (r for r in rows if r["algorithm"] == a and r["icr"] > 0), key=lambda r: r["icr"]
        )
        icr = np.array([r["icr"] for r in own])
        style = {"ls": "--" if a == "sw" else "-", "color": f"C{n}"}
        left.plot(icr, [r["aad"] for r in own], label=a, **style)
        right.plot(icr, [r["point_aad"] for r in own], label=f"{a} mean", **style)
        right.plot(icr, [r["point_max"] for r in own], ls=":", color=f"C{n}", label=f"{a} max")
    left.set(
        xscale="log",
        xlabel="ICR (segment points / samples)",
        ylabel="AAD (deg)",
        title="SLERP reconstruction vs. original samples (AAD)",
    )
    right.set(
        xscale="log",
        yscale="symlog",
        xlabel="ICR (segment points / samples)",
        ylabel="angular deviation (deg)",
        title="segment points vs. original samples",
    )
    right.set_yscale("symlog", linthresh=1e-3)
    right.set_ylim(bottom=0)
    for ax in (left, right):
        ax.set_xlim(3e-3, 1.0)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_frontier(rows: Sequence[dict], bounds: Sequence[float], path: str | Path, title: str = "") -> None:
    """The live frontier as a PNG: for each bound, the best exact AAD at each ICR among the rows
    whose live error stays within it at every sample, against plain fastSW's AAD curve (left);
    the live error p99 of the same rows (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    plain = sorted((r for r in rows if r["live_bound_deg"] == 0 and r["icr"] > 0), key=lambda r: r["icr"])
    if plain:
        left.plot([r["icr"] for r in plain], [r["aad"] for r in plain], "k-", label="plain fastSW (no live bound)")
        right.plot([r["icr"] for r in plain], [r["live_p99"] for r in plain], "k-", label="plain fastSW")
    for n, bound in enumerate(b for b in bounds if b > 0):
        icr, aad = frontier(rows, bound)
        left.plot(icr, aad, ".-", ms=3, color=f"C{n}", label=f"live error <= {bound:g} deg")
        own = sorted((r for r in rows if r["live_bound_deg"] == bound and r["icr"] > 0), key=lambda r: r["icr"])
        right.plot([r["icr"] for r in own], [r["live_p99"] for r in own], ".-", ms=3, color=f"C{n}",
                   label=f"live rule {bound:g} deg")
        right.axhline(bound, color=f"C{n}", ls=":", lw=0.8)
    left.set(xscale="log", yscale="log", xlabel="ICR (segment points / samples)", ylabel="exact AAD (deg)",
             title="best exact AAD with the live error bounded", ylim=(0.1, 5.0))
    right.set(xscale="log", yscale="log", xlabel="ICR (segment points / samples)", ylabel="live error p99 (deg)",
              title="live error, 99th percentile", ylim=(0.5, 100.0))
    for ax in (left, right):
        ax.set_xlim(0.08, 0.6)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _live_bound(text: str) -> float:
    try:
        return kernel.LIVE_BOUND.check(float(text))
    except ValueError:
        raise ValueError(f"live bound must be degrees in 0..180 (0: the plain rules), got {text!r}") from None


def _algorithm(name: str) -> str:
    if name not in kernel.ALGORITHMS:
        raise ValueError(f"unknown algorithm {name!r} (choose from {', '.join(kernel.ALGORITHMS)})")
    return name


def _threshold(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"threshold must be finite and >= 0, got {text}")
    return value


def _calibration(text: str) -> tuple[str, ...]:
    poses = () if text.strip() == "none" else tuple(p.strip() for p in text.split(",") if p.strip())
    if poses not in CALIBRATIONS:
        raise argparse.ArgumentTypeError(f"say none, rest or rest,mounting; got {text!r}")
    return poses


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``limbstream eval``; every list flag takes ``A,B,C``."""
    parser.add_argument("paths", nargs="+", metavar="PATH",
                        help="motion files (.npz, .bvh, x-IMU3 .csv, Xsens .txt), raw sensor recordings (BROAD "
                             "trials, qmt-style full-body .mat files: fused as the device fuses them) or folders of "
                             "them")
    parser.add_argument("--algorithms", type=flags.comma_list(_algorithm), default=None, metavar="NAME[,NAME...]",
                        help=f"algorithms to compare (default: {','.join(ALGORITHMS)}; fastsw with --live-bound)")
    parser.add_argument("--live-bound", type=flags.comma_list(_live_bound), default=None, metavar="DEG[,DEG...]",
                        help="run fastSW's live rule at these bounds, degrees (0: the plain rules); rows gain the "
                             "live error; --plot draws the live frontier")
    parser.add_argument("--predictor", choices=PREDICTORS, default="rate",
                        help="the points' rates for the live error: rate (the live rule's, through the "
                             "neighbouring sample; the C kernel), slope (the closed segment's) or hold (default rate)")
    parser.add_argument("--thresholds", type=flags.comma_list(_threshold), default=None, metavar="TH[,TH...]",
                        help="evaluate these thresholds, one row each, instead of the paper's sweep (0 and 205 "
                             "values 1e-6..1e3) shown at the ICRs 0.05, 0.10, 0.25, 0.50")
    parser.add_argument("--max-len", type=_positive_int, default=MAX_LEN,
                        help=f"largest segment length, samples (default {MAX_LEN})")
    flags.add_names(parser)
    flags.add_source_layout(parser, "default: the layout each source carries (a BVH file: paper10; an IMU recording: the "
                             "smallest built-in holding its segments); a BVH file maps a joint to each of its "
                             "segments, other sources leave out the segments it does not have")
    flags.add_sensor_model(parser)
    parser.add_argument("--calibration", type=_calibration, default=None, metavar="none|rest|rest,mounting",
                        help="with a sensor model: the calibration before the body error (default rest,mounting)")
    parser.add_argument("--joint-angles", action="store_true",
                        help="with --thresholds TH[,TH...]: each row's joint angle errors (mean, p99, bias per "
                             "angle) against the true angles, a second table (docs/evaluation.md, 'Joint angles'); "
                             "motion files only (a recording of real sensors has no true angles)")
    parser.add_argument("--mag", action="store_true",
                        help="raw recordings: fuse their magnetometer too (9D; default 6D, the heading aligned once "
                             "at the start)")
    parser.add_argument("--loop-minutes", type=float, default=None, metavar="M",
                        help="motion files: play each clip looped for M minutes of motion, its seams joined smoothly "
                             "(with a sensor model the calibration script plays once, at the start)")
    flags.add_heading_correction(parser, default="off")
    parser.add_argument("--dump", type=Path, metavar="DIR",
                        help="write each motion's compared orientations and joint positions into DIR/<motion>.npz: "
                             "t, estimated and truth (frames, S, 4), segment_names, source_t, positions and "
                             "true_positions (frames, J, 3), position_joints (docs/evaluation.md, 'Dumps'); one row")
    parser.add_argument("--json", type=Path, metavar="OUT", help="write every (algorithm, threshold) row here")
    parser.add_argument("--plot", type=Path, metavar="OUT.png", help="draw the two Fig. 4 panels into this PNG")


def _fail(message: str) -> int:
    return flags.fail("limbstream eval", message)


def _note(message: str) -> None:
    print(f"limbstream eval: note: {message}", file=sys.stderr)


def _check(args: argparse.Namespace, algorithms: list[str], bounds: list[float]) -> str | None:
    """The first problem of the flags, as a sentence (None: none)."""
    if any(b > 0 for b in bounds) and algorithms != ["fastsw"]:
        return f"--live-bound is fastSW's rule: use it with --algorithms fastsw, not {','.join(algorithms)}"
    if "sw" in algorithms and args.max_len > 1000:
        return f"--max-len for algorithm 'sw' is at most 1000, got {args.max_len}"
    for out, what in ((args.json, "--json"), (args.plot, "--plot")):
        if out is not None and not out.parent.resolve().is_dir():
            return f"{what} {out}: folder {out.parent} does not exist"
    if args.joint_angles and args.thresholds is None:
        return "--joint-angles scores explicit rows: give them with --thresholds TH[,TH...]"
    if args.heading_correction != "off" and args.thresholds is None:
        return "--heading-correction corrects explicit rows: give them with --thresholds TH[,TH...]"
    if args.dump is not None:
        rows = len(algorithms) * len(bounds) * len(args.thresholds or THRESHOLDS)
        if rows != 1:
            return (f"--dump writes one row's orientations: give one algorithm, live bound and threshold "
                    f"(--algorithms fastsw --thresholds TH), not {rows} rows")
        if not args.dump.is_dir():
            return f"--dump {args.dump}: not a folder"
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        return f"--plot {args.plot}: must end in .png"
    if args.loop_minutes is not None and not 0 < args.loop_minutes <= 600:
        return f"--loop-minutes must be in (0, 600], got {args.loop_minutes:g}"
    return None


def _inputs(args: argparse.Namespace) -> tuple[list[Motion], list[RawRecording]]:
    """The motion files and raw recordings of the paths (MotionFileError, OSError)."""
    motions: list[Motion] = []
    recordings: list[RawRecording] = []
    for path in args.paths:
        raw = raw_files(path)
        if raw:
            recordings.extend(load_raw(p, args.layout) for p in raw)
        else:
            motions.extend(load(path, args.names, layout=args.layout))
    return motions, recordings


def _streams(args: argparse.Namespace, sensors: calibration.SensorModel, motions: list[Motion],
             recordings: list[RawRecording]) -> list:
    """Every stream to evaluate (ValueError naming a flag that does not apply)."""
    from limbstream.evaluation import raw_streams

    if args.loop_minutes is not None:
        if recordings:
            raise ValueError("--loop-minutes loops motion clips, not raw recordings "
                             f"({', '.join(r.name for r in recordings)})")
        motions, turning = _looped(motions, args.loop_minutes, args.layout)
    model = flags.imu_model(args)
    streams = (raw_streams.emulated_streams(motions, sensors, model, args.imu_rate, args.vqf_precision, args.layout)
               if model is not None
               else streams_of(motions, sensors, args.layout))
    if args.loop_minutes is not None:  # a clip looped about a fixed root: its times are no longer its file's
        streams = [dataclasses.replace(s, source=None, source_offset_s=math.nan)
                   if s.name.rsplit("/", 1)[0] in turning else s for s in streams]
    for rec in recordings:
        streams += raw_streams.recording_streams(rec, args.mag, vqf_precision=args.vqf_precision)
    return streams


def _looped(motions: list[Motion], minutes: float, layout) -> tuple[list[Motion], set[str]]:
    """Each motion looped for ``minutes``: the BVH clips that :func:`walks_on` on their own cycle,
    the others about a fixed root (:func:`raw_streams.looped`); and the names of the latter."""
    from limbstream.evaluation import raw_streams

    out, turning = [], set()
    for m in motions:
        if walks_on(m):
            looped, loop = looped_motion(m, minutes * 60.0, layout or "paper10")
            _note(f"{looped.name}: the file's frames {loop.i}..{loop.j} ({(loop.j - loop.i) * loop.clip.frame_time:.2f} s) looped, its "
                  f"root walking on; the pose steps by {100 * loop.mismatch_m:.1f} cm (mean joint) at each seam")
        else:
            [looped] = raw_streams.looped([m], minutes)
            turning.add(looped.name)
        out.append(looped)
    return out, turning


def _notes(args: argparse.Namespace, sensors: calibration.SensorModel, motions: list[Motion], n_samples: int) -> None:
    """What a sensor model adds, or a --calibration with nothing to act on."""
    if args.imu == "raw":
        _note(f"raw sensors: every motion begins with the calibration script (rest {calibration.REST_S:g} s, mounting "
              f"{calibration.MOUNTING_S:g} s); each device compresses its filter's orientation at its instants "
              f"({DEVICE_RATE:g} Hz): {n_samples:,} samples, the script's included")
    elif sensors.on:
        plain = sum(len(m.t) * len(m.segments) for m in motions)
        _note(f"the sensor model begins every motion with the calibration script (rest {calibration.REST_S:g} s, "
              f"mounting {calibration.MOUNTING_S:g} s, with the moves between): {n_samples:,} samples instead of "
              f"{plain:,}; ICR and AAD count the script's samples too")
    elif args.heading_correction != "off":
        _note(f"--heading-correction {args.heading_correction} has nothing to act on without a sensor model "
              "(--mounting-deg, --heading-deg, --yaw-drift-dps): the reconstruction is not calibrated")
    elif args.calibration is not None:
        _note(f"--calibration {','.join(args.calibration) or 'none'} has nothing to act on without a sensor model "
              "(--mounting-deg, --heading-deg, --yaw-drift-dps): the body column stays empty")


def _raw_notes(args: argparse.Namespace, recordings: list[RawRecording]) -> None:
    """What the rows of raw recordings hold."""
    if not recordings:
        return
    mode = "9D" if args.mag else "6D"
    _note(f"raw recordings are fused as the device fuses them (VQF {mode}, rest threshold {fusion.REST_TH_GYR_DPS:g} "
          f"deg/s) and compressed at the device's instants ({DEVICE_RATE:g} Hz); ICR and AAD count those samples")
    blind = [r.name for r in recordings if r.truth is None]
    if blind:
        _note(f"{', '.join(blind)}: no reference orientation: no fusion or chain error for its streams (ICR and AAD "
              "only)")


def _position_sources(motions: list[Motion], looped: bool, layout=None) -> str:
    """Where the true joint positions of ``motions`` come from, and the bodies (on ``layout``,
    None: each motion's own), as a sentence."""
    own = [m for m in motions if m.positions is not None and (not looped or walks_on(m))]
    parts = []
    if own:
        units = sorted({f"{m.positions.unit_m:.6g}" for m in own if m.positions is not None})
        parts.append(f"{', '.join(m.name for m in own)}: the file's own joints (forward kinematics of its skeleton), "
                     f"the estimate on the layout's bones measured on its OFFSETs ({' / '.join(units)} m per unit)")
    if len(own) < len(motions):
        who = "the other motions: no positions of their own" if own else "every motion: no positions of its own"
        why = " (looped)" if looped and any(m.positions for m in motions) else ""
        layouts = " / ".join(sorted({layout_of(m, layout).name for m in motions if all(m is not o for o in own)}))
        parts.append(f"{who}{why}: the true orientations' joints on the same body, {layouts}'s default (an adult of "
                     "about 1.75 m)")
    return "; ".join(parts)


def run(args: argparse.Namespace) -> int:
    """``limbstream eval``: print the table and its legend, optionally write JSON rows and the plot."""
    algorithms = (list(dict.fromkeys(args.algorithms)) if args.algorithms is not None
                  else ["fastsw"] if args.live_bound is not None else list(ALGORITHMS))
    bounds = list(dict.fromkeys(args.live_bound)) if args.live_bound is not None else [0.0]
    if (problem := _check(args, algorithms, bounds)) is not None:
        return _fail(problem)
    try:
        motions, recordings = _inputs(args)
    except MotionFileError as exc:
        return _fail(str(exc))
    except OSError as exc:
        return _fail(f"{exc}")
    if args.joint_angles and (real := [m.name for m in motions if m.orientations != "segments"]):
        return _fail(f"--joint-angles: {', '.join(real)}: a recording of real sensors has no true joint angles "
                     "(its orientations are not the segments' own); score motion files (.npz, .bvh)")
    try:
        sensors = flags.sensor_model(args)
    except ValueError as exc:
        return _fail(str(exc))
    poses = CALIBRATIONS[-1] if args.calibration is None else args.calibration
    try:
        streams = _streams(args, sensors, motions, recordings)
    except ValueError as exc:
        return _fail(str(exc))
    if not streams:
        return _fail(f"no motion streams in {' '.join(map(str, args.paths))}")
    thresholds = THRESHOLDS if args.thresholds is None else np.asarray(args.thresholds, np.float64)
    n_samples = sum(len(s.t) for s in streams)
    _notes(args, sensors, motions, n_samples)
    _raw_notes(args, recordings)

    progress = Progress("limbstream eval: rows", lambda text: print(text, end="", file=sys.stderr, flush=True),
                        sys.stderr.isatty())
    start = time.perf_counter()
    try:
        rows = evaluate(streams, algorithms, thresholds, args.max_len, args.live_bound and bounds, args.predictor,
                        poses, progress, args.joint_angles, args.heading_correction == "joints", args.dump)
    except CalibrationError as exc:
        return _fail(f"calibration refused: {exc}")
    finally:
        progress.close()
    elapsed = time.perf_counter() - start
    _report(args, motions, len(recordings), streams, n_samples, algorithms, bounds, thresholds, sensors, poses, rows,
            elapsed)
    return 0


def _full_scale_line(streams: list) -> str | None:
    """The streams whose part read at its full scale (clipped), worst first, or None if none did."""
    clipped = sorted((s for s in streams if s.full_scale > 0), key=lambda s: -s.full_scale)
    if not clipped:
        return None
    return ("clipped: " + ", ".join(f"{s.name} {100 * s.full_scale:.2f} %" for s in clipped)
            + " of their raw samples at the part's full scale (the motion goes beyond its range: their "
              "inclination can be off for seconds after; docs/evaluation.md, \"Raw sensors\")")


def _report(args: argparse.Namespace, motions: list[Motion], recordings: int, streams: list, n_samples: int,
            algorithms: list[str],
            bounds: list[float], thresholds: np.ndarray, sensors: calibration.SensorModel, poses: tuple[str, ...],
            rows: list[dict], elapsed: float) -> None:
    """The run's line, the table with its legend, the files written."""
    def count(n: int, what: str) -> str:
        return f"{n:,} {what}{'' if n == 1 else 's'}"
    raw = f"{count(recordings, 'raw recording')}, " if recordings else ""
    print(f"{count(len(motions), 'motion')}, {raw}{count(len(streams), 'stream')}, {count(n_samples, 'sample')}; "
          f"{count(len(algorithms), 'algorithm')} x {count(len(bounds), 'live bound')} x "
          f"{count(len(thresholds), 'threshold')}, max_len {args.max_len}, predictor {args.predictor}; "
          f"ran {elapsed:.1f} s")
    if args.imu == "raw":
        print(f"raw sensors: {args.imu_model} at {args.imu_rate:g} Hz, fused on each device (VQF 6D, rest threshold "
              f"{fusion.REST_TH_GYR_DPS:g} deg/s); mounting <= {sensors.mounting_deg:g} deg, filter heading "
              f"+-{sensors.heading_deg:g} deg, seed {sensors.seed}; calibration {','.join(poses) or 'none'}"
              + (f"; each clip looped for {args.loop_minutes:g} min" if args.loop_minutes else ""))
        if (line := _full_scale_line(streams)) is not None:
            print(line)
    elif sensors.on:
        print(f"sensors: mounting <= {sensors.mounting_deg:g} deg, heading +-{sensors.heading_deg:g} deg, yaw drift "
              f"+-{sensors.yaw_drift_dps:g} deg/s, seed {sensors.seed}; calibration {','.join(poses) or 'none'}; "
              f"heading correction {args.heading_correction}")
    explicit = args.thresholds is not None
    print("rows: each threshold given" if explicit else
          f"rows: the measures at ICR {', '.join(f'{c:.2f}' for c in ICR_TARGETS)}, interpolated over the paper's "
          "threshold sweep")
    print(format_table(rows, algorithms, None if explicit else ICR_TARGETS, live_bound_deg=bounds))
    if explicit:
        what = "calibrated reconstruction" if sensors.on else "reconstruction"
        held = ", its headings held by the joints" if sensors.on and args.heading_correction == "joints" else ""
        print(f"\njoint error per joint, of the {what}{held}, against the truth")
        print(format_joint_kinds(rows))
        for line in format_heading_stopped(rows):
            print(line)
        print(f"\njoint positions of the {what}{held}, the pelvis at the origin, against the truth's: "
              f"{_position_sources(motions, args.loop_minutes is not None, args.layout)}")
        print(format_positions(rows))
        if (note := flags.no_root_note({layout_of(m, args.layout) for m in motions})) is not None:
            print(f"\n{note}")
        if any(r.get("translation") for r in rows):
            print(f"\nroot translation from the {what}'s feet (docs/evaluation.md, \"Root translation\"), against the "
                  "file's root path")
            print(format_translation(rows))
    if args.joint_angles:
        print(f"\njoint angles of the {'calibrated ' if sensors.on else ''}reconstruction against the true angles")
        print(format_joint_errors(rows))
    if args.dump is not None:
        print(f"wrote {len(motions)} motion{'s' if len(motions) != 1 else ''}' orientations and joint positions to "
              f"{args.dump}/ (<motion>.npz)")
    if args.json is not None:
        write_json(rows, args.json)
        print(f"wrote {len(rows)} rows to {args.json}")
    if args.plot is not None:
        title = ", ".join(str(p) for p in args.paths)
        if args.live_bound is not None:
            plot_frontier(rows, bounds, args.plot, title=f"{title}, max_len {args.max_len}, predictor {args.predictor}")
        else:
            plot(rows, algorithms, args.plot, title=title)
        print(f"wrote {args.plot}")
