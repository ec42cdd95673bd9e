"""A BVH file's wearer: the ``paper10`` body of its own OFFSETs (docs/protocol.md, "Body
dimensions").

Each bone is the zero-pose vector between the joints the segments map to (:mod:`.bvh_names`):
the trunk (pelvis to the neck's joint), the neck (its joint to the tip of its chain: the head's
End Site), the hip offsets (pelvis to each thigh's joint), the shoulders (the neck's joint to each
upper arm's), the thighs (to the shank's joint) and the shanks (to the joint below, the foot). The
zero pose is the segments' rest frame for the legs and trunk (:mod:`.bvh_rest` takes them as they
are), so those bones keep their vectors; the arms, which :mod:`.bvh_rest` turns onto the rest
pose's own axis, keep their lengths along it.

BVH files do not say their unit. Of :data:`UNITS`, the one that makes the legs (thigh + shank)
nearest the default adult's is taken: the CMU clips' 1/0.45 inch, Mixamo's centimetres, metres.

On another layout (``full``) the wearer's body is every bone of the layout measured on the
file's zero pose the same way, between the file's joints of its joints
(:meth:`.bvh_positions.BvhPositions.body`: the feet to the toes, the hands to the fingertips, the
head from the neck's base to the top of the head, the chest from the waist to the neck's base).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from limbstream.body import PAPER10, PAPER10_BONES, Body
from limbstream.sources.bvh_names import tip
from limbstream.sources.bvh_rest import bone_vector, zero_pose_positions

if TYPE_CHECKING:
    from limbstream.sources.bvh import BvhClip

CMU_UNIT_M = 0.0254 / 0.45
"""The CMU clips' unit, m (1/0.45 inch)."""
UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "CMU's 1/0.45 in": CMU_UNIT_M}
"""The units a BVH file's OFFSETs may be in, metres each."""
DEFAULT_LEG_M = float(PAPER10_BONES["l_thigh"]) + float(PAPER10_BONES["l_shank"])  # type: ignore[arg-type]
"""The default adult's thigh + shank, m: what picks a file's unit."""


def _tip(clip: BvhClip, joint: int, at: np.ndarray) -> np.ndarray:
    """(3,) the end of ``joint``'s chain in the zero pose (:func:`.bvh_names.tip`: down its first
    children to the last, then that joint's End Site if it has one)."""
    last, site = tip(clip, joint)
    return at[last] + (clip.end_offsets[last] if site else 0.0)


def bone_vectors(clip: BvhClip, segment_map: Mapping[str, str]) -> dict[str, np.ndarray] | None:
    """Bone -> (3,) zero-pose vector, file units, of each ``paper10`` bone; None where the map
    lacks one of its segments or a joint has nothing below it."""
    index = {name: j for j, name in enumerate(clip.joints)}
    if any(segment_map.get(s) not in index for s in PAPER10.segment_names):
        return None
    j = {s: index[segment_map[s]] for s in PAPER10.segment_names}
    at = zero_pose_positions(clip)
    out = {"hip": at[j["neck"]] - at[j["hip"]], "neck": _tip(clip, j["neck"], at) - at[j["neck"]]}
    for s in ("l", "r"):
        shank, forearm = bone_vector(clip, j[f"{s}_shank"], at), bone_vector(clip, j[f"{s}_lowerarm"], at)
        if shank is None or forearm is None:
            return None
        out |= {f"{s}_hip": at[j[f"{s}_thigh"]] - at[j["hip"]],
                f"{s}_thigh": at[j[f"{s}_shank"]] - at[j[f"{s}_thigh"]], f"{s}_shank": shank,
                f"{s}_shoulder": at[j[f"{s}_upperarm"]] - at[j["neck"]],
                f"{s}_upperarm": at[j[f"{s}_lowerarm"]] - at[j[f"{s}_upperarm"]], f"{s}_lowerarm": forearm}
    return out


def unit_of(vectors: Mapping[str, np.ndarray]) -> float:
    """Metres per file unit of the bones ``vectors`` (:func:`unit_of_leg` of their left leg)."""
    return unit_of_leg(float(np.linalg.norm(vectors["l_thigh"]) + np.linalg.norm(vectors["l_shank"])), 1.0)


def unit_of_leg(leg: float, unknown: float) -> float:
    """Metres per file unit: the :data:`UNITS` entry that puts a leg (thigh + shank) of ``leg``
    file units nearest :data:`DEFAULT_LEG_M` (by ratio); ``unknown`` where ``leg`` is not > 0."""
    if not leg > 0:
        return unknown
    return min(UNITS.values(), key=lambda m: abs(math.log(leg * m / DEFAULT_LEG_M)))


def body_of(clip: BvhClip, segment_map: Mapping[str, str]) -> Body:
    """The clip's ``paper10`` body (see the module); ValueError naming the bone and its bound where
    a bone the OFFSETs give is out of bounds (zero, or over 1.5 m), or naming what is missing."""
    vectors = bone_vectors(clip, segment_map)
    if vectors is None:
        raise ValueError("its joints do not give every bone of the 10-segment body")
    scale = unit_of(vectors)
    arms = {f"{s}_{part}" for s in "lr" for part in ("upperarm", "lowerarm")}
    bones = {name: float(np.linalg.norm(v)) * scale if name in arms else v * scale for name, v in vectors.items()}
    return Body(PAPER10, bones)
