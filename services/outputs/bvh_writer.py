"""BVH export: the take's body in its layout's hierarchy (:func:`bvh_joints`: ``paper10``'s is
:data:`BVH_JOINTS`), joints named as in the CMU clips (so BVH tools and limbstream's own loader,
``limbstream.sources.bvh``, map them to segments), offsets in metres (Y up, X to the subject's left) drawing the take's rest pose (the arms hanging
for ``standing``, out along +-X for ``tpose``: the hierarchy's zero pose *is* the rest pose, so a
reader that takes its rest pose from the OFFSETs, as limbstream's does, reads the orientations
back unchanged), every joint's rotation channels in the order ``Zrotation Xrotation Yrotation``
(intrinsic, degrees) and the root's position channels first."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from limbstream import quat
from limbstream.body import PAPER10, Layout

if TYPE_CHECKING:
    from .export import Take


@dataclass(frozen=True)
class BvhJoint:
    """A BVH joint: its name, parent, the segment whose orientation it carries (None: it follows
    its parent), the pose-frame joint it sits at, the joint its End Site marks (if any) and, for
    a segment's bent bone (:class:`limbstream.body.Bend`), the segment it turns ``share`` of the
    way toward (it carries their SLERP)."""

    name: str
    parent: str | None
    segment: str | None
    at: str
    end: str | None = None
    toward: str | None = None
    share: float = 0.0


BVH_JOINTS: tuple[BvhJoint, ...] = (
    BvhJoint("Hips", None, "hip", "pelvis"),
    BvhJoint("LeftUpLeg", "Hips", "l_thigh", "l_hip"),
    BvhJoint("LeftLeg", "LeftUpLeg", "l_shank", "l_knee", end="l_ankle"),
    BvhJoint("RightUpLeg", "Hips", "r_thigh", "r_hip"),
    BvhJoint("RightLeg", "RightUpLeg", "r_shank", "r_knee", end="r_ankle"),
    BvhJoint("Spine", "Hips", None, "neck_base"),
    BvhJoint("Neck", "Spine", "neck", "neck_base", end="head"),
    BvhJoint("LeftArm", "Spine", "l_upperarm", "l_shoulder"),
    BvhJoint("LeftForeArm", "LeftArm", "l_lowerarm", "l_elbow", end="l_wrist"),
    BvhJoint("RightArm", "Spine", "r_upperarm", "r_shoulder"),
    BvhJoint("RightForeArm", "RightArm", "r_lowerarm", "r_elbow", end="r_wrist"),
)
"""The exported hierarchy, parents first (names of the CMU clips' joints: see
``limbstream.sources.bvh.CMU_SEGMENT_MAPS['cmu']``). Spine carries no sensor: it turns with the hips."""
ROTATION_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")

BVH_NAMES: dict[str, str] = {
    "hip": "Hips", "chest": "Spine", "neck": "Neck", "head": "Neck",
    "l_thigh": "LeftUpLeg", "l_shank": "LeftLeg", "l_foot": "LeftFoot",
    "r_thigh": "RightUpLeg", "r_shank": "RightLeg", "r_foot": "RightFoot",
    "l_upperarm": "LeftArm", "l_lowerarm": "LeftForeArm", "l_hand": "LeftHand",
    "r_upperarm": "RightArm", "r_lowerarm": "RightForeArm", "r_hand": "RightHand",
}
"""The BVH joint carrying each built-in segment (the CMU clips' names; ``full``'s head segment,
neck base to the top of the head, is the ``Neck`` joint as ``paper10``'s neck is); a layout file's
other segments keep their own names."""
BEND_NAMES: dict[str, str] = {"hip": "LowerBack"}
"""The BVH joint carrying a built-in segment's bent bone (the CMU clips' name for ``full``'s
lumbar spine); a layout file's other bent segments: their joint's name and ``Bend``."""


def bvh_joints(layout: Layout) -> tuple[BvhJoint, ...]:
    """The hierarchy of ``layout``, depth first (the file's order): ``paper10``'s :data:`BVH_JOINTS`; any other
    layout one joint per segment at its proximal joint, a child of its parent segment's joint
    (``full``: Hips -> LowerBack (its bent bone) -> Spine (the chest, at the spine joint) -> Neck (the head) with
    its End Site at the top of the head; the arms off the Spine, the hands below the forearms, the legs off the
    Hips, the feet below them), a segment without children ending in an End Site at its distal joint. A
    segment whose bone bends has a second joint at the same place carrying the bend (:data:`BEND_NAMES`): the
    segments starting at its distal joint hang off it, those at an offset off the segment's own."""
    if layout == PAPER10:
        return BVH_JOINTS
    name = {s.name: BVH_NAMES.get(s.name, s.name) for s in layout.segments}
    children: dict[str | None, list[str]] = {}
    for s in layout.segments:
        children.setdefault(s.parent, []).append(s.name)
    joints: list[BvhJoint] = []
    for seg in layout.segments:
        parent = None if seg.parent is None else layout.segment(seg.parent)
        hangs_off = None if parent is None else name[parent.name]
        if parent is not None and parent.bend is not None and seg.offset is None:
            hangs_off = BEND_NAMES.get(parent.name, f"{name[parent.name]}Bend")
        end = None if seg.name in children else seg.end
        joints.append(BvhJoint(name[seg.name], hangs_off, seg.name, seg.joint, end=None if seg.bend else end))
        if seg.bend is not None:
            joints.append(BvhJoint(BEND_NAMES.get(seg.name, f"{name[seg.name]}Bend"), name[seg.name], seg.name,
                                   seg.joint, end=end, toward=seg.bend.toward, share=seg.bend.share))
    under: dict[str | None, list[BvhJoint]] = {}
    for j in joints:
        under.setdefault(j.parent, []).append(j)
    out: list[BvhJoint] = []

    def visit(joint: BvhJoint) -> None:  # depth first: the order of the file's joints and channels
        out.append(joint)
        for child in under.get(joint.name, []):
            visit(child)

    visit(under[None][0])
    return tuple(out)


def _fmt(values) -> str:
    """Numbers with 6 decimals (no "-0.000000")."""
    return " ".join(f"{v:.6f}" for v in np.where(np.abs(values) < 5e-7, 0.0, values))


def bvh_text(take: Take) -> str:
    """The BVH file of ``take`` (see the module docstring)."""
    layout = take.layout
    hierarchy = bvh_joints(layout)
    rest = take.skeleton.positions(np.tile([1.0, 0.0, 0.0, 0.0], (len(layout.segments), 1))).astype(np.float64)
    at = {name: rest[i] for i, name in enumerate(layout.joints)}
    by_name = {j.name: j for j in hierarchy}
    children: dict[str | None, list[BvhJoint]] = {}
    for j in hierarchy:
        children.setdefault(j.parent, []).append(j)
    lines = ["HIERARCHY"]

    def write(joint: BvhJoint, depth: int) -> None:
        pad = "  " * depth
        parent_at = at[by_name[joint.parent].at] if joint.parent else at[joint.at]
        lines.append(f"{pad}{'ROOT' if joint.parent is None else 'JOINT'} {joint.name}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {_fmt(at[joint.at] - parent_at)}")
        position = "Xposition Yposition Zposition " if joint.parent is None else ""
        count = 6 if joint.parent is None else 3
        lines.append(f"{pad}  CHANNELS {count} {position}{' '.join(ROTATION_CHANNELS)}")
        for child in children.get(joint.name, []):
            write(child, depth + 1)
        if joint.end is not None:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {_fmt(at[joint.end] - at[joint.at])}",
                          f"{pad}  }}"])
        lines.append(f"{pad}}}")

    write(children[None][0], 0)
    floor = min(float(p[1]) for p in rest)  # the lowest joint at rest: the ankles (paper10), the toes (full)
    # root: the take's path where it has one (its floor at 0), else the feet on the floor at rest
    columns = [np.tile([0.0, -floor, 0.0], (len(take), 1)) if take.root is None else take.root]
    seg = layout.segment_index

    def carried(joint: BvhJoint | None) -> np.ndarray:
        """(F, 4) global orientation a joint carries (its segment's, or its parent's)."""
        if joint is None:
            return np.tile([1.0, 0.0, 0.0, 0.0], (len(take), 1))
        if joint.segment is None:
            return carried(by_name.get(joint.parent))
        if joint.toward is not None:
            return quat.slerp(take.q[:, seg[joint.segment]], take.q[:, seg[joint.toward]], joint.share)
        return take.q[:, seg[joint.segment]]

    for joint in hierarchy:
        local = quat.multiply(quat.conjugate(carried(by_name.get(joint.parent))), carried(joint))
        columns.append(quat.to_rotation(quat.normalize(local)).as_euler("ZXY", degrees=True))
    motion = np.concatenate(columns, axis=1)
    lines += ["MOTION", f"Frames: {len(take)}", f"Frame Time: {take.period_us / 1e6:.6f}"]
    lines += [_fmt(row) for row in motion]
    return "\n".join(lines) + "\n"
