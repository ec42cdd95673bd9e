"""A body layout as data: its segments (one device each), each segment's parent, the joint where
its bone starts and ends, and the bone's direction at rest; the joints and bones follow from it.

Frames: world Y up, X to the subject's left, Z forward (the subject faces +Z at rest). With every
segment orientation at identity the body stands in its rest pose (``wire.REST_POSES``); a
segment's bone then points along its rest direction in that pose (a unit vector of the segment's
own frame). A segment starts at its parent's proximal or distal joint, or at a joint *offset* from
one of them (hips off the pelvis, shoulders off the neck base): that offset is a bone of the
parent, named by the joint it places. See docs/body.md.
"""
from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

from limbstream import wire
from limbstream.kernel.reconstruct import MAX_JOINTS

Vec = tuple[float, float, float]


def unit(value: Any, what: str) -> Vec:
    """``value`` (3 finite numbers, not all zero) scaled to unit length; ValueError naming ``what``."""
    try:
        x, y, z = (float(c) for c in value)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: direction must be 3 numbers, got {value!r}") from None
    n = math.sqrt(x * x + y * y + z * z)
    if not math.isfinite(n) or n == 0.0:
        raise ValueError(f"{what}: direction must be finite and non-zero, got {[x, y, z]}")
    if abs(n - 1.0) <= 4 * sys.float_info.epsilon:  # unit already: kept as written (a layout's file round trips)
        return (x, y, z)
    return (x / n, y / n, z / n)


def rest_directions(value: Any, what: str) -> dict[str, Vec]:
    """A rest direction per rest pose from a 3-vector (the same in every rest pose) or a mapping
    ``{rest pose: 3-vector}`` (``standing`` required; a rest pose left out takes its direction)."""
    if not isinstance(value, Mapping):
        d = unit(value, what)
        return {pose: d for pose in wire.REST_POSES}
    for pose in value:
        if pose not in wire.REST_POSES:
            raise ValueError(f"{what}: rest pose must be one of {', '.join(wire.REST_POSES)}, got {pose!r}")
    if wire.DEFAULT_REST_POSE not in value:
        raise ValueError(f"{what}: direction needs its {wire.DEFAULT_REST_POSE!r} rest pose")
    base = unit(value[wire.DEFAULT_REST_POSE], what)
    return {pose: unit(value[pose], f"{what} ({pose})") if pose in value else base for pose in wire.REST_POSES}


def _fraction(value: float | None, what: str) -> float | None:
    if value is not None and not (isinstance(value, int | float) and 0 < value <= 1):
        raise ValueError(f"{what}: height fraction must be in (0, 1], got {value!r}")
    return None if value is None else float(value)


@dataclass(frozen=True)
class Offset:
    """Where a segment's proximal joint sits off its parent's bone: ``origin`` (the parent's
    proximal or distal joint) plus a bone of the parent along ``direction`` (unit, the parent's
    frame at rest, both rest poses). ``height_fraction``: its length as a fraction of body height
    (for :meth:`limbstream.body.Body.from_height`; None: not given)."""

    origin: str
    direction: Vec
    height_fraction: float | None = None


@dataclass(frozen=True)
class Bend:
    """A segment's bone that bends with a neighbour: it turns by the SLERP from its segment's
    orientation toward segment ``toward``'s (its parent or a child) by ``share`` in (0, 1), as a
    spine between two sensors bends over its vertebrae (the lumbar spine between pelvis and chest,
    the neck between chest and head): its far joint lies where that bend puts it."""

    toward: str
    share: float


@dataclass(frozen=True)
class Segment:
    """One segment, one device: its bone runs from ``joint`` (proximal) to ``end`` (distal) along
    ``directions[rest_pose]`` (unit, its own frame). ``parent``: the segment it hangs off (None:
    the root, whose ``joint`` is the origin). ``offset``: where ``joint`` sits when it is not a
    joint of the parent. ``height_fraction``: the bone's length as a fraction of body height.
    ``bend``: its bone bends with a neighbour (None: it turns with the segment alone)."""

    name: str
    parent: str | None
    joint: str
    end: str
    directions: Mapping[str, Vec]
    height_fraction: float | None = None
    offset: Offset | None = None
    bend: Bend | None = None


