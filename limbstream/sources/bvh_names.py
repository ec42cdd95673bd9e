"""Which BVH joint carries each segment of a layout (``paper10``, the 10-IMU body, by default).

Tried in order, the first that names a joint for every segment wins:

1. the CMU clips' two schemes (:data:`CMU_SEGMENT_MAPS`): ``LeftUpLeg``, ``LeftArm``, ... and the
   anatomical ``LeftHip``, ``LeftShoulder``, ... (where "hip" is the thigh, "shoulder" the upper arm);
2. names read as side + part (:func:`segment_of`), after any namespace (Mixamo's ``mixamorig:``):
   the side a word before or after the part (``Left``/``L``, ``Right``/``R``, joined by case or by
   ``_ - . space``: ``LeftUpLeg``, ``UpperLeg_L``, ``Thigh_R``, ``LeftThigh``, ``l_thigh``), the part
   one of :data:`PARTS`; the pelvis an unsided ``Hips``/``Pelvis``/``Hip``, the neck ``Neck``. Where
   two joints fit a segment the one nearer the root carries it (a floor root above the pelvis is
   no pelvis: its name fits none).

``full``'s further segments (:func:`full_map`): the feet and hands by the same schemes (CMU's
``LeftFoot``/``LeftAnkle`` and ``LeftHand``/``LeftWrist``; sided ``foot``, ``ankle``, ``hand``,
``wrist``), the head by an unsided ``Head``, the chest by the spine: the joint whose bone
reaches the neck joint's place (CMU's ``Spine`` below ``Spine1``/``Neck``, 131's ``Chest`` below
``Chest2``/``lowerneck``, Mixamo's ``Spine2``). A foot or hand carries the orientation of the
joint whose bone reaches its tip (:func:`carrier`: CMU's ``LeftFingerBase``, at the wrist, turns
the hand's bone; ``LeftFoot`` the foot's, to ``LeftToeBase``).

A file none of them fits is refused with its joints and how to map them: ``--names
JOINT=SEGMENT,...`` (a list or a file of such lines, :mod:`limbstream.sources.names`). A mapping
names any segments of the layout (a layout file's own: ``lowerback=lower_back``), over what the
schemes find: the segments it does not name keep the schemes' joints.
"""
from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from limbstream.sources import SEGMENTS, MotionFileError
from limbstream.sources.bvh_rest import bone_end, zero_pose_positions

if TYPE_CHECKING:
    from limbstream.body import Layout
    from limbstream.sources.bvh import BvhClip

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

CMU_FULL_PARTS: dict[str, dict[str, str]] = {
    "cmu": {"l_foot": "LeftFoot", "r_foot": "RightFoot", "l_hand": "LeftHand", "r_hand": "RightHand",
            "lower_back": "LowerBack", "thorax": "Spine1"},
    "cmu_asf": {"l_foot": "LeftAnkle", "r_foot": "RightAnkle", "l_hand": "LeftWrist", "r_hand": "RightWrist",
                "lower_back": "lowerback", "thorax": "Chest2"},
}
"""Each CMU scheme's joints of ``full``'s feet and hands (its head and chest: from the neck,
:func:`_full_parts`) and of a layout file's spine below and above the chest (``lower_back``:
the joint at the pelvis that turns the spine; ``thorax``: the one at the neck's base that turns
the neck and collar bones; examples/layouts/spine17.json)."""

PARTS: dict[str, str] = {
    "upleg": "thigh", "upperleg": "thigh", "thigh": "thigh", "femur": "thigh",
    "leg": "shank", "lowerleg": "shank", "shank": "shank", "shin": "shank", "calf": "shank", "knee": "shank", "tibia": "shank",
    "arm": "upperarm", "upperarm": "upperarm", "humerus": "upperarm",
    "forearm": "lowerarm", "lowerarm": "lowerarm", "elbow": "lowerarm", "ulna": "lowerarm",
    "foot": "foot", "ankle": "foot", "hand": "hand", "wrist": "hand",
}
"""A sided joint's part (its name's words without the side, joined, lower case) -> segment part."""
UNSIDED: dict[str, str] = {"hips": "hip", "pelvis": "hip", "hip": "hip", "neck": "neck", "head": "head"}
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


def _named(path: Path, joints: Sequence[str], names: Mapping[str, str], layout: Layout | None) -> dict[str, str]:
    """Segment -> joint of ``names`` (JOINT -> SEGMENT); MotionFileError naming a joint the file
    lacks (with its joints) or a segment ``layout`` (None: ``paper10``) lacks (with its segments)."""
    from limbstream.body import PAPER10
    from limbstream.sources.names import check_segments

    unknown = [j for j in names if j not in joints]
    if unknown:
        raise MotionFileError.at(path, None, f"--names: no joint named {unknown[0]!r} (joints: {_listing(joints)})")
    try:
        check_segments(names, layout or PAPER10)
    except ValueError as exc:
        raise MotionFileError.at(path, None, str(exc)) from None
    return {seg: joint for joint, seg in names.items()}


def segment_map(path: Path, joints: Sequence[str], names: Mapping[str, str] | None) -> dict[str, str]:
    """Segment -> joint of a file's ``joints``, from ``names`` (JOINT -> SEGMENT, as ``--names``
    gives it) over the schemes' (the segments it does not name), or the schemes alone;
    MotionFileError naming the file's joints and how to map them (a scheme or mapping that leaves
    a segment without a joint names the segment)."""
    if names is not None:
        chosen = {**(pick_segment_map(joints) or by_parts(joints)), **_named(path, joints, names, None)}
        source = "--names and the joint names"
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


