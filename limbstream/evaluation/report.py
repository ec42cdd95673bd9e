"""Results of a sweep as a table, a Pareto frontier and JSON."""
from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from limbstream.evaluation.sweep import EXTRAS, ICR_TARGETS, KEYS, at_icr
from limbstream.evaluation.table import Column, render
from limbstream.joints import GIMBAL_DEG

EVAL_COLUMNS: tuple[Column, ...] = (
    Column("algorithm", "algorithm", "", "segmentation algorithm (fastsw, sw: the paper's; cplr, swing: baselines)",
           ""),
    Column("live_bound_deg", "bound", "deg", "fastSW's live rule: no sample's live error beyond it (0: off)", "g"),
    Column("icr", "ICR", "", "inverse compression ratio: segment points sent / samples taken", ".4f"),
    Column("threshold", "TH", "", "the algorithm's threshold (SSR bound for fastsw, sw, cplr; largest deviation "
           "per quaternion component for swing); at a target ICR: interpolated", ".2e"),
    Column("aad", "AAD", "deg", "mean angular deviation of the SLERP reconstruction from every sample"),
    Column("std", "std", "deg", "standard deviation of that deviation"),
    Column("p99", "p99", "deg", "its 99th percentile"),
    Column("max", "max", "deg", "its largest value"),
    Column("point_aad", "pt AAD", "deg", "mean deviation of the segment points from the samples at their times "
           "(0: the points are samples)"),
    Column("point_max", "pt max", "deg", "largest deviation of the segment points"),
    Column("live_aad", "live", "deg", "mean live error: the receiver's view at each sample's time (newest point "
           "extrapolated) against the sample; with --live-bound"),
    Column("live_p99", "live p99", "deg", "99th percentile of the live error"),
    Column("live_max", "live max", "deg", "largest live error"),
    Column("body_aad", "body", "deg", "mean error of the calibrated reconstruction against the true segments; with "
           "a sensor model (--mounting-deg, --heading-deg, --yaw-drift-dps) or raw sensors (--imu raw)"),
    Column("fusion_total", "fus tot", "deg", "fusion error of raw sensors with a reference (BROAD's truth, emulated "
           "sensors' own): RMS angle of the devices' samples (their filter's orientation, before calibration) "
           "against it in the earth frame, over the movement phases", ".2f"),
    Column("fusion_heading", "fus head", "deg", "its part about the vertical (6D: heading aligned once at the start)",
           ".2f"),
    Column("fusion_incl", "fus incl", "deg", "its inclination part", ".2f"),
    Column("fusion_drift", "fus drift", "deg/min", "6D: drift of that heading error (median over the streams)", "+.2f"),
    Column("chain_total", "chain tot", "deg", "chain error: the same of the reconstruction (segment points SLERPed)",
           ".2f"),
    Column("chain_heading", "chain head", "deg", "its part about the vertical", ".2f"),
    Column("chain_incl", "chain incl", "deg", "its inclination part", ".2f"),
    Column("chain_drift", "chain drift", "deg/min", "6D: its heading drift", "+.2f"),
    Column("joint_aad", "joint", "deg", "mean joint error: the angle between the estimated and the true relative "
           "orientation of each pair of adjacent segments (knees, elbows, hips, shoulders, neck), whichever way the "
           "body faces; with a sensor model the calibrated reconstruction's (heading-corrected with "
           "--heading-correction joints)"),
    Column("pos_cm", "pos", "cm", "mean per-joint position error: the distance between each estimated and true "
           "joint, the pelvis at the origin in both (hips, knees, ankles, shoulders, elbows, wrists, neck base, head; "
           "docs/evaluation.md, 'Joint positions')", ".2f"),
)
"""The columns of every ``limbstream eval`` table, in order (a new measure: one more here)."""

