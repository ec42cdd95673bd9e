"""``limbstream watch --joints`` shows each frame with its own joint angles: the aggregator
publishes a frame's angles just before the frame, so a drain often holds the next frame's angles
but not yet that frame; the screen pairs by the frame (kind, seq, time), never by arrival."""
from __future__ import annotations

import numpy as np

from limbstream import wire
from limbstream.cli import watch
from limbstream.services.outputs.subscription import Item

T0 = 1_790_000_000_000_000


def frame_item(seq: int) -> Item:
    q = np.tile(np.float32([1, 0, 0, 0]), (len(wire.SEGMENTS), 1))
    frame = wire.PoseFrame(seq, T0 + 20_000 * seq, wire.KIND_LIVE, 0, q, np.zeros((len(wire.JOINTS), 3), np.float32))
    payload = wire.encode_pose(frame)
    return Item(wire.POSE, "s01", None, wire.decode_pose(payload), wire.pose_key("s01"), payload, 0)


def angles_item(seq: int) -> Item:
    n = len(wire.JOINT_ANGLES)
    angles = wire.JointAngles(seq, T0 + 20_000 * seq, wire.KIND_LIVE, wire.BASIS["segments"], float("nan"),
                              np.full(n, float(seq), np.float32), np.zeros(n, np.uint8))
    payload = wire.encode_angles(angles)
    return Item(wire.ANGLES, "s01", None, wire.decode_angles(payload), wire.angles_key("s01"), payload, 0)


def test_each_frame_is_shown_with_its_own_angles():
    newest = watch._Newest(wire.KIND_LIVE)
    # published order: angles 1, frame 1, angles 2, frame 2, ...; this drain stops between angles 2 and frame 2
    assert newest.take([angles_item(1), frame_item(1), angles_item(2)]).seq == 1
    frame, angles = newest.paired()
    assert (frame.seq, angles.seq) == (1, 1) and float(angles.angles[0]) == 1.0
    assert "1.0°" in watch.render_angles(angles) and "2.0°" not in watch.render_angles(angles)
    newest.take([frame_item(2), frame_item(3)])  # frame 3's angles not here yet: frame 2 is the newest paired
    frame, angles = newest.paired()
    assert (frame.seq, angles.seq) == (2, 2)
    newest.take([angles_item(3)])
    assert [x.seq for x in newest.paired()] == [3, 3]


def test_without_angles_the_newest_frame_is_shown_with_none():
    newest = watch._Newest(wire.KIND_LIVE)
    newest.take([frame_item(5), frame_item(6)])
    frame, angles = newest.paired()
    assert frame.seq == 6 and angles is None
    assert "none received yet" in watch.render_angles(angles)