FULL_ONLY: tuple[str, ...] = ("chest", "head", "l_hand", "r_hand", "l_foot", "r_foot")
"""``full``'s segments that ``paper10`` does not have."""
_TIPS = ("l_hand", "r_hand", "l_foot", "r_foot")


def carrier(clip: BvhClip, joint: int) -> int:
    """The joint whose bone reaches the end of ``joint``'s bone (:func:`.bvh_rest.bone_end`): the
    end's parent, at ``joint``'s place (CMU's ``LeftFingerBase`` below ``LeftHand``), or ``joint``
    itself (no joint below it elsewhere)."""
    end = bone_end(clip, joint, zero_pose_positions(clip))
    return joint if end is None else int(clip.parents[end])


def tip(clip: BvhClip, joint: int) -> tuple[int, bool]:
    """The end of ``joint``'s chain (down its first children to the last joint) and whether it
    is that joint's End Site (one away from it) rather than the joint itself."""
    children: dict[int, list[int]] = {}
    for j, parent in enumerate(clip.parents):
        children.setdefault(int(parent), []).append(j)
    while children.get(joint):
        joint = children[joint][0]
    end = clip.end_offsets[joint]
    return joint, bool(np.all(np.isfinite(end)) and np.linalg.norm(end) > 1e-9)


def carriers(clip: BvhClip, segment_map: Mapping[str, str]) -> dict[str, str]:
    """Segment -> the joint whose rotation is its orientation: the joint carrying it, but for
    ``full``'s hands and feet the joint whose bone reaches their end (:func:`carrier`) and for its
    head the one whose bone reaches the top of the head (the tip of the neck's chain)."""
    index = {name: j for j, name in enumerate(clip.joints)}
    out = dict(segment_map)
    for s in _TIPS:
        if s in out:
            out[s] = clip.joints[carrier(clip, index[out[s]])]
    if "head" in out:
        last, site = tip(clip, index[out["head"]])
        out["head"] = clip.joints[last if site or last == index[out["head"]] else int(clip.parents[last])]
    return out


def chest_joint(clip: BvhClip, neck: int, hip: int) -> int | None:
    """The spine joint whose bone reaches the place of the ``neck`` joint (the first of its
    ancestors elsewhere, below the ``hip`` joint); None if the neck hangs off the pelvis."""
    at = zero_pose_positions(clip)
    j = int(clip.parents[neck])
    while j >= 0 and np.linalg.norm(at[j] - at[neck]) < 1e-9:
        j = int(clip.parents[j])
    return None if j < 0 or j == hip else j


def _full_parts(clip: BvhClip, base: Mapping[str, str]) -> dict[str, str]:
    """``full``'s further segments (:data:`FULL_ONLY`) -> the joint at their proximal end by the
    schemes (see the module), given the 10-segment map ``base``: the feet's and hands' joints,
    the neck's for the head (its base), the chest's; those found only."""
    joints = clip.joints
    scheme = next((parts for name, parts in CMU_FULL_PARTS.items()
                   if CMU_SEGMENT_MAPS[name]["hip"] == base.get("hip") and CMU_SEGMENT_MAPS[name]["neck"] == base.get("neck")
                   and set(parts.values()) <= set(joints)), None)
    found = dict(scheme) if scheme is not None else {s: j for s, j in by_parts(joints).items() if s in FULL_ONLY}
    index = {name: j for j, name in enumerate(joints)}
    neck = base.get("neck")
    if neck is None and found.get("head") in index and clip.parents[index[found["head"]]] >= 0:
        neck = joints[int(clip.parents[index[found["head"]]])]  # no neck joint: the head's parent
    if neck is None:
        found.pop("head", None)
        return found
    found["head"] = neck  # the head's bone: the neck's base to the top of the head
    if base.get("hip") in index:
        chest = chest_joint(clip, index[neck], index[base["hip"]])
        if chest is not None:
            found["chest"] = joints[chest]
    return found


def layout_map(clip: BvhClip, names: Mapping[str, str] | None, layout: Layout) -> dict[str, str]:
    """Segment -> joint of every segment of ``layout``, in its order: ``paper10``'s by
    :func:`segment_map`, ``full``'s further ones by :func:`_full_parts`, ``names`` (JOINT ->
    SEGMENT, any segment of ``layout``: a layout file's own too) over both; MotionFileError naming
    the segments without a joint and the file's joints, or a segment of ``names`` the layout lacks."""
    wanted = layout.segment_names
    if set(wanted) <= set(SEGMENTS):
        if names is not None:
            _named(clip.path, clip.joints, names, layout)
        return {s: j for s, j in segment_map(clip.path, clip.joints, names).items() if s in wanted}
    chosen = pick_segment_map(clip.joints) or by_parts(clip.joints)
    chosen = {**chosen, **_full_parts(clip, chosen)}
    source = "the joint names"
    if names is not None:
        chosen.update(_named(clip.path, clip.joints, names, layout))
        source = "--names and the joint names"
    missing = [s for s in wanted if s not in chosen]
    if missing:
        raise MotionFileError.at(clip.path, None, f"no joint for segment {', '.join(missing)} of layout {layout.name} "
                                                  f"(from {source}; joints: {_listing(clip.joints)}); map them with "
                                                  f"{FLAG}, or use --layout paper10")
    return {s: chosen[s] for s in wanted}
