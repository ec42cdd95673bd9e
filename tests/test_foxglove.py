"""Live Foxglove output: a real ``limbstream foxglove`` process between a real Zenoh router and a
WebSocket client in the test that speaks the Foxglove WebSocket protocol (subprotocol
foxglove.sdk.v1, the one foxglove-sdk serves), subscribes, and decodes the protobuf messages with
the schema the server advertises, as the Foxglove app does."""
from __future__ import annotations

import asyncio
import base64
import json
import struct
import threading

import jsonschema
import numpy as np
import pytest
import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from limbstream import wire, zconfig
from limbstream.body import PAPER10
from limbstream.cli import main
from limbstream.skeleton import Skeleton
from limbstream.sources import generator
from limbstream.services.outputs import foxglove as fox
from support.stack import free_port

SUBPROTOCOL = "foxglove.sdk.v1"
T0_US = 1_700_000_000_000_000


def decoder(channel: dict):
    """A message class for an advertised protobuf channel, built from its FileDescriptorSet."""
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


class Publisher:
    """Pose frames (live, 50 Hz of device time, sent as fast as 200 Hz) and stats of s01 on a
    thread; exact frames of other orientations and times in between (must not be shown), and
    undecodable messages first."""

    def __init__(self, endpoint: str):
        motion = generator.generate(4.0, seed=5, activities=[("walking", 2.0), ("arm_circles", 2.0)])
        self.q = motion.q.astype(np.float32)
        self.joints = Skeleton().positions(self.q)
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.pose = self.session.declare_publisher(wire.pose_key("s01"))
        self.stats = self.session.declare_publisher(wire.stats_key("s01"))
        self.sent: dict[int, int] = {}  # t_us -> motion row
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        devices = [{"device": f"s01/{s}", "segment": s, "subject": "s01", "icr": 0.1 + i / 100, "online": True}
                   for i, s in enumerate(wire.SEGMENTS)]
        self.pose.put(b"not a pose frame")  # undecodable: counted and dropped by the output
        self.stats.put(b'{"subject": "s01", "t": "soon", "devices": [{}]}')
        i = 0
        while not self.stop.wait(0.005):
            row = i % len(self.q)
            t_us = T0_US + 20_000 * i
            self.sent[t_us] = row
            self.pose.put(wire.encode_pose(wire.PoseFrame(i, t_us, wire.KIND_LIVE, 0, self.q[row], self.joints[row])))
            if i % 5 == 0:
                self.pose.put(wire.encode_pose(wire.PoseFrame(i, t_us + 7, wire.KIND_EXACT, 0,
                                                              self.q[(row + 50) % len(self.q)], self.joints[row])))
                self.stats.put(wire.encode_stats("s01", t_us / 1e6, devices, {"frames": i}, seq=i // 5))
            i += 1

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()
        self.session.close()


async def collect(port: int, topics: tuple[str, ...], count: int) -> dict[str, list]:
    """Subscribe to ``topics`` once advertised; ``count`` decoded messages of each."""
    got: dict[str, list] = {t: [] for t in topics}
    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL]) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        info = json.loads(await ws.recv())
        assert info["op"] == "serverInfo" and info["name"] == "limbstream"
        subscribed: dict[int, tuple[str, object]] = {}
        while any(len(v) < count for v in got.values()):
            msg = await asyncio.wait_for(ws.recv(), 20)
            if isinstance(msg, str):
                data = json.loads(msg)
                if data["op"] != "advertise":
                    continue
                subs = []
                for ch in data["channels"]:
                    if ch["topic"] in topics:
                        sid = len(subscribed) + 1
                        subscribed[sid] = (ch["topic"], decoder(ch) if ch["encoding"] == "protobuf" else None)
                        subs.append({"id": sid, "channelId": ch["id"]})
                if subs:
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                continue
            op, sid, log_time = struct.unpack_from("<BIQ", msg)
            assert op == 1  # messageData
            topic, cls = subscribed[sid]
            payload = msg[13:]
            value = cls.FromString(payload) if cls else json.loads(payload)
            got[topic].append((log_time, value))
    return got


