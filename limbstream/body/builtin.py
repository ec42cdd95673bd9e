"""The built-in layouts, ``paper10`` and ``full``, and the anthropometric table that sizes them.

Segment lengths as fractions of body height H: Winter, D. A., *Biomechanics and Motor Control of
Human Movement*, 4th ed., Wiley, 2009, ch. 4 "Anthropometry", Fig. 4.1 (after Drillis and
Contini, 1966). docs/body.md lists what each bone takes from it.
"""
from __future__ import annotations

import math
from types import MappingProxyType

from limbstream import wire
from limbstream.body.layout import Bend, Layout, Segment, offset, segment

WINTER_LENGTHS = MappingProxyType({
    "shoulder_width": 0.259, "hip_width": 0.191, "upper_arm": 0.186, "forearm": 0.146, "hand": 0.108,
    "thigh": 0.245, "shank": 0.246, "foot": 0.152, "foot_width": 0.055, "shoulder_to_head_top": 0.182,
    "head": 0.130,
})
"""Winter's Fig. 4.1: segment lengths, fractions of body height H."""

WINTER_HEIGHTS = MappingProxyType({
    "head_top": 1.0, "eye": 0.936, "chin": 0.870, "shoulder": 0.818, "chest": 0.720, "elbow": 0.630,
    "hip": 0.530, "wrist": 0.485, "fingertip": 0.377, "knee": 0.285, "ankle": 0.039,
})
"""Winter's Fig. 4.1: heights of landmarks above the floor standing, fractions of body height H
(the hip: the greater trochanter, taken as the hip joint; the shoulder: the acromion)."""

DEFAULT_HEIGHT_M = 1.75
"""The default adult's height, m (``paper10``'s default body is of about this height)."""

HIP_JOINT_OFFSET = WINTER_LENGTHS["hip_width"] / 4
"""Each hip joint's distance from the pelvis' middle as a fraction of H: Winter's hip width is
the breadth across the greater trochanters; the hip joint centres, inside them, are taken half
that breadth apart (0.167 m at 1.75 m; paper10's default: 0.2 m)."""

UP, DOWN = (0.0, 1.0, 0.0), (0.0, -1.0, 0.0)
SIDES = (("l", 1.0), ("r", -1.0))  # +X is the subject's left


def _arm(side: str, lateral: float) -> dict[str, tuple[float, float, float]]:
    """Arm bones hang down standing and point out to their side (+-X) in the T-pose."""
    return {"standing": DOWN, "tpose": (lateral, 0.0, 0.0)}


# paper10's shoulders sit 0.05 m below the neck base, 0.19 m out (limbstream.skeleton); sized by
# height, the lateral part is half Winter's shoulder width along the same direction
_DROP = 0.05 / 0.19


def _paper10() -> Layout:
    """The 10-segment body of the paper's evaluation: segments wire.SEGMENTS, joints wire.JOINTS,
    bones as :class:`limbstream.skeleton.Skeleton` draws them (no trunk sensor: the spine and the
    shoulders follow the hip segment)."""
    half_shoulder = WINTER_LENGTHS["shoulder_width"] / 2
    drop = half_shoulder * _DROP
    rows: dict[str, Segment] = {
        "hip": segment("hip", None, "pelvis", "neck_base", UP,
                       WINTER_HEIGHTS["shoulder"] - WINTER_HEIGHTS["hip"] + drop),
        "neck": segment("neck", "hip", "neck_base", "head", UP, WINTER_HEIGHTS["head_top"] - WINTER_HEIGHTS["shoulder"] - drop),
    }
    for s, lateral in SIDES:
        rows[f"{s}_thigh"] = segment(f"{s}_thigh", "hip", f"{s}_hip", f"{s}_knee", DOWN, WINTER_LENGTHS["thigh"],
                                     offset("pelvis", (lateral, 0.0, 0.0), HIP_JOINT_OFFSET))
        rows[f"{s}_shank"] = segment(f"{s}_shank", f"{s}_thigh", f"{s}_knee", f"{s}_ankle", DOWN, WINTER_LENGTHS["shank"])
        rows[f"{s}_upperarm"] = segment(
            f"{s}_upperarm", "hip", f"{s}_shoulder", f"{s}_elbow", _arm(s, lateral), WINTER_LENGTHS["upper_arm"],
            offset("neck_base", (lateral * 0.19, -0.05, 0.0), half_shoulder * math.hypot(1.0, _DROP)))
        rows[f"{s}_lowerarm"] = segment(f"{s}_lowerarm", f"{s}_upperarm", f"{s}_elbow", f"{s}_wrist", _arm(s, lateral),
                                        WINTER_LENGTHS["forearm"])
    return Layout("paper10", tuple(rows[name] for name in wire.SEGMENTS), wire.JOINTS)


