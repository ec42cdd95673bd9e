"""``limbstream eval``: evaluate segmentation algorithms on motion files (table, JSON rows, Fig. 4 plot;
with ``--live-bound``, fastSW's live rule and the frontier plot).

The computation is :mod:`limbstream.evaluation`; this module parses, prints and draws.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from limbstream import kernel
from limbstream import calibration
from limbstream.calibration import CalibrationError
from limbstream.evaluation import (ALGORITHMS, CALIBRATIONS, MAX_LEN, PREDICTORS, THRESHOLDS, evaluate, format_table, frontier,
                                   streams_of, write_json)
from limbstream.joints import format_errors
from limbstream.sources import Motion, MotionFileError, load


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
    plain = sorted((r for r in rows if r["live_bound"] == 0 and r["icr"] > 0), key=lambda r: r["icr"])
    if plain:
        left.plot([r["icr"] for r in plain], [r["aad"] for r in plain], "k-", label="plain fastSW (no live bound)")
        right.plot([r["icr"] for r in plain], [r["live_p99"] for r in plain], "k-", label="plain fastSW")
    for n, bound in enumerate(b for b in bounds if b > 0):
        icr, aad = frontier(rows, bound)
        left.plot(icr, aad, ".-", ms=3, color=f"C{n}", label=f"live error <= {bound:g} deg")
        own = sorted((r for r in rows if r["live_bound"] == bound and r["icr"] > 0), key=lambda r: r["icr"])
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


def _bound_list(text: str) -> list[float]:
    values = []
    for part in (p for p in text.replace(" ", ",").split(",") if p):
        try:
            values.append(kernel.LIVE_BOUND.check(float(part)))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"live bound must be degrees in 0..180 (0: the plain rules), got {part!r}") from None
    if not values:
        raise argparse.ArgumentTypeError("no live bound given")
    return values


def _algorithm_list(text: str) -> list[str]:
    names = [n for n in text.replace(" ", ",").split(",") if n]
    for n in names:
        if n not in kernel.ALGORITHMS:
            raise argparse.ArgumentTypeError(
                f"unknown algorithm {n!r} (choose from {', '.join(kernel.ALGORITHMS)})"
            )
    return names


def _threshold(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"threshold must be finite and >= 0, got {text}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``limbstream eval``."""
    parser.add_argument(
        "paths",
        nargs="+",
        metavar="PATH",
        help="motion files (.npz, .bvh, x-IMU3 .csv, Xsens .txt) or folders of them",
    )
    parser.add_argument(
        "--algorithms",
        nargs="+",
        type=_algorithm_list,
        default=None,
        metavar="NAME",
        help=f"algorithms to compare (default: {' '.join(ALGORITHMS)}; fastsw with --live-bound)",
    )
    parser.add_argument(
        "--live-bound",
        type=_bound_list,
        default=None,
        metavar="DEG[,DEG...]",
        help="run fastSW's live rule at these bounds, degrees (0: the plain rules); rows gain the live "
        "error; --plot draws the live frontier",
    )
    parser.add_argument(
        "--predictor",
        choices=PREDICTORS,
        default="rate",
        help="the points' rates for the live error: rate (the live rule's, through the neighbouring "
        "sample; the C kernel), slope (the closed segment's) or hold (default rate)",
    )
    parser.add_argument(
        "--thresholds",
        nargs="+",
        type=_threshold,
        default=None,
        metavar="TH",
        help="evaluate these thresholds instead of the paper's sweep (0 and 205 values 1e-6..1e3)",
    )
    parser.add_argument(
        "--max-len",
        type=_positive_int,
        default=MAX_LEN,
        help=f"largest segment length, samples (default {MAX_LEN})",
    )
    calibration.add_arguments(parser)
    parser.add_argument("--calibration", choices=[",".join(p) or "none" for p in CALIBRATIONS],
                         default="rest,mounting",
                         help="with a sensor model: the calibration before body_aad (default rest,mounting)")
    parser.add_argument("--joint-angles", action="store_true",
                        help="with --thresholds: each row's joint angle errors (mean, p99, bias per angle) against "
                             "the true angles (docs/evaluation.md, 'Joint angles')")
    parser.add_argument(
        "--json", type=Path, metavar="OUT", help="write every (algorithm, threshold) row here"
    )
    parser.add_argument(
        "--plot", type=Path, metavar="OUT.png", help="draw the two Fig. 4 panels into this PNG"
    )


