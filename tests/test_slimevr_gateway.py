"""The SlimeVR gateway: its protocol codec against packets written from the firmware's side
(limbstream.device_emulator.slimevr_tracker), and the gateway itself, in a thread with a real Zenoh session, serving
simulated trackers over real UDP sockets on loopback: handshake and keepalive answers, segments
from body positions and --assign, segment points, link figures in the device status, silent
trackers going offline and coming back as a new stream, and bad datagrams counted by reason
without disturbing the trackers that behave."""
from __future__ import annotations

import collections
import json
import math
import random
import socket
import struct
import time

import pytest

from limbstream import wire, zconfig
from limbstream.device.clocks import ClockSettings
from limbstream.services.gateway import slimevr_protocol as proto
from limbstream.services.gateway.slimevr import GatewaySettings, SlimeVRGateway
from limbstream.device_emulator.slimevr_tracker import Tracker, handshake_payload, rotation_payload, sensor_info_payload
from support.stack import wait_until
from support.slimevr import Running, header, stream, streaming


# ---------------------------------------------------------------- codec

def test_decode_what_the_firmware_sends():
    hs = proto.decode(header(3, 0) + handshake_payload(bytes([0xAA, 1, 2, 3, 4, 0xFF])))
    assert hs.messages == (proto.Handshake(4, 10, 2, 21, "0.6.0", "AA:01:02:03:04:FF"),)
    info = proto.decode(header(15, 7) + sensor_info_payload(1, 9)).messages[0]
    assert (info.sensor, info.status, info.position) == (1, 1, 9)
    assert proto.decode(header(15, 7) + sensor_info_payload(1, 0)).messages[0].position is None
    rot = proto.decode(header(17, 8) + rotation_payload(2, (0.0, 0.0, 0.0, 2.0))).messages[0]
    assert rot == proto.Rotation(2, (0.0, 0.0, 0.0, 1.0))  # normalised, (w, x, y, z)
    q15 = proto.decode(header(23, 9) + struct.pack(">B4h3h", 0, 0, 23170, 0, 23170, 0, 0, 0)).messages[0]
    assert q15.q == pytest.approx((math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0), abs=1e-4)
    bat = proto.decode(header(12, 10) + struct.pack(">ff", 3.9, 0.8)).messages[0]
    assert (bat.voltage, bat.level) == pytest.approx((3.9, 0.8))
    assert proto.decode(header(19, 11) + struct.pack(">Bb", 255, -61)).messages[0] == proto.Signal(-61)
    assert proto.decode(header(10, 0) + struct.pack(">i", -5)).messages[0] == proto.Pong(-5)
    assert proto.decode(header(0, 12)).messages[0] == proto.Other(0)
    correction = struct.pack(">BB4fB", 0, 2, 0, 0, 0, 1, 0)  # magnetometer correction: read, not used
    assert proto.decode(header(17, 13) + correction).messages[0] == proto.Other(17)


def test_decode_bundles():
    items = [(17, rotation_payload(0, (0, 0, 0, 1))), (17, rotation_payload(1, (0, 1, 0, 0))), (19, b"\xff\xc4")]
    wide = header(100, 5) + b"".join(struct.pack(">Hi", len(p) + 4, k) + p for k, p in items)
    compact = header(101, 6) + b"".join(bytes([len(p) + 1, k]) + p for k, p in items)
    for data, number in ((wide, 5), (compact, 6)):
        dg = proto.decode(data)
        assert dg.number == number
        assert [type(m).__name__ for m in dg.messages] == ["Rotation", "Rotation", "Signal"]
        assert dg.messages[1] == proto.Rotation(1, (0.0, 1.0, 0.0, 0.0))
        assert dg.messages[2] == proto.Signal(-60)


@pytest.mark.parametrize("data, reason", [
    (b"\x00\x00\x00", "truncated"),
    (header(17, 1) + b"\x00\x01\x00", "truncated"),
    (header(17, 1) + struct.pack(">BB4fB", 0, 1, 0, 0, 0, 0, 0), "bad_quaternion"),
    (header(17, 1) + struct.pack(">BB4fB", 0, 1, math.nan, 0, 0, 1, 0), "bad_quaternion"),
    (header(77, 1), "unknown_type"),
    (header(17, 1) + bytes(2000), "oversized"),
    (header(100, 1) + b"\x00", "bad_bundle"),
    (header(100, 1) + struct.pack(">H", 50) + bytes(10), "truncated"),
    (header(100, 1) + struct.pack(">Hi", 4, 100), "bad_bundle"),
    (header(101, 1) + bytes([2, 3, 0]), "bad_bundle"),
])
def test_bad_datagrams_have_a_reason(data, reason):
    with pytest.raises(proto.ProtocolError) as info:
        proto.decode(data)
    assert info.value.reason == reason