_ROW = {c.key: c for c in EVAL_COLUMNS}
JOINT_COLUMNS: tuple[Column, ...] = (
    _ROW["algorithm"], _ROW["live_bound_deg"], _ROW["threshold"],
    Column("angle", "angle", "", "joint angle, named as the Rajagopal model's coordinate (docs/evaluation.md, "
           "'Joint angles')", ""),
    Column("mean", "mean", "deg", "mean absolute error of the reconstruction's angle (with a sensor model: the "
           "calibrated reconstruction's) against the true angle, the source's own segments'", ".2f"),
    Column("p99", "p99", "deg", "99th percentile of that absolute error", ".2f"),
    Column("bias", "bias", "deg", "mean signed error, estimate - truth", "+.2f"),
    Column("n", "frames", "", "frames scored (the joint's segments present in both, not near gimbal lock)", "d"),
    Column("gimbal", "near lock", "", f"frames left out within {GIMBAL_DEG:g} deg of gimbal lock (either side's "
           "flag GIMBAL)", "d"),
)
"""The columns of ``limbstream eval --joint-angles``: one line per (row, joint angle)."""


JOINT_KIND_COLUMNS: tuple[Column, ...] = (
    _ROW["algorithm"], _ROW["live_bound_deg"], _ROW["threshold"],
    Column("joint", "joint", "", "the joints of one kind, left and right together (the neck: hip to neck, or chest to head "
           "where there is a chest; lumbar: hip to chest)", ""),
    Column("mean", "mean", "deg", "mean joint error: the angle between the estimated and the true relative "
           "orientation of the joint's two segments", ".2f"),
    Column("p99", "p99", "deg", "its 99th percentile", ".2f"),
    Column("first", "minute 1", "deg", "its mean over each motion's first minute", ".2f"),
    Column("last", "last minute", "deg", "its mean over each motion's last minute (with --loop-minutes, how far a "
           "drifting heading took it)", ".2f"),
    Column("n", "samples", "", "joint samples scored (both segments present in the estimate and the truth)", "d"),
)
"""The columns of the per-joint table of ``limbstream eval``: one line per (row, joint kind)."""


POSITION_COLUMNS: tuple[Column, ...] = (
    _ROW["algorithm"], _ROW["live_bound_deg"], _ROW["threshold"],
    Column("joint", "joint", "", "the joints of one kind, left and right together (neck base: the top of the "
           "spine; head: paper10's end of the neck segment; full: spine, the waist; head_top, toes, "
           "fingertips: the tips of the head, feet and hands)", ""),
    Column("mean", "mean", "cm", "mean distance between the estimated and the true joint, the pelvis at the origin",
           ".2f"),
    Column("p99", "p99", "cm", "its 99th percentile", ".2f"),
    Column("n", "samples", "", "joint samples scored (the segments placing the joint present in both)", "d"),
)
"""The columns of the per-joint position table of ``limbstream eval``: one line per (row, joint kind)."""

TRANSLATION_COLUMNS: tuple[Column, ...] = (
    _ROW["algorithm"], _ROW["live_bound_deg"], _ROW["threshold"],
    Column("motion", "motion", "", "the motion (a file with a root path that travels 0.5 m or more)", ""),
    Column("path_m", "path", "m", "the true root's horizontal path (over 0.1 s steps)", ".2f"),
    Column("end_cm", "end", "cm", "horizontal root error at the end, the start aligned once (heading and offset, "
           "first 0.5 s)", ".1f"),
    Column("end_pct", "end", "% path", "the same as a share of the path", ".1f"),
    Column("height_cm", "height", "cm", "mean root height error, each above its own floor (the truth's: its feet's "
           "lowest point over the motion)", ".1f"),
    Column("height_feet_cm", "height/feet", "cm", "the same, the truth's floor at its lowest foot point frame by frame "
           "(the root's height over its feet)", ".1f"),
    Column("below_cm", "below", "cm", "deepest an estimated foot point went below the floor", ".1f"),
    Column("skate_cmps", "skate", "cm/s", "estimated feet's horizontal speed while the true feet are planted", ".1f"),
    Column("true_skate_cmps", "true skate", "cm/s", "the true feet's own over the same frames", ".1f"),
)
"""The columns of ``limbstream eval``'s root translation table: one line per (row, motion)."""


def format_table(
    rows: Sequence[dict], algorithms: Sequence[str], targets: Sequence[float] | None = ICR_TARGETS,
    live_bound_deg: Sequence[float] = (0.0,),
) -> str:
    """The comparison table with its legend: the measures interpolated at the ``targets`` ICRs
    per algorithm and live bound, or (``targets`` None) every row as swept."""
    if targets is None:
        shown = list(rows)
    else:
        shown = [r | {"live_bound_deg": bound} for a in algorithms for bound in live_bound_deg
                 for r in at_icr(rows, a, targets, live_bound_deg=bound)]
    return render(EVAL_COLUMNS, shown)