@dataclass(frozen=True)
class Bone:
    """A vector of the chain: it places ``joint`` at joint ``origin`` plus its rest vector turned
    by ``segment``'s orientation (the root joint is the origin of the body), or bent toward a
    neighbour's (``bend``: a segment's own bone only). A segment's own bone is named by the
    segment, an offset by the joint it places."""

    name: str
    joint: str
    origin: str
    segment: str
    directions: Mapping[str, Vec]
    height_fraction: float | None
    bend: Bend | None = None

    @property
    def turned_by(self) -> tuple[str, ...]:
        """The segments whose orientations turn this bone: its own, and the one it bends toward."""
        return (self.segment,) if self.bend is None else (self.segment, self.bend.toward)


@dataclass(frozen=True)
class Layout:
    """Segments in device order (a pose's orientations (..., S, 4) come in this order) and,
    derived from them, the bones (parents first) and the joints (``joints``: their order in
    positions (..., J, 3); None: the root joint, then each bone's joint in bone order).
    Invalid layouts raise ValueError naming the problem (``check``)."""

    name: str
    segments: tuple[Segment, ...]
    joints: tuple[str, ...] = ()
    bones: tuple[Bone, ...] = field(init=False)

    def __post_init__(self):
        object.__setattr__(self, "segments", tuple(self.segments))
        object.__setattr__(self, "bones", _bones(self.name, self.segments))
        placed = [self.root.joint, *(b.joint for b in self.bones)]
        if not self.joints:
            object.__setattr__(self, "joints", tuple(placed))
        else:
            object.__setattr__(self, "joints", tuple(self.joints))
            _check_order(self.name, self.joints, placed)
        if len(self.joints) > MAX_JOINTS:
            raise ValueError(f"layout {self.name}: {len(self.joints)} joints, at most {MAX_JOINTS}")

    def __hash__(self) -> int:  # equal layouts share these (their segments hold dicts)
        return self._hash

    @cached_property
    def _hash(self) -> int:  # (a frame builder looks layouts up per subject and frame: computed once)
        return hash((self.name, self.segment_names, self.joints))

    @cached_property
    def root(self) -> Segment:
        """The segment without a parent (its proximal joint is the origin)."""
        return next(s for s in self.segments if s.parent is None)

    @cached_property
    def segment_names(self) -> tuple[str, ...]:
        """(S,) segment names in device order."""
        return tuple(s.name for s in self.segments)

    @cached_property
    def segment_index(self) -> dict[str, int]:
        """Segment name -> its index in orientations (..., S, 4)."""
        return {s.name: i for i, s in enumerate(self.segments)}

    @cached_property
    def joint_index(self) -> dict[str, int]:
        """Joint name -> its index in positions (..., J, 3)."""
        return {j: i for i, j in enumerate(self.joints)}

    @cached_property
    def bone_names(self) -> tuple[str, ...]:
        """(B,) bone names, chain order (each segment's, then the offsets it branches off)."""
        return tuple(b.name for b in self.bones)

    def segment(self, name: str) -> Segment:
        """The segment called ``name``; ValueError if the layout has none."""
        for s in self.segments:
            if s.name == name:
                return s
        raise ValueError(f"layout {self.name} has no segment {name!r}")

    def part(self, name: str, segments: Sequence[str]) -> Layout:
        """A layout called ``name`` of these of its ``segments`` (in its order; a bend toward a segment
        left out is dropped): a lower body of ``full``, say. ValueError as any layout's."""
        keep = [s for s in self.segments if s.name in segments]
        names = {s.name for s in keep}
        keep = [s if s.bend is None or s.bend.toward in names else replace(s, bend=None) for s in keep]
        return Layout(name, tuple(keep))

    def to_dict(self) -> dict[str, Any]:
        """The layout as a file's table (:func:`limbstream.body.files.layout_from_dict` reads it back)."""
        def direction(d: Mapping[str, Vec]) -> Any:
            return list(d[wire.DEFAULT_REST_POSE]) if len(set(d.values())) == 1 else {p: list(v) for p, v in d.items()}
        rows = []
        for s in self.segments:
            row: dict[str, Any] = {"name": s.name, "joint": s.joint, "end": s.end, "direction": direction(s.directions)}
            if s.parent is not None:
                row["parent"] = s.parent
            if s.height_fraction is not None:
                row["height_fraction"] = s.height_fraction
            if s.offset is not None:
                row["offset"] = {"from": s.offset.origin, "direction": list(s.offset.direction)}
                if s.offset.height_fraction is not None:
                    row["offset"]["height_fraction"] = s.offset.height_fraction
            if s.bend is not None:
                row["bend"] = {"toward": s.bend.toward, "share": s.bend.share}
            rows.append(row)
        return {"name": self.name, "joints": list(self.joints), "segments": rows}