LUMBAR_BEND = 0.5
"""How far ``full``'s pelvis bone, the lumbar spine from the pelvis to the chest's joint, turns
toward the chest (:class:`~limbstream.body.layout.Bend`): it bends over five vertebrae between the
two sensors, as Xsens MVN's lumbar segments are interpolated between its pelvis and sternum
sensors; halfway is the middle of that bend."""


def _full() -> Layout:
    """15 segments: pelvis (``hip``, as in paper10), chest, head; per side upper arm, lower arm,
    hand, thigh, shank, foot. 20 joints, the tips included (head top, fingertips, toes). The
    pelvis's bone bends toward the chest (:data:`LUMBAR_BEND`)."""
    h = WINTER_HEIGHTS
    toe_forward = math.sqrt(WINTER_LENGTHS["foot"] ** 2 - h["ankle"] ** 2)  # the toe tip on the floor
    rows = [segment("hip", None, "pelvis", "spine", UP, h["elbow"] - h["hip"],  # the waist at elbow height
                    bend=Bend("chest", LUMBAR_BEND)),
            segment("chest", "hip", "spine", "neck_base", UP, h["shoulder"] - h["elbow"]),
            segment("head", "chest", "neck_base", "head_top", UP, WINTER_LENGTHS["shoulder_to_head_top"])]
    for s, lateral in SIDES:
        rows += [segment(f"{s}_upperarm", "chest", f"{s}_shoulder", f"{s}_elbow", _arm(s, lateral),
                         WINTER_LENGTHS["upper_arm"],
                         offset("neck_base", (lateral, 0.0, 0.0), WINTER_LENGTHS["shoulder_width"] / 2)),
                 segment(f"{s}_lowerarm", f"{s}_upperarm", f"{s}_elbow", f"{s}_wrist", _arm(s, lateral),
                         WINTER_LENGTHS["forearm"]),
                 segment(f"{s}_hand", f"{s}_lowerarm", f"{s}_wrist", f"{s}_fingertip", _arm(s, lateral),
                         WINTER_LENGTHS["hand"])]
    for s, lateral in SIDES:
        rows += [segment(f"{s}_thigh", "hip", f"{s}_hip", f"{s}_knee", DOWN, WINTER_LENGTHS["thigh"],
                         offset("pelvis", (lateral, 0.0, 0.0), HIP_JOINT_OFFSET)),
                 segment(f"{s}_shank", f"{s}_thigh", f"{s}_knee", f"{s}_ankle", DOWN, WINTER_LENGTHS["shank"]),
                 segment(f"{s}_foot", f"{s}_shank", f"{s}_ankle", f"{s}_toe", (0.0, -h["ankle"], toe_forward),
                         WINTER_LENGTHS["foot"])]
    joints = ("pelvis", "spine", "neck_base", "head_top",
              *(f"{s}_{j}" for s, _ in SIDES for j in ("hip", "knee", "ankle", "toe")),
              *(f"{s}_{j}" for s, _ in SIDES for j in ("shoulder", "elbow", "wrist", "fingertip")))
    return Layout("full", tuple(rows), joints)


PAPER10 = _paper10()
FULL = _full()
LAYOUTS = MappingProxyType({layout.name: layout for layout in (PAPER10, FULL)})
"""The built-in layouts by name."""

PAPER10_BONES = MappingProxyType({
    "hip": 0.50, "neck": 0.22, "l_hip": 0.10, "r_hip": 0.10,
    "l_shoulder": (0.19, -0.05, 0.0), "r_shoulder": (-0.19, -0.05, 0.0),
    "l_thigh": 0.45, "r_thigh": 0.45, "l_shank": 0.43, "r_shank": 0.43,
    "l_upperarm": 0.30, "r_upperarm": 0.30, "l_lowerarm": 0.27, "r_lowerarm": 0.27,
})
"""``paper10``'s default body (:class:`limbstream.skeleton.Skeleton`'s defaults, an adult of about
1.75 m): bone lengths in m, the shoulder offsets as vectors (m, standing frame)."""


def builtin_layout(name: str) -> Layout:
    """The built-in layout called ``name``; ValueError naming the choices."""
    if name not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)} or a .toml/.json file, got {name!r}")
    return LAYOUTS[name]
