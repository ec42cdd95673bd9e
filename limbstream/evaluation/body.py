"""Whole bodies of an evaluation: a motion's segment streams put back together, frame by frame,
for what only a body has: heading correction by its joints, the joint error, and the dump that
lets anyone recompute every figure.

- :func:`layout_of`: the layout a motion's bodies are evaluated on (``eval --layout``, else its own).
- :func:`bodies`: per motion, the estimated orientations (the calibrated reconstruction with a
  sensor model, else the reconstruction) and the true ones (the segments' with a sensor model,
  else the samples), (frames, S, 4) in the order of the motion's layout (``paper10``: SEGMENTS;
  ``full``), NaN where a segment has no data.
- :func:`correct_heading`: a calibrated body's headings held by its joints, as the aggregator
  holds them (:class:`limbstream.heading.HeadingCorrection`, run over the motion from the
  calibration on), stopped where the motion contradicts the joints' constraints (``contradicted``).
- :func:`joint_figures`: the joint error (the angle between the estimated and the true relative
  orientation of each pair of adjacent segments, :func:`limbstream.heading.joints.joint_errors_deg`)
  pooled over bodies, overall and per joint kind, with its first and last minute: the joints
  among the body's layout's segments (``wire.joints_among``: ``paper10``'s table, or ``full``'s
  with its ankles, wrists and lumbar spine, the shoulders and neck from the chest).
- :func:`dump`: one body as an npz file, its joint positions too (docs/evaluation.md, "Dumps").
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from limbstream import wire
from limbstream.body import PAPER10, Layout as BodyLayout
from limbstream.heading import HeadingCorrection
from limbstream.heading.joints import Layout, joint_errors_deg, kind
from limbstream.sources import Motion

if TYPE_CHECKING:
    from limbstream.evaluation.positions import Positions
    from limbstream.sources.bvh_positions import BvhPositions

KINDS: tuple[str, ...] = ("knee", "elbow", "ankle", "wrist", "hip", "shoulder", "lumbar", "neck")
"""The joint kinds of the per-joint table, in its order (each pools its left and right; the
ankles, wrists and lumbar spine where the bodies have feet, hands and a chest)."""

LAYOUT = Layout.of(wire.SEGMENTS)
"""The joints among ``paper10``'s segments (relative orientations: the rest pose does not matter)."""


@dataclass
class Body:
    """One motion's bodies, frame by frame.

    Attributes
    ----------
    name : the motion's name.
    t : (m,) s, the frames' times (the motion after the calibration script with a sensor model).
    estimated, truth : (m, S, 4) in ``layout``'s segment order, NaN rows where a segment has no data.
    rest_pose : what identity means for the motion's orientations.
    streams : {segment index: the pool's stream index} of the body's segments.
    calibrated : whether ``estimated`` is a calibrated reconstruction (a sensor model).
    source_t : (m,) s, each frame's time in the source file (NaN: none).
    source : the source file's own joint positions, if it has them (a BVH file's).
    layout : the body's layout (its segments, in their order; the joints its positions are of).
    contradicted : the joints whose constraints its motion contradicts, each with its share of the
        last minute, once the heading correction found so and stopped (at ``stopped_s``, s of
        motion; :mod:`limbstream.heading.contradiction`); empty: not found, or not corrected.
    """

    name: str
    t: np.ndarray
    estimated: np.ndarray
    truth: np.ndarray
    rest_pose: str
    streams: dict[int, int]
    calibrated: bool
    source_t: np.ndarray
    source: BvhPositions | None = None
    layout: BodyLayout = PAPER10
    contradicted: dict[str, float] = field(default_factory=dict)
    stopped_s: float = math.nan

    @property
    def joints(self) -> Layout:
        """The joints among the body's segments (its layout's joint table)."""
        return LAYOUT if self.layout.segment_names == wire.SEGMENTS else Layout.of(self.layout.segment_names)


def layout_of(motion: Motion, layout: BodyLayout | None = None) -> BodyLayout:
    """The layout a motion's bodies are evaluated on: ``layout`` if given, else the motion's own
    (``Motion.layout``; ``paper10`` where no built-in layout holds its segments)."""
    if layout is not None:
        return layout
    try:
        return motion.layout
    except ValueError:
        return PAPER10


