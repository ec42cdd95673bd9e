"""Joint positions of ``limbstream eval``'s bodies: the mean per-joint position error, root
relative (docs/evaluation.md, "Joint positions").

Estimated positions: the body's layout's forward kinematics (:meth:`limbstream.body.Body.positions`;
``paper10`` or ``full``, :attr:`limbstream.evaluation.body.Body.layout`) driven by the estimated
segment orientations, on the source's own body where it has one (a BVH file's bones measured on
its OFFSETs, :class:`limbstream.sources.bvh_positions.BvhPositions`), else on the layout's
default body. True positions: the file's own forward kinematics at the
frames' file times (BVH), else the same forward kinematics driven by the true orientations. Both
with the pelvis joint at the origin, in the world frame (Y up), metres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from functools import cache

from limbstream.body import PAPER10, Body as Dimensions, Layout
from limbstream.evaluation.body import Body
from limbstream.sources import Motion

LAYOUT = PAPER10
"""The layout of a body that names none (its joints, in its order)."""


def scored(layout: Layout = LAYOUT) -> tuple[int, ...]:
    """Indices of the joints scored: every joint of ``layout`` but the root (at the origin in both)."""
    return tuple(j for j, name in enumerate(layout.joints) if name != layout.root.joint)


SCORED: tuple[int, ...] = scored()
""":func:`scored` of :data:`LAYOUT`."""

KINDS: tuple[str, ...] = ("hip", "knee", "ankle", "toe", "shoulder", "elbow", "wrist", "fingertip", "spine",
                          "neck_base", "head", "head_top")
"""The joints of the per-joint position table, in its order (each pools its left and right):
``paper10``'s and ``full``'s; a layout file's other joints follow in their own order."""


def source_of(motion: Motion, script_s: float = 0.0) -> dict:
    """The fields of a motion's :class:`~limbstream.evaluation.sweep.Stream` objects that tie them
    to its source (its own positions, the offset of its file's time), their motion starting
    ``script_s`` s into the stream."""
    start = motion.positions.start_s if motion.positions is not None else 0.0
    return {"source": motion.positions, "source_offset_s": start - script_s}


def kind(joint: str) -> str:
    """A joint's kind: its name without the side (``l_knee`` -> ``knee``)."""
    return joint[2:] if joint[:2] in ("l_", "r_") else joint


@cache
def chains(layout: Layout = LAYOUT) -> np.ndarray:
    """(J, S) bool: the segments whose orientations place each joint (its bones down from the root)."""
    s, j = layout.segment_index, layout.joint_index
    out = np.zeros((len(layout.joints), len(layout.segments)), bool)
    for bone in layout.bones:  # parents first: the origin's chain is known
        out[j[bone.joint]] = out[j[bone.origin]]
        out[j[bone.joint], [s[seg] for seg in bone.turned_by]] = True
    return out


CHAINS = chains()


@dataclass
class Positions:
    """One body's joint positions (its layout's joints), frame by frame.

    Attributes
    ----------
    estimated, truth : (m, J, 3) float64 metres, the pelvis joint at the origin, world frame (Y
        up); NaN where a joint's segments (or the source's time) are missing.
    joints : (J,) for each position the source's own joint (a BVH file's joint), else the layout's.
    from_file : whether ``truth`` is the source file's own (else the true orientations' FK).
    dimensions : the body both are drawn on (``dimensions.layout``: whose joints they are).
    unit_m : metres per unit of the source file (NaN: not a file with positions).
    """

    estimated: np.ndarray
    truth: np.ndarray
    joints: tuple[str, ...]
    from_file: bool
    dimensions: Dimensions
    unit_m: float


def forward(dimensions: Dimensions, q: np.ndarray, rest_pose: str) -> np.ndarray:
    """(m, J, 3) float64 the positions of ``dimensions`` under orientations ``q`` (m, S, 4) (NaN
    rows: no data), NaN for every joint whose chain holds a segment without data."""
    q = np.asarray(q, np.float64)
    ok = np.isfinite(q).all(axis=-1)  # (m, S)
    filled = np.where(ok[..., None], q, [1.0, 0.0, 0.0, 0.0])
    out = dimensions.positions(filled, rest_pose == "tpose", np.float64)
    missing = (~ok[:, None, :] & chains(dimensions.layout)[None]).any(axis=-1)  # (m, J)
    out[missing] = np.nan
    return out


def positions_of(body: Body) -> Positions:
    """The estimated and true joint positions of ``body`` on its layout (see the module)."""
    source, layout = body.source, body.layout
    if source is not None:
        dimensions = source.body(layout)
        return Positions(forward(dimensions, body.estimated, body.rest_pose), source.at(body.source_t, layout),
                         source.joints(layout), True, dimensions, source.unit_m)
    dimensions = Dimensions.default(layout)
    return Positions(forward(dimensions, body.estimated, body.rest_pose), forward(dimensions, body.truth, body.rest_pose),
                     layout.joints, False, dimensions, math.nan)


def errors_cm(positions: Positions) -> np.ndarray:
    """(m, J) the distance between each estimated and true joint, cm (NaN: either missing)."""
    return np.linalg.norm(positions.estimated - positions.truth, axis=-1) * 100.0


def position_figures(all_positions: list[Positions]) -> tuple[float, dict[str, dict]]:
    """The mean per-joint position error over every scored joint (:func:`scored`) and frame of
    ``all_positions``, cm (NaN if none), and per joint kind (:data:`KINDS`, then any other, those
    with frames) ``mean``, ``p99`` (cm) and ``n`` (joint samples scored)."""
    pooled: dict[str, list[np.ndarray]] = {k: [] for k in KINDS}
    for p in all_positions:
        err, layout = errors_cm(p), p.dimensions.layout
        for j in scored(layout):
            e = err[:, j]
            pooled.setdefault(kind(layout.joints[j]), []).append(e[np.isfinite(e)])
    joined = {k: np.concatenate(v) if v else np.zeros(0) for k, v in pooled.items()}
    everything = np.concatenate(list(joined.values()))
    figures = {k: {"mean": float(e.mean()), "p99": float(np.percentile(e, 99)), "n": int(e.size)}
               for k, e in joined.items() if e.size}
    return (float(everything.mean()) if everything.size else math.nan), figures
