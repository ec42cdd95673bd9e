"""True joint angles of a motion source and the error figures of estimated ones (docs/evaluation.md,
"Joint angles")."""
from __future__ import annotations

import math

import numpy as np

from limbstream.body import Layout
from limbstream.joints.convention import ANGLES, GIMBAL, angle_names, joint_angles
from limbstream.sources import Motion

FIGURES: tuple[str, ...] = ("mean", "p99", "bias", "n", "gimbal")
"""Per angle: mean and 99th percentile of the absolute error (deg), mean signed error (bias,
estimate - truth, deg), frames scored, frames left out near gimbal lock."""


def in_layout(motion: Motion, layout: Layout | str = "paper10") -> tuple[np.ndarray, np.ndarray]:
    """A motion's orientations in a layout (a built-in's name, a layout file or a Layout; the
    motion's own: ``motion.layout``): (m, S, 4) float64 in the layout's segment order (NaN rows
    for the segments it lacks) and (S,) bool, the segments it has."""
    from limbstream.body import layout as named  # (a name or a file)
    names = (named(layout) if isinstance(layout, str) else layout).segment_names
    q = np.full((len(motion.t), len(names), 4), np.nan)
    present = np.zeros(len(names), bool)
    for k, name in enumerate(motion.segments):
        if name in names:
            q[:, names.index(name)] = motion.q[:, k]
            present[names.index(name)] = True
    return q, present


def true_angles(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """The joint angles of a motion source's own segment orientations (BVH clips, npz files, the
    generator: ``Motion.orientations`` ``segments``), those of its layout (``Motion.layout``:
    ``paper10``'s :data:`ANGLES` for a motion of its segments, ``wire.joint_angles(layout)``
    else): (m, A) degrees and (m, A) flags (:func:`joint_angles`). ValueError for a recording of
    real sensors (rest-calibrated, their facing unknown, or uncalibrated: not the segments' own
    orientations)."""
    if motion.orientations != "segments":
        raise ValueError(f"{motion.name}: real sensors' orientations ({motion.orientations}) have no true joint "
                         "angles")
    layout = motion.layout
    q, present = in_layout(motion, layout)
    return joint_angles(q, present, motion.rest_pose, layout=layout)


def angle_errors(estimate: np.ndarray, truth: np.ndarray, flags: np.ndarray | None = None,
                 names: tuple[str, ...] = ANGLES) -> dict[str, dict]:
    """Per-angle error figures (:data:`FIGURES`) of ``estimate`` against ``truth`` (each (m, A)
    degrees, in the order of ``names``, a layout's angles; NaN frames are not scored). Errors wrap
    to (-180, 180]. Frames that ``flags`` (m, A) (either side's, or-ed) marks GIMBAL are left out
    and counted."""
    estimate, truth = np.asarray(estimate, np.float64), np.asarray(truth, np.float64)
    error = np.remainder(estimate - truth + 180.0, 360.0) - 180.0
    gimbal = np.zeros(error.shape, bool) if flags is None else (np.asarray(flags) & GIMBAL) != 0
    return {name: _figures(error[:, k], gimbal[:, k]) for k, name in enumerate(names)}


def _figures(error: np.ndarray, gimbal: np.ndarray) -> dict:
    """:data:`FIGURES` of one angle's errors (m,) degrees, NaN unscored, ``gimbal`` (m,) left out."""
    e = error[np.isfinite(error) & ~gimbal]
    return {"mean": float(np.abs(e).mean()) if e.size else math.nan,
            "p99": float(np.percentile(np.abs(e), 99)) if e.size else math.nan,
            "bias": float(e.mean()) if e.size else math.nan,
            "n": int(e.size), "gimbal": int((gimbal & np.isfinite(error)).sum())}


def pooled_errors(motions, layout: Layout | str = "paper10") -> dict[str, dict]:
    """Per-angle error figures pooled over motions: each an (estimate, truth, rest_pose) triple of
    (m, S, 4) segment orientations of ``layout`` (its segment order, NaN rows where a segment has
    no data), the estimate calibrated (anatomical), the truth the source's own segments; or an
    (estimate, truth, rest_pose, layout) quadruple, for motions of different layouts. The
    figures are per angle: ``layout``'s angles, then those of the motions' layouts it lacks."""
    errors: dict[str, list[np.ndarray]] = {name: [] for name in angle_names(layout)}
    gimbal: dict[str, list[np.ndarray]] = {name: [] for name in errors}
    for estimate, truth, rest_pose, *own in motions:
        lay = own[0] if own else layout
        e, e_flags = joint_angles(estimate, rest_pose=rest_pose, layout=lay)
        t, t_flags = joint_angles(truth, rest_pose=rest_pose, layout=lay)
        error = np.remainder(e - t + 180.0, 360.0) - 180.0
        for k, name in enumerate(angle_names(lay)):
            errors.setdefault(name, []).append(error[:, k])
            gimbal.setdefault(name, []).append(((e_flags[:, k] | t_flags[:, k]) & GIMBAL) != 0)
    return {name: _figures(np.concatenate(errors[name]) if errors[name] else np.zeros(0),
                           np.concatenate(gimbal[name]) if gimbal[name] else np.zeros(0, bool)) for name in errors}