def bodies(pool, rec: np.ndarray, calibrated: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> list[Body]:
    """The bodies of a pool of streams (``limbstream.evaluation.sweep``'s): ``rec`` (n, 4) the
    pooled reconstruction; ``calibrated``: per stream with a truth, (calibrated motion, truth,
    where both are finite), each over the motion after the calibration script. Streams named
    ``<motion>/<segment>`` of a body segment are put together by motion."""
    out: dict[str, Body] = {}
    for j, s in enumerate(pool.streams):
        motion, _, segment = s.name.rpartition("/")
        layout = s.layout or PAPER10
        if segment not in layout.segment_index:
            continue
        if j in calibrated:
            estimate, truth, _ = calibrated[j]
            t = s.t[s.motion_from:]
        else:
            estimate, truth, t = rec[pool.start[j]:pool.start[j + 1]], s.q, s.t
        if motion not in out:
            empty = np.full((len(truth), len(layout.segments), 4), np.nan)
            t = np.asarray(t, np.float64)
            out[motion] = Body(motion, t, empty, empty.copy(), s.rest_pose, {}, j in calibrated, t + s.source_offset_s,
                               s.source, layout)
        body = out[motion]
        k = body.layout.segment_index[segment]
        body.estimated[:, k], body.truth[:, k] = estimate, truth
        body.streams[k] = j
    return list(out.values())


def correct_heading(body: Body) -> None:
    """Hold a calibrated body's headings by its joints, in place (its estimated orientations
    turned about the vertical, each segment by its own correction, from the first frame on)."""
    if not body.calibrated or len(body.t) < 2:
        return
    names = body.layout.segment_names
    have = sorted(body.streams)
    layout = Layout.of([names[k] for k in have], body.rest_pose)
    fs = 1.0 / float(np.median(np.diff(body.t)))
    body.estimated[:, have], est = HeadingCorrection.run_over(body.estimated[:, have], layout, fs)
    body.contradicted, body.stopped_s = est.contradicted_joints(0), float(est.stopped_s[0])


def joint_figures(bodies_: list[Body], minute_s: float = 60.0) -> tuple[float, dict[str, dict]]:
    """The joint error pooled over ``bodies_``: its mean over every joint and frame (deg; NaN if
    none), and per joint kind (:data:`KINDS`, those with frames) ``mean``, ``p99``, ``first``
    (the mean over each body's first minute), ``last`` (over its last minute: the frames within
    ``minute_s`` s of its end), ``n`` (joint samples scored). A joint counts where both its
    segments are finite in the estimate and the truth."""
    errors: dict[str, list[np.ndarray]] = {k: [] for k in KINDS}
    first: dict[str, list[np.ndarray]] = {k: [] for k in KINDS}
    last: dict[str, list[np.ndarray]] = {k: [] for k in KINDS}
    for body in bodies_:
        joints = body.joints
        err = joint_errors_deg(np.nan_to_num(body.estimated), np.nan_to_num(body.truth), joints)  # (m, J)
        ok = (np.isfinite(body.estimated).all(axis=-1) & np.isfinite(body.truth).all(axis=-1))
        both = ok[:, joints.parent] & ok[:, joints.child]
        since = body.t - body.t[0]
        for j, name in enumerate(joints.joints):
            mine = both[:, j]
            errors[kind(name)].append(err[mine, j])
            first[kind(name)].append(err[mine & (since < minute_s), j])
            last[kind(name)].append(err[mine & (since >= since[-1] - minute_s), j])
    pooled = {k: np.concatenate(v) if v else np.zeros(0) for k, v in errors.items()}
    everything = np.concatenate(list(pooled.values()))
    figures = {}
    for k, e in pooled.items():
        if e.size:
            f, la = np.concatenate(first[k]), np.concatenate(last[k])
            figures[k] = {"mean": float(e.mean()), "p99": float(np.percentile(e, 99)),
                          "first": float(f.mean()) if f.size else math.nan,
                          "last": float(la.mean()) if la.size else math.nan, "n": int(e.size)}
    return (float(everything.mean()) if everything.size else math.nan), figures


def dump(body: Body, folder: Path, heading: str, positions: Positions) -> Path:
    """Write ``body`` to ``folder/<motion>.npz`` (the name's characters other than letters,
    digits, ``._-`` as ``_``): ``t`` (m,) s, ``estimated`` and ``truth`` (m, S, 4) float64
    scalar-first (NaN: no data), ``segment_names`` (S,) (the layout's, ``layout``), ``rest_pose``,
    ``heading_correction`` (``off`` or ``joints``), ``joints`` (J,) the joints' names and
    ``joint_parent``, ``joint_child`` (J,) their segments' indices; from ``positions``
    (:mod:`limbstream.evaluation.positions`): ``source_t`` (m,) s, ``positions`` and
    ``true_positions`` (m, P, 3) m, ``position_joints`` (P,), ``positions_from_file``,
    ``source_unit_m``; ``root`` and ``true_root`` (m, 3) m, the estimated root tracked from the
    estimated feet and the file's (:func:`limbstream.evaluation.translation.root_paths`; NaN where
    there is none): world positions are ``positions + root[:, None]``; ``feet`` (m, C, 3) m the
    estimate's foot points in its world, ``foot_points`` (C,) their names, ``contacts`` (m,) its
    contact bits (``wire.CONTACTS``), ``root_heading_rad`` () the turn about +Y from its world to
    the truth's (:func:`limbstream.evaluation.translation.aligned`; C = 0 and NaN where there is no
    root path). Returns the path."""
    path = Path(folder) / (re.sub(r"[^A-Za-z0-9._-]", "_", body.name) + ".npz")
    joints = body.joints
    from limbstream.evaluation.translation import RootPaths, root_paths  # (it reads this module's bodies)
    paths = root_paths(body, positions)
    if paths is None:
        nowhere = np.full((len(body.t), 3), np.nan)
        paths = RootPaths(nowhere, nowhere, np.zeros((len(body.t), 0, 3)), np.zeros((len(body.t), 0, 3)), (),
                          np.zeros(len(body.t), np.int64), math.nan)
    np.savez(path, root=paths.root, true_root=paths.true_root, feet=paths.feet, foot_points=np.array(paths.names, str),
             contacts=paths.contacts, root_heading_rad=np.array(paths.heading_rad), t=body.t, estimated=body.estimated,
             truth=body.truth,
             segment_names=np.array(body.layout.segment_names), layout=np.array(body.layout.name),
             rest_pose=np.array(body.rest_pose), heading_correction=np.array(heading),
             joints=np.array(joints.joints), joint_parent=joints.parent, joint_child=joints.child,
             source_t=body.source_t, positions=positions.estimated, true_positions=positions.truth,
             position_joints=np.array(positions.joints), positions_from_file=np.array(positions.from_file),
             source_unit_m=np.array(positions.unit_m))
    return path