def test_random_bytes_never_escape_as_another_error():
    """Mutated bundles and random bytes: each decodes into known messages or is refused with one
    of the reasons; both happen, with every reason."""
    rng = random.Random(7)
    good = header(100, 3) + struct.pack(">Hi", 22, 17) + rotation_payload(0, (1, 0, 0, 0))
    messages = (proto.Handshake, proto.SensorInfo, proto.Rotation, proto.Battery, proto.Signal, proto.Pong, proto.Other)
    outcomes: collections.Counter = collections.Counter()
    for _ in range(3000):
        data = bytearray(good if rng.random() < 0.5 else bytes(rng.randrange(40)))
        for _ in range(rng.randrange(1, 6)):
            if data:
                data[rng.randrange(len(data))] = rng.randrange(256)
        data = bytes(data[:rng.randrange(len(data) + 1)] if rng.random() < 0.3 else data)
        try:
            dg = proto.decode(data)
        except proto.ProtocolError as exc:
            assert exc.reason in {"truncated", "oversized", "unknown_type", "bad_quaternion", "bad_bundle"}
            outcomes[exc.reason] += 1
        else:
            assert isinstance(dg.number, int), dg
            assert all(isinstance(m, messages) for m in dg.messages), dg
            outcomes["decoded"] += 1
    assert {"decoded", "truncated", "unknown_type", "bad_quaternion", "bad_bundle"} <= set(outcomes), outcomes


def test_server_answers_are_what_the_firmware_checks():
    answer = proto.handshake_answer()
    assert len(answer) == 64 and answer[0] == 3 and answer[1:13] == b"Hey OVR =D 5"
    assert proto.heartbeat()[3] == 1 and len(proto.heartbeat()) == 12
    assert proto.ping(42) == header(10, 0) + struct.pack(">i", 42)
    assert proto.sensor_info_answer(1, 1) == struct.pack(">iBB", 15, 1, 1)
    assert proto.feature_flags()[12:] == b"\x03"


# ---------------------------------------------------------------- the gateway


@pytest.fixture
def gateway(request):
    g = Running(reads=getattr(request, "param", "ticks"))
    yield g
    g.close()


@pytest.mark.parametrize("gateway", ["ticks", "between", "as they come"], indirect=True)
def test_trackers_become_devices(gateway):
    a = Tracker(gateway.address, bytes([2, 0, 0, 0, 0, 1]), {0: 7, 1: 13})   # left thigh, left lower arm
    b = Tracker(gateway.address, bytes([2, 0, 0, 0, 0, 2]), {0: 1})          # head: no segment
    try:
        for t in (a, b):
            t.connect()
        assert a.features == b"\x03"
        a.battery(3.8, 0.55)
        a.signal(-58)
        stream([a, b], {a.mac_text: [0, 1], b.mac_text: [0]}, 2.0)
        received = wait_until(lambda: (r := gateway.poll()) and {"s01/l_thigh", "s01/l_lowerarm"} <= set(r) and r,
                              10, "segment points of both sensors of tracker a")
        assert set(received) == {"s01/l_thigh", "s01/l_lowerarm"}  # the head sensor is not published
        points = received["s01/l_thigh"]
        assert [p.seq for p in points] == list(range(len(points)))
        assert points[0].omega is not None  # live mode: version 2 points
        assert all(abs(sum(v * v for v in p.q) - 1) < 1e-3 for p in points)
        # about 100 samples of a steady turn: fastSW sends far fewer points
        samples = gateway.status("s01/l_thigh")["samples"]
        assert samples >= 50 and len(points) < samples / 2
        status = gateway.status("s01/l_thigh")
        assert status["tracker"] == f"{a.mac_text}/0"
        assert status["battery_pct"] == pytest.approx(55.0)
        assert status["signal_dbm"] == -58
        assert status["link_loss"] == 0.0 and status["link_pps"] > 10
        decoded = wire.decode_status(json.dumps(status).encode())
        assert decoded.link is not None and decoded.link.tracker == f"{a.mac_text}/0"
        report = wait_until(lambda: gateway.report().get("unassigned"), 5, "the unassigned head sensor reported")
        assert report == {f"{b.mac_text}/0": "body position 1 has no segment in the layout"}
        assert gateway.alive() == {"s01/l_thigh", "s01/l_lowerarm"}
        assert a.heartbeats >= 1 and a.pings >= 1  # the keepalive reached the tracker, which answered
        tracker = gateway.report()["trackers"][a.mac_text]
        assert tracker["rtt_ms"] is not None and tracker["lost"] == 0
    finally:
        a.close()
        b.close()