def _check_tree(name: str, segments: Sequence[Segment]) -> dict[str, Segment]:
    """Segments by name: unique names, known parents, no cycle, one root."""
    by_name: dict[str, Segment] = {}
    for s in segments:
        if s.name in by_name:
            raise ValueError(f"layout {name}: duplicate segment {s.name!r}")
        by_name[s.name] = s
    if not by_name:
        raise ValueError(f"layout {name}: no segments")
    for s in segments:
        if s.parent is not None and s.parent not in by_name:
            raise ValueError(f"layout {name}: segment {s.name!r} has a missing parent {s.parent!r}")
    for s in segments:
        path, at = [s.name], s
        while at.parent is not None:
            if at.parent in path:
                loop = path[path.index(at.parent):] + [at.parent]
                raise ValueError(f"layout {name}: cycle of parents {' -> '.join(loop)}")
            path.append(at.parent)
            at = by_name[at.parent]
    roots = [s.name for s in segments if s.parent is None]
    if len(roots) != 1:
        raise ValueError(f"layout {name}: one segment has no parent (the root), here {', '.join(roots)}")
    return by_name


def _bones(name: str, segments: Sequence[Segment]) -> tuple[Bone, ...]:
    """The chain's bones, parents first: per segment (breadth first from the root) the offset
    placing its proximal joint (a bone of its parent), then its own bone."""
    by_name = _check_tree(name, segments)
    children: dict[str | None, list[Segment]] = {}
    for s in segments:
        children.setdefault(s.parent, []).append(s)
    root = children[None][0]
    if root.offset is not None:
        raise ValueError(f"layout {name}: the root segment {root.name!r} takes no offset (its joint is the origin)")
    bones: list[Bone] = []
    placer: dict[str, str] = {root.joint: "the origin"}  # joint -> what places it
    queue = [root]
    while queue:
        s = queue.pop(0)
        if s.parent is not None:
            _place_start(name, s, by_name[s.parent], placer, bones)
        if s.end in placer:
            raise ValueError(f"layout {name}: joint {s.end!r} placed twice ({placer[s.end]} and segment {s.name!r})")
        placer[s.end] = f"segment {s.name!r}"
        _check_bend(name, s, children)
        bones.append(Bone(s.name, s.end, s.joint, s.name, s.directions, s.height_fraction, s.bend))
        queue += children.get(s.name, [])
    names = [b.name for b in bones]
    for b in bones:
        if names.count(b.name) > 1:
            raise ValueError(f"layout {name}: bone name {b.name!r} used twice (an offset is named by its joint)")
    return tuple(bones)