def test_foxglove_serves_skeletons_and_stats(stack):
    stack.router()
    port = free_port()
    child = stack.start("foxglove", "foxglove", "--port", str(port), "--subjects", "s0*", "--connect", stack.endpoint)
    stack.wait_ready(child, lambda: any("serving ws://" in line for line in child.tail()), "foxglove to listen", 30)
    with Publisher(stack.endpoint) as pub:
        got = asyncio.run(collect(port, ("/s01/tf", "/s01/skeleton", "/s01/stats"), 5))
    q, joints, sent = pub.q, pub.joints, pub.sent  # the publisher thread has ended
    assert not child.last_line().lower().count("error"), child.tail()
    for log_time, msg in got["/s01/tf"]:
        t_us = log_time // 1000
        assert t_us in sent, f"tf at {t_us} is not a live frame published"
        row = sent[t_us]
        tf = {t.child_frame_id: t for t in msg.transforms}
        assert set(tf) == {"s01"} | {f"s01/{s}" for s in wire.SEGMENTS}
        root = tf["s01"]
        assert root.parent_frame_id == "world"
        assert [root.rotation.x, root.rotation.y, root.rotation.z, root.rotation.w] == [0.5] * 4
        assert root.timestamp.seconds * 1_000_000 + root.timestamp.nanos // 1000 == t_us
        for i, seg in enumerate(wire.SEGMENTS):
            t = tf[f"s01/{seg}"]
            assert t.parent_frame_id == "s01"
            r = t.rotation
            assert [r.w, r.x, r.y, r.z] == q[row, i].astype(np.float64).tolist()  # float32 carried exactly
            origin = wire.JOINTS.index(PAPER10.segment(seg).joint)
            assert [t.translation.x, t.translation.y, t.translation.z] == joints[row, origin].astype(np.float64).tolist()
    for log_time, msg in got["/s01/skeleton"]:
        (entity,) = msg.entities
        assert entity.id == "s01" and entity.frame_id == "s01"
        line = entity.lines[0]
        points = np.array([[p.x, p.y, p.z] for p in line.points])[list(line.indices)]  # indexed line list
        want = joints[sent[log_time // 1000]][[wire.JOINTS.index(j) for b in PAPER10.bones for j in (b.origin, b.joint)]]
        assert np.array_equal(points, want.astype(np.float64))
        assert len(entity.spheres) == len(wire.JOINTS)
    for _, msg in got["/s01/stats"]:
        assert set(msg["devices"]) == set(wire.SEGMENTS)
        assert msg["devices"]["l_shank"]["icr"] == pytest.approx(0.1)
        jsonschema.validate(msg, fox.stats_schema())


def test_stats_schema_follows_the_field_table():
    devices = [{"device": "s01/hip", "segment": "hip", "subject": "s01", "icr": 0.5}]
    msg = fox.stats_message(wire.decode_stats(wire.encode_stats("s01", 1.0, devices, {"frames": 3}, seq=2)))
    schema = fox.stats_schema()
    jsonschema.validate(msg, schema)
    assert set(schema["properties"]["devices"]["properties"]["hip"]["properties"]) == set(wire.STATS_FIELDS)
    from limbstream.body import FULL  # every built-in layout's segments are named (full's feet, hands, ...)
    assert set(schema["properties"]["devices"]["properties"]) == set(wire.SEGMENTS) | set(FULL.segment_names)
    msg["devices"]["hip"]["icr"] = "high"
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(msg, schema)


def test_port_in_use_is_a_one_line_error(capsys):
    taken = fox.FoxgloveOutput(port=0)
    try:
        code = main(["foxglove", "--port", str(taken.port)])
    finally:
        taken.close()
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and err.startswith(f"limbstream foxglove: error: --port {taken.port}"), err
    assert "in use" in err


@pytest.mark.parametrize("argv, flag", [(["--subjects", "s/1"], "--subjects s/1"), (["--port", "70000"], "--port")])
def test_bad_flags_are_one_line_errors(argv, flag, capsys):
    assert main(["foxglove", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"limbstream foxglove: error: {flag}"), err


def decoded(message):
    """A foxglove-sdk message as the app decodes it (protobuf, from the schema it carries)."""
    schema = message.get_schema()
    cls = decoder({"schema": base64.b64encode(schema.data).decode(), "schemaName": schema.name})
    return cls.FromString(message.encode())


def test_a_full_frame_is_drawn_with_its_layouts_segments_and_bones():
    """A ``full`` frame: a transform per segment of the 15 (the feet at the ankles, the hands at
    the wrists, the chest at the spine, the head at the neck base), a line per bone of its 19
    (the feet to the toes, the hands to the fingertips), a sphere per joint of its 20; its pelvis
    lifted to its hip's height at rest above the toes."""
    from limbstream.body import FULL, Body
    body = Body.from_height(FULL, 1.8)
    q = np.tile(np.float32([1, 0, 0, 0]), (15, 1))
    q[FULL.segment_index["l_foot"]] = [np.cos(0.2), np.sin(0.2), 0, 0]
    frame = wire.PoseFrame(4, T0_US, wire.KIND_LIVE, 0, q, body.positions(q), FULL)
    tf = {t.child_frame_id: t for t in decoded(fox.frame_transforms("s07", frame, 2)).transforms}
    assert set(tf) == {"s07"} | {f"s07/{s}" for s in FULL.segment_names} and len(tf) == 16
    at = {name: frame.joints[FULL.joint_index[joint]].astype(np.float64).tolist() for name, joint in (
        ("l_foot", "l_ankle"), ("r_hand", "r_wrist"), ("chest", "spine"), ("head", "neck_base"), ("hip", "pelvis"))}
    for seg, xyz in at.items():
        t = tf[f"s07/{seg}"]
        assert [t.translation.x, t.translation.y, t.translation.z] == xyz, seg
    r = tf["s07/l_foot"].rotation
    assert [r.w, r.x, r.y, r.z] == q[FULL.segment_index["l_foot"]].astype(np.float64).tolist()
    rest = body.positions(np.tile([1.0, 0, 0, 0], (15, 1)))
    lift = rest[FULL.joint_index["l_hip"], 1] - rest[FULL.joint_index["l_toe"], 1]  # the toes on the grid
    assert tf["s07"].translation.z == pytest.approx(lift, abs=1e-5) and tf["s07"].translation.y == -2.0
    assert fox.leg_m(frame) == pytest.approx(lift, abs=1e-5)

    (entity,) = decoded(fox.scene_update("s07", frame)).entities
    line = entity.lines[0]
    assert len(line.indices) == 2 * 19 and len(line.points) == 20 and len(entity.spheres) == 20
    pairs = [(FULL.joints[a], FULL.joints[b]) for a, b in zip(line.indices[::2], line.indices[1::2])]
    assert pairs == [(b.origin, b.joint) for b in FULL.bones]
    assert {("l_ankle", "l_toe"), ("r_ankle", "r_toe"), ("l_wrist", "l_fingertip"), ("r_wrist", "r_fingertip"),
            ("pelvis", "spine"), ("spine", "neck_base"), ("neck_base", "head_top")} <= set(pairs)
    paper = wire.PoseFrame(0, T0_US, wire.KIND_LIVE, 0, np.tile(np.float32([1, 0, 0, 0]), (10, 1)),
                           Skeleton().positions(np.tile([1.0, 0, 0, 0], (10, 1))))
    assert len(decoded(fox.scene_update("s08", paper)).entities[0].lines[0].indices) == 2 * len(wire.BONES)
    assert fox.leg_m(paper) == pytest.approx(Skeleton().thigh + Skeleton().shank, abs=1e-6)


def test_a_frame_with_a_root_stands_at_it_in_the_world():
    """A frame carrying a root: ``world -> <s>`` puts the pelvis at the root turned Z up (limbstream's
    Z, X, Y as world X, Y, Z; the floor at 0), beside its slot; the same body without a root (zeros,
    no contacts) keeps the lift by its legs; a root of zeros with a contact set is a root."""
    import dataclasses
    q = np.tile(np.float32([1, 0, 0, 0]), (10, 1))
    still = wire.PoseFrame(4, T0_US, wire.KIND_LIVE, 0, q, Skeleton().positions(q.astype(np.float64)))
    walked = dataclasses.replace(still, root=np.float32([0.4, 0.9, -1.2]), contacts=0b0011)
    placed = decoded(fox.frame_transforms("s07", walked, 2)).transforms[0]
    assert [placed.translation.x, placed.translation.y, placed.translation.z] == pytest.approx([-1.2, 0.4 - 2.0, 0.9])
    lifted = decoded(fox.frame_transforms("s07", still, 2)).transforms[0]
    assert [lifted.translation.x, lifted.translation.y, lifted.translation.z] == pytest.approx(
        [0.0, -2.0, fox.leg_m(still)])
    at_origin = decoded(fox.frame_transforms("s07", dataclasses.replace(still, contacts=0b0100), 0)).transforms[0]
    assert [at_origin.translation.x, at_origin.translation.y, at_origin.translation.z] == [0.0, 0.0, 0.0]
    pose = decoded(fox.placement(1, root=walked.root)).position
    assert [pose.x, pose.y, pose.z] == pytest.approx([-1.2, 0.4 - 1.0, 0.9])
