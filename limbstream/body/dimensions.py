"""A wearer's body: the bone vectors of a layout, and its forward kinematics.

A body is its bones: per bone of a :class:`~limbstream.body.layout.Layout` a length (m, along the
layout's rest direction) or a vector (m, in its segment's frame at rest, as a BVH file's offsets
give it). Built from a height by Winter's proportions (:meth:`Body.from_height`), from a file of
bone lengths (:meth:`Body.from_file`), from bone vectors (:meth:`Body.from_vectors`) or as a
layout's default (:meth:`Body.default`). Bounds: height within [0.5, 2.5] m, each bone in
(0, 1.5] m; anything else is refused with the bound.
"""
from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from limbstream import wire
from limbstream.body.builtin import DEFAULT_HEIGHT_M, PAPER10, PAPER10_BONES
from limbstream.body.files import read_table
from limbstream.body.layout import Layout
from limbstream.kernel import reconstruct

HEIGHT_BOUNDS_M = (0.5, 2.5)
"""A body's height, m: within these (inclusive)."""
MAX_BONE_M = 1.5
"""A bone's length, m: above 0, at most this."""


def check_height(height_m: Any) -> float:
    """``height_m`` as a float if within :data:`HEIGHT_BOUNDS_M`, else ValueError with the bound."""
    lo, hi = HEIGHT_BOUNDS_M
    if isinstance(height_m, bool) or not isinstance(height_m, int | float) or not lo <= height_m <= hi:
        raise ValueError(f"height must be within [{lo}, {hi}] m, got {height_m!r}")
    return float(height_m)


def check_length(name: str, length: Any) -> float:
    """``length`` of bone ``name`` as a float if in (0, :data:`MAX_BONE_M`] m, else ValueError."""
    if isinstance(length, bool) or not isinstance(length, int | float | np.floating) or not 0 < length <= MAX_BONE_M:
        raise ValueError(f"bone {name!r} must be in (0, {MAX_BONE_M}] m, got {length!r}")
    return float(length)


