"""True joint angles of a motion source and the error figures of estimated ones (docs/evaluation.md,
"Joint angles")."""
from __future__ import annotations

import math

import numpy as np

from limbstream import wire
from limbstream.joints.convention import ANGLES, GIMBAL, joint_angles
from limbstream.sources import Motion

FIGURES: tuple[str, ...] = ("mean", "p99", "bias", "n", "gimbal")
"""Per angle: mean and 99th percentile of the absolute error (deg), mean signed error (bias,
estimate - truth, deg), frames scored, frames left out near gimbal lock."""


def in_layout(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """A motion's orientations in the 10-segment layout: (m, 10, 4) float64 (NaN rows for the
    segments it lacks) and (10,) bool, the segments it has."""
    q = np.full((len(motion.t), len(wire.SEGMENTS), 4), np.nan)
    present = np.zeros(len(wire.SEGMENTS), bool)
    for k, name in enumerate(motion.segments):
        if name in wire.SEGMENTS:
            q[:, wire.SEGMENTS.index(name)] = motion.q[:, k]
            present[wire.SEGMENTS.index(name)] = True
    return q, present


def true_angles(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """The joint angles of a motion source's own segment orientations (BVH clips, npz files, the
    generator: ``Motion.orientations`` ``segments``): (m, A) degrees and (m, A) flags
    (:func:`joint_angles`). ValueError for a recording of real sensors (rest-calibrated, their
    facing unknown, or uncalibrated: not the segments' own orientations)."""
    if motion.orientations != "segments":
        raise ValueError(f"{motion.name}: real sensors' orientations ({motion.orientations}) have no true joint "
                         "angles")
    q, present = in_layout(motion)
    return joint_angles(q, present, motion.rest_pose)


def angle_errors(estimate: np.ndarray, truth: np.ndarray, flags: np.ndarray | None = None) -> dict[str, dict]:
    """Per-angle error figures (:data:`FIGURES`) of ``estimate`` against ``truth`` (each (m, A)
    degrees, :data:`ANGLES` order; NaN frames are not scored). Errors wrap to (-180, 180]. Frames
    that ``flags`` (m, A) (either side's, or-ed) marks GIMBAL are left out and counted."""
    estimate, truth = np.asarray(estimate, np.float64), np.asarray(truth, np.float64)
    error = np.remainder(estimate - truth + 180.0, 360.0) - 180.0
    gimbal = np.zeros(error.shape, bool) if flags is None else (np.asarray(flags) & GIMBAL) != 0
    out = {}
    for k, name in enumerate(ANGLES):
        e = error[:, k]
        scored = np.isfinite(e) & ~gimbal[:, k]
        e = e[scored]
        out[name] = {"mean": float(np.abs(e).mean()) if e.size else math.nan,
                     "p99": float(np.percentile(np.abs(e), 99)) if e.size else math.nan,
                     "bias": float(e.mean()) if e.size else math.nan,
                     "n": int(e.size), "gimbal": int((gimbal[:, k] & np.isfinite(error[:, k])).sum())}
    return out


def pooled_errors(motions) -> dict[str, dict]:
    """Per-angle error figures pooled over motions: each an (estimate, truth, rest_pose) triple of
    (m, 10, 4) segment orientations (SEGMENTS order, NaN rows where a segment has no data), the
    estimate calibrated (anatomical), the truth the source's own segments."""
    estimated, true, flags = [], [], []
    for estimate, truth, rest_pose in motions:
        e, e_flags = joint_angles(estimate, rest_pose=rest_pose)
        t, t_flags = joint_angles(truth, rest_pose=rest_pose)
        estimated.append(e)
        true.append(t)
        flags.append(e_flags | t_flags)
    if not estimated:
        return angle_errors(np.zeros((0, len(ANGLES))), np.zeros((0, len(ANGLES))))
    return angle_errors(np.concatenate(estimated), np.concatenate(true), np.concatenate(flags))