def _fail(message: str) -> int:
    print(f"limbstream eval: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    """``limbstream eval``: print the ICR table, optionally write JSON rows and the plot."""
    if args.algorithms is None:
        algorithms = ["fastsw"] if args.live_bound is not None else list(ALGORITHMS)
    else:
        algorithms = list(dict.fromkeys(n for group in args.algorithms for n in group))
    bounds = list(dict.fromkeys(args.live_bound)) if args.live_bound is not None else [0.0]
    if any(b > 0 for b in bounds) and algorithms != ["fastsw"]:
        return _fail(f"--live-bound is fastSW's rule: use it with --algorithms fastsw, not {' '.join(algorithms)}")
    if "sw" in algorithms and args.max_len > 1000:
        return _fail(f"--max-len for algorithm 'sw' is at most 1000, got {args.max_len}")
    for out, what in ((args.json, "--json"), (args.plot, "--plot")):
        if out is not None and not out.parent.resolve().is_dir():
            return _fail(f"{what} {out}: folder {out.parent} does not exist")
    if args.joint_angles and args.thresholds is None:
        return _fail("--joint-angles prints a table per row: give the rows' --thresholds")
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        return _fail(f"--plot {args.plot}: must end in .png")
    motions: list[Motion] = []
    for path in args.paths:
        try:
            motions.extend(load(path))
        except MotionFileError as exc:
            return _fail(str(exc))
        except OSError as exc:
            return _fail(f"{path}: {exc}")
    try:
        sensors = calibration.from_args(args)
    except ValueError as exc:
        return _fail(str(exc))
    poses = () if args.calibration == "none" else tuple(args.calibration.split(","))
    streams = streams_of(motions, sensors)
    if not streams:
        return _fail(f"no motion streams in {' '.join(map(str, args.paths))}")
    thresholds = THRESHOLDS if args.thresholds is None else np.asarray(args.thresholds, np.float64)
    n_samples = sum(len(s.t) for s in streams)

    start = time.perf_counter()
    try:
        rows = evaluate(streams, algorithms, thresholds, args.max_len, args.live_bound and bounds, args.predictor,
                        poses, args.joint_angles)
    except CalibrationError as exc:
        return _fail(f"calibration refused: {exc}")
    elapsed = time.perf_counter() - start

    print(
        f"{len(motions)} motions, {len(streams)} streams, {n_samples} samples; "
        f"{len(algorithms)} algorithms x {len(bounds)} live bounds x {len(thresholds)} thresholds, "
        f"max_len {args.max_len}, predictor {args.predictor}: {elapsed:.1f} s"
        + (f"; sensors: mounting <= {sensors.mounting_deg:g} deg, heading +-{sensors.heading_deg:g} deg, "
           f"yaw drift +-{sensors.yaw_drift_dps:g} deg/s, seed {sensors.seed}, "
           f"calibration {args.calibration}" if sensors.on else "")
    )
    if args.thresholds is not None:  # explicit thresholds: show every row
        print(
            f"{'algorithm':<9} {'bound':>5} {'TH':>9} {'ICR':>7} {'AAD':>7} {'std':>7} {'p99':>7} {'max':>7} "
            f"{'pt_AAD':>8} {'pt_max':>8} {'live':>7} {'live99':>7} {'livemax':>7} {'body':>7}"
        )
        for r in rows:
            print(
                f"{r['algorithm']:<9} {r['live_bound']:>5g} {r['threshold']:>9.2e} {r['icr']:>7.4f} {r['aad']:>7.3f} "
                f"{r['std']:>7.3f} {r['p99']:>7.3f} {r['max']:>7.3f} {r['point_aad']:>8.3f} {r['point_max']:>8.3f} "
                f"{r['live_aad']:>7.3f} {r['live_p99']:>7.3f} {r['live_max']:>7.3f} {r['body_aad']:>7.3f}"
            )
    else:
        print(format_table(rows, algorithms, live_bounds=bounds))
    for r in rows if args.joint_angles else ():
        against = "the calibrated reconstruction" if sensors.on else "the reconstruction"
        print("\n" + format_errors(r["joints"], f"joint angles of {against} against the truth's (deg): "
                                                f"{r['algorithm']}, TH {r['threshold']:.2e}, bound {r['live_bound']:g}"))
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
    return 0
