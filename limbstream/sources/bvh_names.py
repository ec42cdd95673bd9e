"""Which BVH joint carries each segment of the 10-IMU layout.

Tried in order, the first that names a joint for every segment wins:

1. the CMU clips' two schemes (:data:`CMU_SEGMENT_MAPS`): ``LeftUpLeg``, ``LeftArm``, ... and the
   anatomical ``LeftHip``, ``LeftShoulder``, ... (where "hip" is the thigh, "shoulder" the upper arm);
2. names read as side + part (:func:`segment_of`), after any namespace (Mixamo's ``mixamorig:``):
   the side a word before or after the part (``Left``/``L``, ``Right``/``R``, joined by case or by
   ``_ - . space``: ``LeftUpLeg``, ``UpperLeg_L``, ``Thigh_R``, ``LeftThigh``, ``l_thigh``), the part
   one of :data:`PARTS`; the pelvis an unsided ``Hips``/``Pelvis``/``Hip``, the neck ``Neck``. Where
   two joints fit a segment the one nearer the root carries it (a floor root above the pelvis is
   no pelvis: its name fits none).

A file none of them fits is refused with its joints and how to map them: ``--names
JOINT=SEGMENT,...`` (a list or a file of such lines, :mod:`limbstream.sources.names`).
"""
from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from limbstream.sources import SEGMENTS, MotionFileError

CMU_SEGMENT_MAPS: dict[str, dict[str, str]] = {
    # CMU BVH export of the ASF skeleton ("LeftShoulder" is the collar bone here).
    "cmu": {
        "l_shank": "LeftLeg", "r_shank": "RightLeg", "l_thigh": "LeftUpLeg", "r_thigh": "RightUpLeg",
        "l_lowerarm": "LeftForeArm", "r_lowerarm": "RightForeArm", "l_upperarm": "LeftArm",
        "r_upperarm": "RightArm", "neck": "Neck", "hip": "Hips",
    },
    # Anatomical naming (e.g. subject 131): "LeftShoulder" is the upper arm, "Neck" the upper neck.
    "cmu_asf": {
        "l_shank": "LeftKnee", "r_shank": "RightKnee", "l_thigh": "LeftHip", "r_thigh": "RightHip",
        "l_lowerarm": "LeftElbow", "r_lowerarm": "RightElbow", "l_upperarm": "LeftShoulder",
        "r_upperarm": "RightShoulder", "neck": "lowerneck", "hip": "Hips",
    },
}
"""Segment -> joint maps for the CMU naming schemes, in the order they are tried."""

PARTS: dict[str, str] = {
    "upleg": "thigh", "upperleg": "thigh", "thigh": "thigh", "femur": "thigh",
    "leg": "shank", "lowerleg": "shank", "shank": "shank", "shin": "shank", "calf": "shank", "knee": "shank", "tibia": "shank",
    "arm": "upperarm", "upperarm": "upperarm", "humerus": "upperarm",
    "forearm": "lowerarm", "lowerarm": "lowerarm", "elbow": "lowerarm", "ulna": "lowerarm",
}
"""A sided joint's part (its name's words without the side, joined, lower case) -> segment part."""
UNSIDED: dict[str, str] = {"hips": "hip", "pelvis": "hip", "hip": "hip", "neck": "neck"}
"""An unsided joint's name (words joined, lower case) -> segment."""
SIDES = {"l": "l", "left": "l", "r": "r", "right": "r"}

FLAG = "--names JOINT=SEGMENT,... (or a file of such lines)"


def words(name: str) -> list[str]:
    """The lower-case words of a joint name, without its namespace: ``mixamorig:LeftUpLeg`` ->
    ``left up leg``, ``UpperLeg_L`` -> ``upper leg l``, ``LFoot`` -> ``l foot``."""
    name = name.rsplit(":", 1)[-1]
    return [w.lower() for w in re.findall(r"[A-Z]+(?=[A-Z][a-z]|[^A-Za-z]|$)|[A-Z]?[a-z]+|\d+", name)]


def segment_of(name: str) -> str | None:
    """The segment a joint name says it is (see the module), or None."""
    parts = words(name)
    if not parts or any(w.isdigit() for w in parts):
        return None
    joined = "".join(parts)
    if joined in UNSIDED:
        return UNSIDED[joined]
    for side, rest in ((parts[0], parts[1:]), (parts[-1], parts[:-1])):
        part = PARTS.get("".join(rest))
        if side in SIDES and part is not None:
            return f"{SIDES[side]}_{part}"
    return None


def by_parts(joints: Sequence[str]) -> dict[str, str]:
    """Segment -> the first joint (file order: nearer the root first) whose name says it."""
    found: dict[str, str] = {}
    for joint in joints:
        segment = segment_of(joint)
        if segment is not None:
            found.setdefault(segment, joint)
    return found


def pick_segment_map(joints: Sequence[str]) -> dict[str, str]:
    """The first scheme (see the module) that names a joint for every segment, in SEGMENTS order;
    ``{}`` if none does."""
    have = set(joints)
    for mapping in CMU_SEGMENT_MAPS.values():
        if set(mapping.values()) <= have:
            return {s: mapping[s] for s in SEGMENTS}
    found = by_parts(joints)
    return {s: found[s] for s in SEGMENTS} if set(SEGMENTS) <= set(found) else {}


def _listing(joints: Sequence[str]) -> str:
    return ", ".join(joints)


def segment_map(path: Path, joints: Sequence[str], names: Mapping[str, str] | None) -> dict[str, str]:
    """Segment -> joint of a file's ``joints``, from ``names`` (JOINT -> SEGMENT, as ``--names``
    gives it) or the schemes; MotionFileError naming the file's joints and how to map them
    (a scheme or mapping that leaves a segment without a joint names the segment)."""
    if names is not None:
        unknown = [j for j in names if j not in joints]
        if unknown:
            raise MotionFileError.at(path, None, f"--names: no joint named {unknown[0]!r} "
                                                 f"(joints: {_listing(joints)})")
        chosen = {seg: joint for joint, seg in names.items() if seg in SEGMENTS}
        source = "--names"
    else:
        chosen = pick_segment_map(joints)
        if chosen:
            return chosen
        chosen = by_parts(joints)
        if len(chosen) < len(SEGMENTS) // 2:
            raise MotionFileError.at(path, None, f"joint names match no naming scheme (CMU, Mixamo, sided "
                                                 f"Left/L/Right/R names); joints: {_listing(joints)}; map them "
                                                 f"with {FLAG}, segments: {', '.join(SEGMENTS)}")
        source = "the joint names"
    missing = [s for s in SEGMENTS if s not in chosen]
    if missing:
        raise MotionFileError.at(path, None, f"no joint for segment {', '.join(missing)} (from {source}; joints: "
                                             f"{_listing(joints)}); map them with {FLAG}")
    return {s: chosen[s] for s in SEGMENTS}