class Body:
    """Bone vectors of ``layout`` in each rest pose, (B, 3) m in ``layout.bones`` order.

    Parameters
    ----------
    layout : the layout the bones belong to.
    bones : bone name -> a length (m, along the layout's rest direction in each rest pose) or a
        3-vector (m, in its segment's frame in ``rest_pose``; in the other rest pose the same vector
        where the layout's direction is the same in both, else the layout's direction at its
        length). Every bone of the layout, no other.
    rest_pose : the rest pose vectors refer to (wire.REST_POSES).
    height_m : the wearer's height, m, when known (:meth:`from_height`).
    """

    def __init__(self, layout: Layout, bones: Mapping[str, Any], rest_pose: str = wire.DEFAULT_REST_POSE,
                 height_m: float | None = None):
        wire.check_rest_pose(rest_pose)
        names = layout.bone_names
        unknown = [b for b in bones if b not in names]
        if unknown:
            raise ValueError(f"layout {layout.name} has no bone {', '.join(map(repr, unknown))}")
        missing = [b for b in names if b not in bones]
        if missing:
            raise ValueError(f"missing bone {', '.join(map(repr, missing))} of layout {layout.name}")
        self.layout = layout
        self.height_m = None if height_m is None else check_height(height_m)
        vectors = {pose: np.empty((len(names), 3)) for pose in wire.REST_POSES}
        for i, bone in enumerate(layout.bones):
            value = bones[bone.name]
            if isinstance(value, int | float | np.floating) and not isinstance(value, bool):
                length = check_length(bone.name, value)
                for pose in wire.REST_POSES:
                    vectors[pose][i] = np.array(bone.directions[pose]) * length
                continue
            vec = _vector(bone.name, value)
            length = check_length(bone.name, float(np.linalg.norm(vec)))
            for pose in wire.REST_POSES:
                same = bone.directions[pose] == bone.directions[rest_pose]
                vectors[pose][i] = vec if pose == rest_pose or same else np.array(bone.directions[pose]) * length
        for array in vectors.values():
            array.flags.writeable = False  # the chain is built from them once
        self.vectors = vectors
        """Rest pose -> (B, 3) bone vectors, m, in their segments' frames at rest."""

    @property
    def lengths(self) -> dict[str, float]:
        """Bone name -> length, m."""
        return dict(self._lengths)

    @cached_property
    def _lengths(self) -> dict[str, float]:  # (every stats message of a subject with a body gives them: once)
        standing = self.vectors[wire.DEFAULT_REST_POSE]
        return {name: float(np.linalg.norm(v)) for name, v in zip(self.layout.bone_names, standing)}

    def positions(self, q: np.ndarray, tpose: np.ndarray | bool = False, dtype: type = np.float32) -> np.ndarray:
        """Joint positions, the root joint at the origin: each joint its bone's origin joint plus
        the bone turned by its segment's orientation, or by the SLERP toward its neighbour's where
        it bends (:class:`~limbstream.body.layout.Bend`) (in C: :class:`reconstruct.Chain`).

        Parameters
        ----------
        q : (..., S, 4) segment orientations, ``layout.segments`` order, scalar-first, unit norm.
        tpose : (...) bool or a bool: the orientations refer to the T-pose (else to the standing
            rest pose).
        dtype : of the result, float32 or float64 (summed in float64 either way).

        Returns
        -------
        (..., J, 3) metres, ``layout.joints`` order.
        """
        q = np.asarray(q)
        if q.ndim < 2 or q.shape[-2:] != (len(self.layout.segments), 4):
            raise ValueError(f"orientations must be (..., {len(self.layout.segments)}, 4) for layout "
                             f"{self.layout.name}, got {q.shape}")
        return self._chain.positions(q, tpose, dtype)

    @cached_property
    def _chain(self) -> reconstruct.Chain:
        s, j = self.layout.segment_index, self.layout.joint_index
        root = self.layout.root.joint
        bones = self.layout.bones
        return reconstruct.Chain([s[b.segment] for b in bones], [j[b.joint] for b in bones],
                                 [-1 if b.origin == root else j[b.origin] for b in bones],
                                 self.vectors["standing"], self.vectors["tpose"], len(self.layout.joints),
                                 [-1 if b.bend is None else s[b.bend.toward] for b in bones],
                                 [0.0 if b.bend is None else b.bend.share for b in bones])

    def to_dict(self) -> dict[str, Any]:
        """``layout`` and the bones (lengths where a bone lies along its rest direction, else
        vectors in the standing frame), a body file's table (:meth:`from_mapping` reads it)."""
        out: dict[str, Any] = {"layout": self.layout.name}
        for bone, vec in zip(self.layout.bones, self.vectors["standing"]):
            length = float(np.linalg.norm(vec))
            along = np.array(bone.directions["standing"]) * length
            out[bone.name] = length if np.array_equal(along, vec) else [float(c) for c in vec]
        return out

    @classmethod
    def from_height(cls, layout: Layout, height_m: float) -> Body:
        """The default adult scaled to ``height_m`` (m, within :data:`HEIGHT_BOUNDS_M`): each bone
        its layout's height fraction (Winter, *Biomechanics and Motor Control of Human
        Movement*, Fig. 4.1, segment lengths as fractions of height H) times ``height_m``."""
        height_m = check_height(height_m)
        lacking = [b.name for b in layout.bones if b.height_fraction is None]
        if lacking:
            raise ValueError(f"layout {layout.name} gives no height fraction for bone {', '.join(map(repr, lacking))}")
        return cls(layout, {b.name: b.height_fraction * height_m for b in layout.bones if b.height_fraction},
                   height_m=height_m)

    @classmethod
    def default(cls, layout: Layout) -> Body:
        """``paper10``: :data:`~limbstream.body.builtin.PAPER10_BONES` (the skeleton the paper's
        evaluation uses); any other layout: :meth:`from_height` at
        :data:`~limbstream.body.builtin.DEFAULT_HEIGHT_M`."""
        if layout is PAPER10 or layout == PAPER10:
            return cls(layout, PAPER10_BONES)
        return cls.from_height(layout, DEFAULT_HEIGHT_M)

    @classmethod
    def from_vectors(cls, layout: Layout, vectors: Mapping[str, Any], rest_pose: str = "tpose") -> Body:
        """A body whose bones are vectors (m, (3,) each, in their segments' frames in
        ``rest_pose``): a skeleton file's offsets (a BVH's, in the T-pose) mapped to the layout's
        bones. Every bone of the layout must be given."""
        return cls(layout, {name: _vector(name, v) for name, v in vectors.items()}, rest_pose)

    @classmethod
    def from_mapping(cls, layout: Layout, data: Mapping[str, Any], where: str = "body") -> Body:
        """A body from a file's table: bone name = metres (or a 3-vector, standing frame), every
        bone of ``layout``; an optional ``layout`` entry must name ``layout``."""
        data = dict(data)
        named = data.pop("layout", layout.name)
        if named != layout.name:
            raise ValueError(f"{where}: a body of layout {named!r}, not {layout.name!r}")
        try:
            return cls(layout, data)
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from None

    @classmethod
    def from_file(cls, layout: Layout, path: str | Path) -> Body:
        """A body from a ``.toml`` or ``.json`` file of bone lengths (:meth:`from_mapping`);
        ValueError naming the file and the unknown, missing or out-of-bounds bone."""
        return cls.from_mapping(layout, read_table(path), str(path))


def _vector(name: str, value: Any) -> np.ndarray:
    """(3,) finite float64 vector of bone ``name``, else ValueError naming it."""
    try:
        vec = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        vec = np.empty(0)
    if vec.shape != (3,) or not np.all(np.isfinite(vec)):
        raise ValueError(f"bone {name!r} must be a length in m or a finite 3-vector, got {value!r}")
    return vec


def lengths_of(layout: Layout, positions: np.ndarray) -> dict[str, float]:
    """Bone name -> length, m, of joint positions ``positions`` (J, 3) m in ``layout.joints``
    order (a pose frame's): the distance from each bone's origin joint to its joint, in float64."""
    at = layout.joint_index
    p = np.asarray(positions, np.float64)
    return {b.name: float(np.linalg.norm(p[at[b.joint]] - p[at[b.origin]])) for b in layout.bones}


def rest_heights(body: Body) -> dict[str, float]:
    """Joint name -> height above the lowest joint, m, standing in the rest pose (identity
    orientations, ``standing``)."""
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(body.layout.segments), 1))
    y = body.positions(q, False, np.float64)[:, 1]
    return {joint: float(v - y.min()) for joint, v in zip(body.layout.joints, y)}

