"""Live Foxglove output: pose frames and stats over the Foxglove WebSocket protocol (foxglove-sdk),
so the Foxglove app (``ws://127.0.0.1:8765``) shows skeletons in its 3-D panel and plots stats.

Topics, per subject ``<s>`` (created when its first message comes):

=================  ==========================  ==============================================
topic              schema                      content
=================  ==========================  ==============================================
``/<s>/tf``        ``foxglove.FrameTransforms``  ``world -> <s>`` and ``<s> -> <s>/<segment>``
                                               for each segment of the frame's layout
``/<s>/skeleton``  ``foxglove.SceneUpdate``      one entity ``<s>`` in frame ``<s>``: a line per
                                               bone of the frame's layout, a sphere per joint
``/<s>/stats``     JSON (JSON Schema from        the stats message with ``devices`` keyed by
                   :data:`wire.FIELDS`)          segment: plot ``/s01/stats.devices.l_thigh.icr``
=================  ==========================  ==============================================

Frames: the subject frame ``<s>`` is limbstream's (Y up, X to the subject's left, pelvis at the
origin); ``world -> <s>`` turns it Z up (Foxglove's and ROS's convention: limbstream's Z, X, Y
become world X, Y, Z) and places the pelvis at the frame's root (the body moving through the room,
the floor at 0, the grid's height) or, for a frame without a root (zeros, no contacts: not
tracked, recorded before), lifts it to its leg's height at rest (thigh + shank, and the foot's
drop where the layout has feet; the frames' own lengths: its subject's body) so the feet touch the
grid; the n-th subject seen (from 0) is :data:`SPACING_M` to the right of the one before (each
subject's root starts where its tracking began).
``<s>/<segment>`` sits at the joint where the segment starts (``l_thigh`` at ``l_hip``, ``l_foot``
at ``l_ankle``) and has
the pose frame's global segment orientation, unchanged. Frames shown: live ones first
(:mod:`limbstream.services.outputs.kinds`). Messages are built only for topics a client subscribed to.
"""
from __future__ import annotations

from functools import lru_cache

import foxglove
import numpy as np
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
from foxglove.messages import (Color, FrameTransform, FrameTransforms, LinePrimitive, LinePrimitiveLineType,
                               Point3, Pose, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, Timestamp,
                               Vector3)

from limbstream import wire
from limbstream.body import LAYOUTS, PAPER10, Layout
from limbstream.skeleton import Skeleton
from limbstream.services.outputs.kinds import LiveFirst
from limbstream.services.outputs.subscription import Item

SPACING_M = 1.0
"""Distance between neighbouring subjects in the world frame, metres."""
_Y_UP_TO_Z_UP = (0.5, 0.5, 0.5, 0.5)  # (x, y, z, w): 120 deg about (1, 1, 1); x -> y, y -> z, z -> x
_LEG_M = Skeleton().thigh + Skeleton().shank
_BONE_COLOR = Color(r=0.2, g=0.7, b=1.0, a=1.0)
_JOINT_COLOR = Color(r=1.0, g=0.6, b=0.1, a=1.0)
_JOINT_SIZE = Vector3(x=0.05, y=0.05, z=0.05)
_IDENTITY = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


@lru_cache(maxsize=16)
def drawing(layout: Layout) -> tuple[tuple[tuple[int, str, int], ...], tuple[int, ...]]:
    """How frames of ``layout`` are drawn: per segment (its index, name, the index of the joint
    its frame sits at: where it starts) and the line list of its bones (joint indices, two per
    bone: proximal, distal)."""
    j = layout.joint_index
    origins = tuple((i, s.name, j[s.joint]) for i, s in enumerate(layout.segments))
    return origins, tuple(j[name] for b in layout.bones for name in (b.origin, b.joint))