def _check_bend(name: str, s: Segment, children: Mapping[str | None, list[Segment]]) -> None:
    """A bend goes toward the segment's parent or a child, by a share in (0, 1); the segment's
    children start at its distal joint or off its proximal one (a joint off the bent bone's end
    would turn with neither: a BVH hierarchy cannot draw it)."""
    if s.bend is None:
        return
    neighbours = [*([s.parent] if s.parent else []), *(c.name for c in children.get(s.name, []))]
    if s.bend.toward not in neighbours:
        raise ValueError(f"layout {name}: segment {s.name!r} bends toward {s.bend.toward!r}, not its parent or "
                         f"a child ({', '.join(neighbours) or 'none'})")
    off_end = [c.name for c in children.get(s.name, []) if c.offset is not None and c.offset.origin == s.end]
    if off_end:
        raise ValueError(f"layout {name}: segment {s.name!r} bends, so no child may start off its distal joint "
                         f"{s.end!r}; {off_end[0]!r} does (start it at {s.end!r} or off {s.joint!r})")


def _place_start(name: str, s: Segment, parent: Segment, placer: dict[str, str], bones: list[Bone]) -> None:
    """Check where segment ``s`` starts on ``parent``, appending its offset bone if it has one."""
    ends = (parent.joint, parent.end)
    if s.offset is None:
        if s.joint not in ends:
            raise ValueError(f"layout {name}: segment {s.name!r} starts at unknown joint {s.joint!r} "
                             f"(not {' or '.join(ends)} of its parent {parent.name!r}; give it an offset)")
        return
    if s.offset.origin not in ends:
        raise ValueError(f"layout {name}: offset of segment {s.name!r} from unknown joint {s.offset.origin!r} "
                         f"(not {' or '.join(ends)} of its parent {parent.name!r})")
    if s.joint in placer:
        raise ValueError(f"layout {name}: joint {s.joint!r} placed twice ({placer[s.joint]} and the offset of {s.name!r})")
    placer[s.joint] = f"the offset of segment {s.name!r}"
    directions = {pose: s.offset.direction for pose in wire.REST_POSES}
    bones.append(Bone(s.joint, s.joint, s.offset.origin, parent.name, directions, s.offset.height_fraction))


def _check_order(name: str, order: Sequence[str], placed: Sequence[str]) -> None:
    """``order`` (a layout's joints) must name each placed joint once."""
    unknown = [j for j in order if j not in placed]
    if unknown:
        raise ValueError(f"layout {name}: unknown joint {unknown[0]!r} in its joints order")
    doubled = sorted({j for j in order if order.count(j) > 1})
    if doubled:
        raise ValueError(f"layout {name}: joint {doubled[0]!r} twice in its joints order")
    missing = [j for j in placed if j not in order]
    if missing:
        raise ValueError(f"layout {name}: joints order misses {', '.join(missing)}")


def segment(name: str, parent: str | None, joint: str, end: str, direction: Any, height_fraction: float | None = None,
            offset: Offset | None = None, bend: Bend | None = None) -> Segment:
    """A :class:`Segment` with its direction checked and made unit (a 3-vector or a mapping per
    rest pose, as :func:`rest_directions` takes)."""
    what = f"segment {name!r}"
    return Segment(name, parent, joint, end, rest_directions(direction, what), _fraction(height_fraction, what), offset,
                   bend)


def bend(toward: Any, share: Any, what: str = "bend") -> Bend:
    """A :class:`Bend` with its share checked: a number in (0, 1)."""
    if not isinstance(toward, str) or not toward:
        raise ValueError(f"{what}: 'toward' must be a segment's name, got {toward!r}")
    if isinstance(share, bool) or not isinstance(share, int | float) or not 0 < share < 1:
        raise ValueError(f"{what}: share must be in (0, 1), got {share!r}")
    return Bend(toward, float(share))


def offset(origin: str, direction: Any, height_fraction: float | None = None, what: str = "offset") -> Offset:
    """An :class:`Offset` with its direction checked and made unit."""
    return Offset(origin, unit(direction, what), _fraction(height_fraction, what))