def test_assign_overrides_and_config_is_tunable():
    g = Running(assign={("02:00:00:00:00:03", None): ("s07", "r_shank"), ("02:00:00:00:00:04", 1): ("s01", "hip")})
    a = Tracker(g.address, bytes([2, 0, 0, 0, 0, 3]), {0: 7})
    b = Tracker(g.address, bytes([2, 0, 0, 0, 0, 4]), {0: 0, 1: 0})
    try:
        with streaming([a, b], {a.mac_text: [0], b.mac_text: [0, 1]}, 6.0, q15=True):
            wait_until(lambda: {"s07/r_shank", "s01/hip"} <= set(g.poll()), 10, "points of the assigned devices")
            replies = list(g.session.get(wire.config_key("s07", "r_shank"), payload=wire.encode_config({"max_len": 5}),
                                         timeout=5.0))
            assert json.loads(replies[0].ok.payload.to_bytes())["max_len"] == 5
            bad = list(g.session.get(wire.config_key("s07", "r_shank"), payload=b'{"max_len": 0}', timeout=5.0))
            assert bad[0].err is not None and "max_len" in bad[0].err.payload.to_bytes().decode()
            assert g.status("s07/r_shank")["max_len"] == 5
            assert wait_until(lambda: g.report().get("unassigned"), 5, "sensor 0 of b listed") == {
                f"{b.mac_text}/0": "no body position and no --assign"}
    finally:
        a.close()
        b.close()
        g.close()


def test_a_silent_tracker_goes_offline_and_comes_back_as_a_new_stream(gateway):
    t = Tracker(gateway.address, bytes([2, 0, 0, 0, 0, 5]), {0: 10})
    try:
        t.connect()
        sensors = {t.mac_text: [0]}
        stream([t], sensors, 1.0)
        wait_until(lambda: gateway.poll().get("s01/r_shank"), 10, "points of the first stream")
        assert gateway.alive() == {"s01/r_shank"}
        # silent: the gateway ends the stream (FINAL) and drops the token
        wait_until(lambda: any(p.flags & wire.FLAG_FINAL for p in gateway.poll().get("s01/r_shank", [])), 10,
                   "the first stream's FINAL point")
        wait_until(lambda: not gateway.alive(), 10, "the liveliness token gone")
        first = gateway.poll()["s01/r_shank"][0].stream
        stream([t], sensors, 1.0)
        wait_until(lambda: any(p.stream != first for p in gateway.poll()["s01/r_shank"]), 10, "a new stream")
        second = [p for p in gateway.poll()["s01/r_shank"] if p.stream != first]
        assert second[0].seq == 0 and second[0].index == 0
        assert gateway.alive() == {"s01/r_shank"}
        device = wait_until(lambda: (d := gateway.report()["devices"]["s01/r_shank"]) and d["streams"] == 2 and d,
                            5, "two streams reported")
        assert device["online"]
    finally:
        t.close()


def test_bad_datagrams_are_counted_and_never_stop_the_others(gateway):
    with (Tracker(gateway.address, bytes([2, 0, 0, 0, 0, 6]), {0: 2}) as good,
          Tracker(gateway.address, bytes([2, 0, 0, 0, 0, 7]), {0: 6}) as bad,
          socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger):
        bad.connect()
        rng = random.Random(3)
        sent = {"truncated": 0, "oversized": 0, "unknown_type": 0, "bad_quaternion": 0, "out_of_order": 0,
                "no_handshake": 0}
        with streaming([good], {good.mac_text: [0]}):
            wait_until(lambda: gateway.poll().get("s01/neck"), 10, "points of the good tracker")
            before = len(gateway.poll()["s01/neck"])
            for _ in range(200):
                choice = rng.choice(sorted(sent))
                if choice == "truncated":
                    bad.send_raw(header(17, bad.number + 1)[: rng.randrange(12)])
                elif choice == "oversized":
                    bad.send_raw(bytes(rng.randrange(1473, 4000)))
                elif choice == "unknown_type":
                    bad.send(rng.choice([2, 5, 77, 99, 250, -1]), bytes(rng.randrange(8)))
                elif choice == "bad_quaternion":
                    bad.send(17, struct.pack(">BB4fB", 0, 1, 0, 0, 0, 0, 0))
                elif choice == "out_of_order":
                    bad.send(17, rotation_payload(0, (1, 0, 0, 0)), number=1)
                else:
                    stranger.sendto(header(17, 5) + rotation_payload(0, (1, 0, 0, 0)), gateway.address)
                sent[choice] += 1
                time.sleep(0.001)  # a burst, not a flood: the socket buffer keeps every datagram
            bad.send_raw(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64))))  # noise: some reason
            dropped = wait_until(lambda: (d := gateway.report().get("dropped", {})) and sum(d.values()) > sum(
                sent.values()) and d, 10, "every bad datagram counted",
                on_fail=lambda: f"sent {sent}, counted {gateway.report().get('dropped')}")
            # each one counted once, by its reason; the noise once, by some reason
            assert sum(dropped.values()) == sum(sent.values()) + 1, (sent, dropped)
            assert all(dropped.get(reason, 0) - n in (0, 1) for reason, n in sent.items()), (sent, dropped)
            # the good tracker kept streaming through it all
            wait_until(lambda: len(gateway.poll()["s01/neck"]) > before + 3, 10, "more points of the good tracker")
            assert gateway.status("s01/neck")["link_loss"] == 0.0
        assert gateway.thread.is_alive()


