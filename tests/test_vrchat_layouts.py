"""VRChat trackers of a ``full`` subject: its chest and feet have segments, so the chest tracker
turns with the chest (not the pelvis) and sits halfway up it, the foot trackers turn with the feet
(not the shanks); the toes stand on the floor; a real OSC receiver gets them at the same addresses."""
from __future__ import annotations

import numpy as np
import pytest
from support.osc import OscReceiver
from support.stack import wait_until
from test_vrchat import axis_angle, per_frame

from limbstream import wire
from limbstream.body import FULL, Body
from limbstream.services.outputs import vrchat

BODY = Body.from_height(FULL, 1.75)
NAMES = {t.name: k for k, t in enumerate(vrchat.FULL_TRACKERS)}
IDENTITY = np.tile([1.0, 0.0, 0.0, 0.0], (15, 1))


def frame_of(q: np.ndarray) -> wire.PoseFrame:
    q = np.asarray(q, np.float32)
    return wire.PoseFrame(0, 0, wire.KIND_LIVE, 0, q, BODY.positions(q), FULL)


def test_full_trackers_take_the_chest_and_feet_segments():
    assert [t.address for t in vrchat.trackers(FULL)] == [t.address for t in vrchat.TRACKERS]
    assert {t.name: t.segment for t in vrchat.trackers(FULL)} == {
        "hip": "hip", "chest": "chest", "left foot": "l_foot", "right foot": "r_foot", "left knee": "l_thigh",
        "right knee": "r_thigh", "left elbow": "l_upperarm", "right elbow": "r_upperarm", "head": "head"}
    q = IDENTITY.copy()
    q[FULL.segment_index["chest"]] = axis_angle("Y", 30.0)  # the chest turned left, the pelvis not
    q[FULL.segment_index["l_foot"]] = axis_angle("X", -20.0)  # the left foot's toes up (pitched about +X)
    positions, rotations = vrchat.tracker_values(frame_of(q))
    assert rotations[NAMES["hip"]] == pytest.approx([0.0, 0.0, 0.0], abs=1e-4)
    assert rotations[NAMES["chest"]] == pytest.approx([0.0, -30.0, 0.0], abs=1e-4)  # Unity: +y turns right
    assert rotations[NAMES["left foot"]] == pytest.approx([-20.0, 0.0, 0.0], abs=1e-4)  # mirror keeps x angles
    assert rotations[NAMES["right foot"]] == pytest.approx([0.0, 0.0, 0.0], abs=1e-4)

    positions, _ = vrchat.tracker_values(frame_of(IDENTITY))
    rest = BODY.positions(IDENTITY)
    at = lambda joint: rest[FULL.joint_index[joint]] * [-1.0, 1.0, 1.0] + [0.0, -rest[:, 1].min(), 0.0]  # noqa: E731
    assert rest[:, 1].min() == rest[FULL.joint_index["l_toe"], 1]  # the toes are the lowest: on the floor
    assert positions[NAMES["left foot"]] == pytest.approx(at("l_ankle"), abs=1e-6)
    assert positions[NAMES["left foot"], 1] == pytest.approx(0.039 * 1.75, abs=2e-3)  # Winter's ankle height
    assert positions[NAMES["chest"]] == pytest.approx((at("spine") + at("neck_base")) / 2, abs=1e-6)
    assert positions[NAMES["head"]] == pytest.approx(at("head_top"), abs=1e-6)
    assert positions[NAMES["head"], 1] == pytest.approx(1.75, abs=1e-4)  # the top of the head at its height
    assert positions[NAMES["left knee"]][0] < 0 < positions[NAMES["right knee"]][0]  # Unity's x to the right


def test_a_full_frame_is_sent_at_the_trackers_addresses():
    receiver = OscReceiver()
    sender = vrchat.VrchatSender("s01", ("127.0.0.1", receiver.port))
    q = IDENTITY.copy()
    q[FULL.segment_index["r_foot"]] = axis_angle("Y", 45.0)
    try:
        assert sender.send(frame_of(q))
        wait_until(lambda: len(receiver.snapshot()) >= len(vrchat.ADDRESSES), 10, "one frame's messages")
        (got,) = per_frame(receiver.snapshot())
    finally:
        sender.close()
        receiver.close()
    positions, rotations = vrchat.tracker_values(frame_of(q))
    assert list(got) == list(vrchat.ADDRESSES)
    assert got["/tracking/trackers/4/rotation"] == pytest.approx([0.0, -45.0, 0.0], abs=1e-4)
    for k, t in enumerate(vrchat.FULL_TRACKERS):
        assert got[f"/tracking/trackers/{t.address}/position"] == pytest.approx(positions[k], abs=1e-6)
        assert got[f"/tracking/trackers/{t.address}/rotation"] == pytest.approx(rotations[k], abs=1e-4)
