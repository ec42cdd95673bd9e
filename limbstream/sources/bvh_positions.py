"""A BVH file's own joint positions, and a layout's body sized by its OFFSETs.

What a motion loaded from a BVH file keeps of it (``Motion.positions``): the file's forward
kinematics (:func:`limbstream.sources.bvh.joint_positions`) at the joints a layout has, root
relative, in metres; which of the file's joints each of the layout's joints is; and the layout's
bones measured on the file's zero pose, so that the layout's forward kinematics
(:meth:`limbstream.body.Body.positions`) driven by the segments' true orientations puts every
joint where the file does, wherever the file has no joint between them that the layout lacks.

Units: BVH files do not say theirs; :func:`metres_per_unit` picks one as the wearer's body does
(:func:`.bvh_body.unit_of_leg`).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from limbstream import quat
from limbstream.body import PAPER10, Body, Layout
from limbstream.sources.bvh_body import CMU_UNIT_M, unit_of_leg
from limbstream.sources.bvh_names import tip
from limbstream.sources.bvh_rest import bone_end, zero_pose_positions

if TYPE_CHECKING:
    from limbstream.sources.bvh import BvhClip

@dataclass(frozen=True, eq=False)
class BvhPositions:
    """The joint positions of the BVH file a motion was read from.

    Attributes
    ----------
    clip : the parsed file (:class:`limbstream.sources.bvh.BvhClip`).
    segment_map : segment -> the file's joint that carries it.
    corrections : segment -> (4,) the rotation its orientations were turned by on the right
        (:func:`limbstream.sources.bvh_rest.rest_pose`: arms off the rest pose's direction).
    rest_pose : the motion's rest pose.
    start_s : the file's time at the motion's t = 0, s (a dropped first frame: one frame time).
    """

    clip: BvhClip
    segment_map: Mapping[str, str]
    corrections: Mapping[str, np.ndarray]
    rest_pose: str
    start_s: float = 0.0
    _cache: dict = field(default_factory=dict, repr=False)  # (what, layout name) -> joints, body, positions

    @cached_property
    def unit_m(self) -> float:
        """Metres per file unit (see the module)."""
        return metres_per_unit(self.clip, self.segment_map)

    def joints(self, layout: Layout = PAPER10) -> tuple[str, ...]:
        """(J,) for each of ``layout.joints`` the file's joint whose position it is: a segment's
        proximal joint is the joint that carries it; a distal joint no segment starts at is the
        first joint below the segment's at another place (``<joint>/End Site`` where there is
        none), the tip of the chain for ``full``'s head (:func:`.bvh_names.tip`). ValueError if the map lacks a segment of the layout."""
        if ("joints", layout.name) not in self._cache:
            self._cache["joints", layout.name] = tuple(self._file_joints(layout))
        return self._cache["joints", layout.name]

    def body(self, layout: Layout = PAPER10) -> Body:
        """The layout's body measured on the file: each bone the zero-pose vector between its
        joints' file joints, in metres, turned into its segment's frame (by the segment's
        correction, if any)."""
        if ("body", layout.name) in self._cache:
            return self._cache["body", layout.name]
        names = self.joints(layout)
        at = zero_pose_positions(self.clip) * self.unit_m
        place = dict(zip(layout.joints, self._zero(names, at)))
        vectors = {}
        for bone in layout.bones:
            vec = place[bone.joint] - place[bone.origin]
            c = self.corrections.get(bone.segment) if bone.name == bone.segment else None
            vectors[bone.name] = vec if c is None else quat.rotate(quat.conjugate(c), vec)
        self._cache["body", layout.name] = Body.from_vectors(layout, vectors, self.rest_pose)
        return self._cache["body", layout.name]

    def at(self, t_s: np.ndarray, layout: Layout = PAPER10) -> np.ndarray:
        """(m, J, 3) float64 the file's positions of ``layout.joints`` at file times ``t_s`` (m,)
        s, the root joint at the origin, metres, the file's world frame; linear between frames,
        NaN outside the file's frames (or where ``t_s`` is NaN)."""
        return self._interpolate(self._positions(layout), t_s)

    def root_at(self, t_s: np.ndarray, layout: Layout = PAPER10) -> np.ndarray:
        """(m, 3) float64 the path of ``layout``'s root joint (its file joint) at file times ``t_s``
        (m,) s, metres, the file's world frame (its own origin and floor), as :meth:`at`."""
        if ("root", layout.name) not in self._cache:
            from limbstream.sources.bvh import joint_positions

            joint = self.joints(layout)[layout.joint_index[layout.root.joint]].removesuffix(_SITE)
            j = self.clip.joints.index(joint)
            self._cache["root", layout.name] = joint_positions(self.clip, [j])[0][:, j] * self.unit_m
        return self._interpolate(self._cache["root", layout.name][:, None], t_s)[:, 0]

    def travels(self, layout: Layout = PAPER10) -> bool:
        """Whether the file moves ``layout``'s root joint: a joint from it up to the file's root has
        all three position channels (else :meth:`root_at` is its zero pose's place throughout)."""
        from limbstream.sources.bvh import _moves

        joint = self.joints(layout)[layout.joint_index[layout.root.joint]].removesuffix(_SITE)
        return _moves(self.clip, self.clip.joints.index(joint))

    def _interpolate(self, frames: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """``frames`` (F, ...) at file times ``t_s`` (m,): linear between frames, NaN outside."""
        x = np.asarray(t_s, np.float64) / self.clip.frame_time
        inside = np.isfinite(x) & (x >= -1e-9) & (x <= len(frames) - 1 + 1e-9)
        x = np.clip(np.nan_to_num(x), 0.0, len(frames) - 1)
        k = np.minimum(np.floor(x).astype(int), max(len(frames) - 2, 0))
        u = (x - k).reshape(-1, *([1] * (frames.ndim - 1)))
        out = frames[k] * (1.0 - u) + frames[np.minimum(k + 1, len(frames) - 1)] * u
        out[~inside] = np.nan
        return out

    def _positions(self, layout: Layout) -> np.ndarray:
        """(F, J, 3) the file's positions of ``layout.joints`` at its frames, root relative, m."""
        if ("frames", layout.name) not in self._cache:
            from limbstream.sources.bvh import joint_positions

            names = self.joints(layout)
            index = {name: j for j, name in enumerate(self.clip.joints)}
            place, ends = joint_positions(self.clip, [index[n.removesuffix(_SITE)] for n in names])
            columns = [ends[:, index[n.removesuffix(_SITE)]] if n.endswith(_SITE) else place[:, index[n]]
                       for n in names]
            out = np.stack(columns, axis=1)
            root = layout.joint_index[layout.root.joint]
            self._cache["frames", layout.name] = (out - out[:, root:root + 1]) * self.unit_m
        return self._cache["frames", layout.name]

    def _zero(self, names: Sequence[str], at: np.ndarray) -> np.ndarray:
        """(J, 3) the zero-pose positions ``at`` (J_file, 3) of the named file joints (and sites)."""
        index = {name: j for j, name in enumerate(self.clip.joints)}
        out = []
        for n in names:
            j = index[n.removesuffix(_SITE)]
            out.append(at[j] + self.clip.end_offsets[j] * self.unit_m if n.endswith(_SITE) else at[j])
        return np.array(out)

    def _file_joints(self, layout: Layout) -> list[str]:
        """The file's joint (or ``<joint>/End Site``) of each of ``layout.joints``."""
        missing = [s.name for s in layout.segments if s.name not in self.segment_map]
        if missing:
            raise ValueError(f"{self.clip.path}: no joint for segment {', '.join(missing)} of layout {layout.name}")
        index = {name: j for j, name in enumerate(self.clip.joints)}
        found = {s.joint: self.segment_map[s.name] for s in layout.segments}
        at = zero_pose_positions(self.clip)
        for s in layout.segments:
            if s.end not in found and s.name in _TO_TIP:
                last, site = tip(self.clip, index[self.segment_map[s.name]])
                found[s.end] = self.clip.joints[last] + (_SITE if site else "")
            elif s.end not in found:
                own = self.segment_map[s.name]
                end = bone_end(self.clip, index[own], at)
                found[s.end] = self.clip.joints[end] if end is not None else own + _SITE
        return [found[j] for j in layout.joints]


_SITE = "/End Site"
_TO_TIP = ("head",)
"""Segments whose bone ends at the tip of their joint's chain (``full``'s head: the neck's base
to the top of the head), not at the first joint below."""


def metres_per_unit(clip: BvhClip, segment_map: Mapping[str, str]) -> float:
    """Metres per unit of ``clip`` (:func:`.bvh_body.unit_of_leg` of its left leg: the ``l_thigh``
    joint to the ``l_shank`` joint to the end of its bone, a joint below it or its End Site), CMU's
    where the map has no such leg."""
    index = {name: j for j, name in enumerate(clip.joints)}
    at = zero_pose_positions(clip)
    thigh, shank = index.get(segment_map.get("l_thigh", "")), index.get(segment_map.get("l_shank", ""))
    if thigh is None or shank is None:
        return CMU_UNIT_M
    end = bone_end(clip, shank, at)
    shin = (at[end] - at[shank] if end is not None else clip.end_offsets[shank])
    if not np.isfinite(shin).all():
        return CMU_UNIT_M
    return unit_of_leg(float(np.linalg.norm(at[shank] - at[thigh]) + np.linalg.norm(shin)), CMU_UNIT_M)