def test_packet_loss_is_counted_from_packet_numbers(gateway):
    t = Tracker(gateway.address, bytes([2, 0, 0, 0, 0, 8]), {0: 9})
    try:
        t.connect()
        for k in range(40):
            t.rotation(0, (1.0, 0.0, 0.0, 0.0))
            if k % 4 == 3:
                t.number += 1  # a packet lost on the way
            time.sleep(0.01)
        # 10 numbers skipped, the last one with nothing after it yet: 9 packets known lost
        def settled():
            tracker = gateway.report()["trackers"][t.mac_text]
            loss = gateway.status("s01/l_shank")["link_loss"]
            return tracker["lost"] == 9 and tracker["packets"] >= 40 and loss == pytest.approx(
                9 / (9 + tracker["packets"]), abs=1e-4)
        wait_until(settled, 10, "9 lost packets in the report and the loss fraction in the device status")
    finally:
        t.close()


def test_flags_of_the_command_are_checked():
    from limbstream.cli.gateway_slimevr import parse_address, parse_assign
    import argparse
    assert parse_address("127.0.0.1:7000") == ("127.0.0.1", 7000)
    assert parse_address("6969") == ("0.0.0.0", 6969)
    assert parse_assign("aa:bb:cc:dd:ee:ff/1=s02/hip") == (("AA:BB:CC:DD:EE:FF", 1), ("s02", "hip"))
    assert parse_assign("10.0.0.5:5000=neck") == (("10.0.0.5:5000", None), (None, "neck"))
    for bad in ("127.0.0.1:99999", "x:y"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_address(bad)
    for bad in ("aa:bb=knee", "=neck", "aa/300=neck", "aa=s 1/neck"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_assign(bad)


def test_a_tracker_whose_address_another_takes_goes_offline():
    """A handshake of a new tracker from a known tracker's address (a DHCP lease handed on, a
    port reused): the tracker there goes offline and its device can be fed by another sensor."""
    session = zconfig.open_session(zconfig.ZenohSettings(mode="peer", connect=()))
    with session, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        g = SlimeVRGateway(session, sock, GatewaySettings("s01", clock=ClockSettings(sync=False),
                                                           assign={("02:00:00:00:00:01", None): ("s01", "hip"),
                                                                   ("02:00:00:00:00:02", None): ("s01", "hip")}))
        g.declare()
        here, there = ("127.0.0.1", 9), ("127.0.0.2", 9)  # the discard port: answers go nowhere
        g.handle(header(3, 0) + handshake_payload(bytes([2, 0, 0, 0, 0, 1])), here, 0.0, 0.0)
        g.handle(header(17, 1) + rotation_payload(0, (1.0, 0.0, 0.0, 0.0)), here, 1.0, 0.0)
        assert g.host.by_id["s01/hip"].online and g.host.by_id["s01/hip"].source.tracker.name == "02:00:00:00:00:01"
        g.handle(header(3, 0) + handshake_payload(bytes([2, 0, 0, 0, 0, 2])), here, 2.0, 0.1)
        first = g.host.by_id["s01/hip"].source.tracker
        assert not first.online and not g.host.by_id["s01/hip"].online  # its stream ended
        g.handle(header(17, 1) + rotation_payload(0, (1.0, 0.0, 0.0, 0.0)), here, 3.0, 0.1)
        assert g.host.by_id["s01/hip"].source.tracker.name == "02:00:00:00:00:02" and g.host.by_id["s01/hip"].online
        g.handle(header(3, 0) + handshake_payload(bytes([2, 0, 0, 0, 0, 1])), there, 4.0, 0.2)  # back elsewhere
        assert {t.name: t.online for t in g.sessions.trackers.values()} == {"02:00:00:00:00:01": True,
                                                                   "02:00:00:00:00:02": True}
        g.undeclare()