def _stamp(t_us: int) -> Timestamp:
    return Timestamp(t_us // 1_000_000, t_us % 1_000_000 * 1000)


def frame_transforms(subject: str, frame: wire.PoseFrame, slot: int = 0) -> FrameTransforms:
    """``world -> <subject>`` and ``<subject> -> <subject>/<segment>`` for every segment.

    Parameters
    ----------
    subject : key chunk, the frame id.
    frame : its pose frame (q (S, 4) scalar-first, joints (J, 3) m, of its layout).
    slot : the subject's place in the row (0, 1, ...), :data:`SPACING_M` apart.
    """
    stamp = _stamp(frame.t_us)
    translation, rotation = _placement(slot, leg_m(frame), frame.root if frame.has_root else None)
    out = [FrameTransform(timestamp=stamp, parent_frame_id="world", child_frame_id=subject,
                          translation=translation, rotation=rotation)]
    q, joints = frame.q.tolist(), frame.joints.tolist()
    for i, seg, j in drawing(frame.layout or PAPER10)[0]:
        (qw, qx, qy, qz), (px, py, pz) = q[i], joints[j]
        out.append(FrameTransform(timestamp=stamp, parent_frame_id=subject, child_frame_id=f"{subject}/{seg}",
                                  translation=Vector3(x=px, y=py, z=pz),
                                  rotation=Quaternion(x=qx, y=qy, z=qz, w=qw)))
    return FrameTransforms(transforms=out)


def leg_m(frame: wire.PoseFrame) -> float:
    """The height of the frame's left hip joint above the floor at rest, m: the leg's bones from
    the thigh down (thigh + shank, and a foot's drop), each bone's length (its subject's: the
    frames are drawn with its body) times how far down it points at rest; the height its pelvis
    is lifted to. A layout without ``l_thigh``: the default adult's thigh + shank."""
    layout = frame.layout or PAPER10
    if "l_thigh" not in layout.segment_index:
        return _LEG_M
    j, at = frame.joints.astype(np.float64), layout.joint_index
    height, segment = 0.0, layout.segment("l_thigh")
    while segment is not None:
        down = max(0.0, -segment.directions[wire.DEFAULT_REST_POSE][1])
        height += down * float(np.linalg.norm(j[at[segment.end]] - j[at[segment.joint]]))
        segment = next((s for s in layout.segments if s.parent == segment.name), None)
    return height


def _placement(slot: int, leg: float = _LEG_M, root: np.ndarray | None = None) -> tuple[Vector3, Quaternion]:
    x, y, z, w = _Y_UP_TO_Z_UP
    rx, ry, rz = (0.0, leg, 0.0) if root is None else (float(v) for v in root)
    return Vector3(x=rz, y=rx - SPACING_M * slot, z=ry), Quaternion(x=x, y=y, z=z, w=w)


def placement(slot: int, leg: float = _LEG_M, root: np.ndarray | None = None) -> Pose:
    """Where the body frame of the ``slot``-th subject (from 0) sits in ``world``: turned Z up, the
    pelvis at ``root`` ((3,) m, limbstream's axes, floor at 0: a frame's root) or, without one,
    lifted by its leg length (:func:`leg_m`; default the default adult's), :data:`SPACING_M` to the
    right of the one before."""
    position, orientation = _placement(slot, leg, root)
    return Pose(position=position, orientation=orientation)


def scene_update(subject: str, frame: wire.PoseFrame, placed: Pose | None = None) -> SceneUpdate:
    """The skeleton of ``frame`` as one entity ``subject``: a line list of its layout's bones
    between its joints (indexed: :func:`drawing`) and, live, a sphere per joint.

    Live (``placed`` None) the entity is in frame ``subject``, which ``/<s>/tf`` places. A
    recording has no transforms, so there (``placed``: :func:`placement`) the entity is in frame
    ``world`` with the lines at ``placed``, without spheres (each would need its own pose). The
    recorder writes one per exact frame: this builder is its cost per frame (docs/benchmarks.md).
    """
    joints = frame.joints.tolist()
    points = [Point3(x=x, y=y, z=z) for x, y, z in joints]
    lines = LinePrimitive(type=LinePrimitiveLineType.LineList, thickness=0.02, color=_BONE_COLOR,
                          points=points, indices=drawing(frame.layout or PAPER10)[1], **({} if placed is None else {"pose": placed}))
    if placed is None:
        spheres = [SpherePrimitive(pose=Pose(position=Vector3(x=x, y=y, z=z), orientation=_IDENTITY),
                                   size=_JOINT_SIZE, color=_JOINT_COLOR) for x, y, z in joints]
        entity = SceneEntity(timestamp=_stamp(frame.t_us), frame_id=subject, id=subject, frame_locked=True,
                             lines=[lines], spheres=spheres)
    else:
        entity = SceneEntity(timestamp=_stamp(frame.t_us), frame_id="world", id=subject, lines=[lines])
    return SceneUpdate(entities=[entity])


def stats_message(stats: dict) -> dict:
    """A decoded stats message with ``devices`` as {segment: entry} (plot paths by name)."""
    return {**stats, "devices": {d.get("segment") or d.get("device"): d for d in stats["devices"]}}


def stats_schema() -> dict:
    """JSON Schema of :func:`stats_message`, from the stats field table (every value may be null)."""
    kinds = {float: "number", int: "integer", bool: "boolean", str: "string", dict: "object"}

    def props(scope):
        return {f.name: {"type": [kinds[f.type], "null"],
                         "description": f.help + (f" ({f.unit})" if f.unit else "")} for f in scope}

    device = {"type": "object", "properties": props(wire.DEVICE_FIELDS)}
    return {"type": "object", "properties": {
        "subject": {"type": "string"}, "t": {"type": "number", "description": "send time (s, epoch)"},
        "seq": {"type": "integer", "description": "stats message counter of the subject"},
        **props(wire.SUBJECT_FIELDS),
        "devices": {"type": "object", "additionalProperties": device,
                    "properties": {s: device for lay in LAYOUTS.values() for s in lay.segment_names}},
        "aggregator": {"type": "object", "properties": props(wire.AGGREGATOR_FIELDS)},
    }}


class _Topics:
    """The three channels of one subject."""

    def __init__(self, subject: str, slot: int, context: foxglove.Context, schema: dict):
        self.slot = slot
        self.tf = FrameTransformsChannel(f"/{subject}/tf", context=context)
        self.skeleton = SceneUpdateChannel(f"/{subject}/skeleton", context=context)
        self.stats = foxglove.Channel(f"/{subject}/stats", schema=schema, context=context)


class FoxgloveOutput:
    """Publishes pose and stats items on a foxglove-sdk WebSocket server.

    Parameters
    ----------
    host, port : where the server listens (port 0: a free one, see :attr:`port`).
    name : server name shown in the app.

    Raises
    ------
    OSError if the server cannot listen there (port taken, bad host).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, name: str = "limbstream"):
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        except RuntimeError as exc:  # foxglove-sdk: "FoxgloveError: Failed to bind port: ..."
            raise OSError(str(exc).removeprefix("FoxgloveError: ")) from None
        self.port = self.server.port
        self.kinds = LiveFirst()
        self.topics: dict[str, _Topics] = {}
        self.schema = stats_schema()
        self.published = 0  # messages logged (to at least one subscribed client)

    def _topics(self, subject: str) -> _Topics:
        if (t := self.topics.get(subject)) is None:
            t = self.topics[subject] = _Topics(subject, len(self.topics), self.context, self.schema)
        return t

    def publish(self, item: Item) -> None:
        """Log one pose or stats item (pose frames of the kind :class:`LiveFirst` picks; log time:
        a pose frame's time, a stats message's receive time)."""
        topics = self._topics(item.subject)
        if item.kind == "pose":
            frame = item.value
            if not self.kinds.wanted(item.subject, frame):
                return
            log_time = frame.t_us * 1000
            if topics.tf.has_sinks():
                topics.tf.log(frame_transforms(item.subject, frame, topics.slot), log_time=log_time)
                self.published += 1
            if topics.skeleton.has_sinks():
                topics.skeleton.log(scene_update(item.subject, frame), log_time=log_time)
                self.published += 1
        elif item.kind == "stats" and topics.stats.has_sinks():
            topics.stats.log(stats_message(item.value), log_time=item.received_ns)
            self.published += 1

    def close(self) -> None:
        self.server.stop()