def format_joint_errors(rows: Sequence[dict]) -> str:
    """The joint angle errors of the rows that have them (``joints``: per angle the figures of
    :func:`limbstream.joints.angle_errors`), one line per (row, angle), with the legend; an angle
    no frame scored shows :data:`~limbstream.evaluation.table.DASH`."""
    lines = [r | {"angle": angle} | figures for r in rows for angle, figures in r.get("joints", {}).items()]
    return render(JOINT_COLUMNS, lines)


def format_joint_kinds(rows: Sequence[dict]) -> str:
    """The joint error of the rows that have it per joint kind (``joint_kinds``:
    :func:`limbstream.evaluation.body.joint_figures`), one line per (row, kind), with the legend."""
    lines = [r | {"joint": f"{name}s" if name not in ("neck", "lumbar") else name} | figures
             for r in rows for name, figures in r.get("joint_kinds", {}).items()]
    return render(JOINT_KIND_COLUMNS, lines)


def format_positions(rows: Sequence[dict]) -> str:
    """The joint position error of the rows that have it per joint kind (``positions``:
    :func:`limbstream.evaluation.positions.position_figures`), one line per (row, kind), with the
    legend."""
    lines = [r | {"joint": f"{name}s" if name not in ("neck_base", "head", "spine", "head_top") else name} | figures
             for r in rows for name, figures in r.get("positions", {}).items()]
    return render(POSITION_COLUMNS, lines)


def format_translation(rows: Sequence[dict]) -> str:
    """The root translation figures of the rows' motions that have a root path (``translation``:
    :func:`limbstream.evaluation.translation.translation_of`), one line per (row, motion), with
    the legend."""
    lines = [r | figures for r in rows for figures in r.get("translation", [])]
    return render(TRANSLATION_COLUMNS, lines)


def frontier(rows: Sequence[dict], bound: float | None, tolerance: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """The best exact AAD at each ICR among rows whose live error stays within ``bound`` degrees
    at every sample (``live_max <= bound + tolerance``; None: every row): the rows not beaten by
    another with lower or equal ICR and lower AAD.

    Returns
    -------
    icr, aad : (F,) float64, ICR increasing, AAD decreasing.
    """
    ok = [r for r in rows if np.isfinite(r["icr"]) and np.isfinite(r["aad"])
          and (bound is None or r["live_max"] <= bound + tolerance)]
    ok.sort(key=lambda r: (r["icr"], r["aad"]))
    icr: list[float] = []
    aad: list[float] = []
    for r in ok:
        if not aad or r["aad"] < aad[-1]:
            icr.append(r["icr"])
            aad.append(r["aad"])
    return np.array(icr), np.array(aad)


def _finite(value):
    """``value`` with every non-finite float (also within dicts) as None (JSON null)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    return None if isinstance(value, float) and not math.isfinite(value) else value


def format_heading_stopped(rows: Sequence[dict]) -> list[str]:
    """One line per motion of each row whose heading correction stopped, its joints contradicting
    their constraints (``heading_stopped``: its rest pose is not what it says)."""
    lines = []
    for r in rows:
        for s in r.get("heading_stopped", ()):
            joints = ", ".join(f"{j} {v:.2f}" for j, v in s["joints"].items())
            lines.append(f"heading correction stopped for {s['motion']} at {s['at_s']:.0f} s "
                         f"({r['algorithm']} TH {r['threshold']:g}): its joints contradict their constraints ({joints}: "
                         "share of the last minute); its rest pose is not what it says")
    return lines


def write_json(rows: Sequence[dict], path: str | Path) -> None:
    """All rows as a JSON list of objects with the :data:`KEYS` (and the ``EXTRAS``, ``joint_kinds``,
    ``joints``, ``positions``, where scored); NaN becomes null."""
    clean = [_finite({k: r[k] for k in KEYS} | {k: r[k] for k in EXTRAS if k in r}) for r in rows]
    Path(path).write_text(json.dumps(clean, indent=1) + "\n")
