"""Each subject's body layout, taken from its devices (docs/protocol.md, "Body layouts in the
aggregator").

A subject's layout is the one its devices' status body names (``wire.encode_body``): the first
named is the subject's, and a device whose status names another is counted (``status_layout``) and
its body left out. Before any names one, it is the smallest built-in layout holding the segments
of its devices (:func:`limbstream.body.layout_for`), grown as devices appear (``paper10``, then
``full`` once a device of a segment only ``full`` has joins). A device whose segment the subject's
layout lacks is not placed: its points are counted (``segment_not_in_layout``) and dropped, the
rest of the subject streams.

The joints between a layout's segments, for the heading correction and the joint error, come from
:func:`joint_table`, the one place that says which they are.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from limbstream import wire
from limbstream.body import Body, Layout, layout_for
from limbstream.heading import joints

if TYPE_CHECKING:
    from limbstream.services.aggregator.devices import DeviceTable
    from limbstream.services.aggregator.frames import FrameBuilder
    from limbstream.services.aggregator.fusion import Subject
    from limbstream.services.aggregator.heading import HeadingStage
    from limbstream.services.aggregator.scoring import Scoring
    from limbstream.services.aggregator.track import DeviceTrack


def joint_table(layout: Layout) -> tuple[wire.Joint, ...]:
    """The joints of ``layout`` (``wire.joint_table``: paper10's ``wire.JOINT_TABLE``; ``full``'s
    with its ankles, lumbar spine, wrists, and the shoulders and the neck off its ``chest``)."""
    return wire.joint_table(layout.name if layout.name in wire.JOINT_TABLES else layout)


def joints_of(layout: Layout, segments: tuple[str, ...] | list[str] | None = None,
              rest_pose: str = wire.DEFAULT_REST_POSE) -> joints.Layout:
    """The joints of ``layout`` (:func:`joint_table`) indexed over the segment names ``segments``
    (default: the layout's own, in its order; e.g. the device table's columns)."""
    names = tuple(layout.segment_names if segments is None else segments)
    index = {name: i for i, name in enumerate(names)}
    table = [j for j in joint_table(layout) if j.parent in index and j.child in index]
    return joints.Layout(names, tuple(j.name for j in table), np.array([index[j.parent] for j in table], int),
                         np.array([index[j.child] for j in table], int),
                         np.array([joints.is_hinge(j) for j in table], bool), wire.check_rest_pose(rest_pose))


def grown(layout: Layout, announced: bool, segments, segment: str) -> Layout | None:
    """The layout of a subject of ``layout`` (``announced``: named by its devices' status) whose
    devices are on ``segments`` once a device on ``segment`` joins: its own if it has the segment;
    else, where none was announced, the smallest built-in layout holding them all; None if the
    device does not fit."""
    if segment in layout.segment_index:
        return layout
    if announced:
        return None
    try:
        return layout_for({*segments, segment})
    except ValueError:
        return None


def same_body(a: Body | None, b: Body) -> bool:
    """Whether ``a`` is ``b`` (the same layout, height and bones)."""
    return a is not None and a.layout == b.layout and a.height_m == b.height_m and all(
        np.array_equal(a.vectors[pose], b.vectors[pose]) for pose in b.vectors)


class SubjectLayouts:
    """Which layout each subject's frames are of, and which of its devices they take (the module
    docstring): kept in the device table (its columns, ``placed``), the frame builder (the layout
    and body each subject is drawn with), the heading stage and the scoring (their joints)."""

    def __init__(self, table: DeviceTable, frames: FrameBuilder, heading: HeadingStage, scoring: Scoring):
        self.table, self.frames, self.heading, self.scoring = table, frames, heading, scoring
        self._bodies: dict[tuple, Body] = {}  # every body announced, once per value: subjects of one body share it

    def set_layout(self, sub: Subject, layout: Layout) -> None:
        """The subject's frames are of ``layout`` from now on: its devices on its segments placed,
        the others not (their points dropped); a body of another layout is no longer drawn with."""
        sub.layout = layout
        cols = self.table.set_layout(sub.index, layout.segment_names, {s: t.slot for s, t in sub.tracks.items()})
        self.frames.set_layout(sub.index, layout, cols)
        self.heading.set_layout(sub.index, layout, cols)
        self.scoring.set_layout(sub.index, layout, self.table.columns)
        if sub.body is not None and sub.body.layout != layout:
            sub.body = None
            self.frames.set_body(sub.index, None)

    def add_device(self, sub: Subject, track: DeviceTrack) -> None:
        """A new device of ``sub`` (in its ``tracks``): placed if its segment fits (:func:`grown`)."""
        placed = [name for name, t in sub.tracks.items() if t is not track and self.table.placed[t.slot]]
        self.set_layout(sub, grown(sub.layout, sub.announced, placed, track.segment) or sub.layout)

    def set_body(self, sub: Subject, track: DeviceTrack, body: Body | None, refused: str | None = None) -> None:
        """The body a device of ``sub`` announces in its status (None: none; ``refused``: why a
        malformed one was dropped, counted on the device as ``status_body``): its subject's frames
        are of its layout and drawn with it from now on. The first layout announced is the
        subject's; a body of another is counted on the device as ``status_layout`` and left out. A
        status without a body leaves the subject's as it is."""
        if refused is not None:
            track.dropped["status_body"] += 1
        if body is None:
            return
        if sub.announced and body.layout != sub.layout:
            track.dropped["status_layout"] += 1
            return
        if not sub.announced:
            sub.announced = True
            self.set_layout(sub, body.layout)
        if not same_body(sub.body, body):  # (each device says it again every poll: the chain is built once per body)
            key = (body.layout.name, body.height_m, *(body.vectors[pose].tobytes() for pose in sorted(body.vectors)))
            sub.body = self._bodies.setdefault(key, body)
            self.frames.set_body(sub.index, sub.body)

    @staticmethod
    def fields(sub: Subject) -> dict:
        """A subject's layout and body in its stats: ``layout``; where its devices announce a body,
        ``height_m`` (null: not given) and ``bones_m`` (bone -> length, m)."""
        if sub.body is None:
            return {"layout": sub.layout.name}
        return {"layout": sub.layout.name, "height_m": sub.body.height_m, "bones_m": sub.body.lengths}
