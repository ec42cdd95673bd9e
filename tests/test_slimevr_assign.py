"""Run-time assignment of a SlimeVR gateway's sensors on its queryable (``limbstream/@gateway/<name>``):
the gateway in a thread with a real Zenoh session and simulated trackers on real UDP sockets, as in
test_slimevr_gateway. A sensor without a segment is listed with the reason; assigned, its device
appears and publishes; moved, the old device's stream ends (FINAL, token gone) and the new device
starts a stream; a device fed by another sensor and bad payloads are refused with a sentence."""
from __future__ import annotations

import json

from support.slimevr import Running, stream, streaming

from limbstream import wire
from limbstream.device_emulator.slimevr_tracker import Tracker
from support.stack import wait_until


def ask(g: Running, payload: bytes | None = None) -> tuple[dict | None, str | None]:
    """(listing, None) or (None, error sentence) from the gateway's queryable."""
    [reply] = list(g.session.get(wire.gateway_key("slimevr"), payload=payload, timeout=5.0))
    if reply.ok is not None:
        return wire.decode_sensors(reply.ok.payload.to_bytes()), None
    return None, json.loads(reply.err.payload.to_bytes())["error"]


def assign(g: Running, tracker: str, sensor: int, segment: str | None, subject: str | None = None):
    return ask(g, wire.encode_assignment(wire.Assignment(tracker, sensor, subject, segment)))


def listed(listing: dict) -> dict[str, tuple]:
    return {f"{s['tracker']}/{s['sensor']}": (s["device"], s["why"]) for s in listing["sensors"]}


def finals(g: Running, device: str) -> list[wire.SegmentPoint]:
    return [p for p in g.poll().get(device, []) if p.flags & wire.FLAG_FINAL]


def test_sensors_are_listed_assigned_moved_and_refused():
    g = Running()
    a = Tracker(g.address, bytes([2, 0, 0, 0, 1, 1]), {0: 1, 1: 7})   # head (no segment), left thigh
    b = Tracker(g.address, bytes([2, 0, 0, 0, 1, 2]), {0: 13})        # left lower arm
    try:
        with streaming([a, b], {a.mac_text: [0, 1], b.mac_text: [0]}):
            wait_until(lambda: {"s01/l_thigh", "s01/l_lowerarm"} <= set(g.poll()), 10, "points of the placed sensors")
            listing, _ = ask(g)
            assert listing["gateway"] == "slimevr" and listing["subject"] == "s01"
            assert listed(listing) == {f"{a.mac_text}/0": (None, "body position 1 has no segment in the layout"),
                                       f"{a.mac_text}/1": ("s01/l_thigh", None),
                                       f"{b.mac_text}/0": ("s01/l_lowerarm", None)}
            assert all(s["online"] for s in listing["sensors"])

            # the unassigned head sensor, assigned: its device appears and publishes
            listing, error = assign(g, a.mac_text, 0, "hip")
            assert error is None and listed(listing)[f"{a.mac_text}/0"] == ("s01/hip", None)
            wait_until(lambda: len(g.poll().get("s01/hip", [])) >= 2, 10, "points of the assigned sensor")
            hip_stream = g.poll()["s01/hip"][0].stream
            assert g.poll()["s01/hip"][0].seq == 0
            wait_until(lambda: "s01/hip" in g.alive(), 5, "the new device's liveliness token")

            # a device fed by another sensor is refused, and nothing changes
            listing, error = assign(g, a.mac_text, 0, "l_lowerarm")
            assert listing is None and error == f"s01/l_lowerarm is fed by {b.mac_text}/0: unassign it first"
            assert listed(ask(g)[0])[f"{a.mac_text}/0"] == ("s01/hip", None)

            # moved to another subject's segment: the old stream ends, the new device starts its own
            listing, error = assign(g, a.mac_text, 0, "r_thigh", subject="s02")
            assert error is None and listed(listing)[f"{a.mac_text}/0"] == ("s02/r_thigh", None)
            wait_until(lambda: finals(g, "s01/hip"), 10, "the old device's FINAL point")
            wait_until(lambda: "s01/hip" not in g.alive(), 10, "the old device's token gone")
            assert {p.stream for p in g.poll()["s01/hip"]} == {hip_stream}
            new = wait_until(lambda: len(g.poll().get("s02/r_thigh", [])) >= 2 and g.poll()["s02/r_thigh"], 10,
                             "points of the moved sensor's new device")
            assert new[0].seq == 0 and new[0].index == 0 and not new[0].flags & wire.FLAG_FINAL
            assert "s02/r_thigh" in g.alive()
            assert g.status("s02/r_thigh")["device"] == "s02/r_thigh"  # a new subject's devices answer too
            # the old device takes no points after its FINAL one
            hip = g.poll()["s01/hip"]
            assert hip[-1].flags & wire.FLAG_FINAL

            # unassigned: its device's stream ends, the sensor is listed with the reason
            listing, error = assign(g, b.mac_text, 0, None)
            assert error is None and listed(listing)[f"{b.mac_text}/0"] == (None, "unassigned at run time")
            wait_until(lambda: finals(g, "s01/l_lowerarm"), 10, "the unassigned sensor's device's FINAL point")
            arm_stream = g.poll()["s01/l_lowerarm"][0].stream
            # now free, the segment can be fed by another sensor
            _, error = assign(g, a.mac_text, 0, "l_lowerarm")
            assert error is None
            wait_until(lambda: finals(g, "s02/r_thigh"), 10, "the FINAL point of the device it left")
            wait_until(lambda: any(p.stream != arm_stream for p in g.poll()["s01/l_lowerarm"])
                       and "s01/l_lowerarm" in g.alive(), 10, "a new stream on the freed device")
            report = wait_until(lambda: (r := g.report()) and r["devices"]["s01/l_lowerarm"]["streams"] == 2 and r, 5,
                                "the second stream reported")
            assert report["unassigned"] == {f"{b.mac_text}/0": "unassigned at run time"}
            assert report["devices"]["s01/l_thigh"]["online"] and report["devices"]["s01/l_thigh"]["streams"] == 1
    finally:
        a.close()
        b.close()
        g.close()


BAD = [
    (b"not json", "an assignment must be a JSON object"),
    (b"[1, 2]", "an assignment must be a JSON object {tracker, sensor, subject, segment}"),
    (b'{"tracker": "02:00:00:00:01:03", "sensor": 0, "segment": "tail"}', "segment must be one of l_shank, r_shank, "),
    (b'{"tracker": "02:00:00:00:01:03", "sensor": 300, "segment": "hip"}', "sensor must be an integer in 0..255"),
    (b'{"tracker": "02:00:00:00:01:03", "sensor": 0, "subject": "a b", "segment": "hip"}', "subject must be"),
    (b'{"tracker": "02:00:00:00:01:03", "sensor": 0, "segment": "hip", "extra": 1}', "unknown assignment field"),
    (b'{"tracker": "02:00:00:00:01:09", "sensor": 0, "segment": "hip"}',
     "no sensor 02:00:00:00:01:09/0 has reported to gateway slimevr"),
    (b'{"tracker": "02:00:00:00:01:03", "sensor": 4, "segment": "hip"}',
     "no sensor 02:00:00:00:01:03/4 has reported to gateway slimevr"),
]


def test_bad_assignments_get_a_sentence_and_change_nothing():
    g = Running()
    t = Tracker(g.address, bytes([2, 0, 0, 0, 1, 3]), {0: 0})
    try:
        t.connect()
        stream([t], {t.mac_text: [0]}, 0.1)
        wait_until(lambda: listed(ask(g)[0]), 10, "the tracker's sensor listed")
        for payload, error in BAD:
            listing, message = ask(g, payload)
            assert listing is None and error in message, (payload, message)
        assert listed(ask(g)[0]) == {f"{t.mac_text}/0": (None, "no body position and no --assign")}
        assert not g.poll()
    finally:
        t.close()
        g.close()


def test_a_full_gateway_refuses_a_new_device_and_keeps_the_old_one():
    g = Running(max_devices=1)
    t = Tracker(g.address, bytes([2, 0, 0, 0, 1, 4]), {0: 7})   # left thigh
    try:
        with streaming([t], {t.mac_text: [0]}):
            wait_until(lambda: g.poll().get("s01/l_thigh"), 10, "points of the placed sensor")
            listing, error = assign(g, t.mac_text, 0, "hip")
            assert listing is None and error == "gateway full (1 devices): no room for s01/hip"
            count = len(g.poll()["s01/l_thigh"])
            wait_until(lambda: len(g.poll()["s01/l_thigh"]) > count, 10, "more points of the kept device")
            assert not finals(g, "s01/l_thigh") and "s01/l_thigh" in g.alive()
            assert listed(ask(g)[0]) == {f"{t.mac_text}/0": ("s01/l_thigh", None)}
    finally:
        t.close()
        g.close()


def test_assignments_made_at_run_time_outlive_the_gateway(tmp_path):
    """With an assignments file, a restarted gateway feeds the devices the last one was told to at
    run time (over body positions), and keeps a sensor it was told to unassign unassigned."""
    kept = tmp_path / "assignments.json"
    for run in range(2):
        g = Running(assignments_file=str(kept))
        t = Tracker(g.address, bytes([2, 0, 0, 0, 1, 5]), {0: 1, 1: 7})   # head (no segment), left thigh
        try:
            with streaming([t], {t.mac_text: [0, 1]}):
                if run == 0:
                    wait_until(lambda g=g: "s01/l_thigh" in g.poll(), 10, "points of the placed sensor")
                    assert assign(g, t.mac_text, 0, "neck", subject="s03")[1] is None
                    assert assign(g, t.mac_text, 1, None)[1] is None
                    assert json.loads(kept.read_text()) == [
                        {"tracker": t.mac_text, "sensor": 0, "subject": "s03", "segment": "neck"},
                        {"tracker": t.mac_text, "sensor": 1, "subject": None, "segment": None}]
                else:  # the new gateway: as it was left
                    wait_until(lambda g=g: "s03/neck" in g.poll(), 10, "points of the kept assignment")
                    assert listed(ask(g)[0]) == {f"{t.mac_text}/0": ("s03/neck", None),
                                                 f"{t.mac_text}/1": (None, "unassigned at run time")}
                    assert "s01/l_thigh" not in g.poll()
        finally:
            t.close()
            g.close()


def test_a_full_set_is_placed_by_body_position_on_the_full_layout():
    """SlimeVR's positions of a full set (head, neck, upper chest, hip, legs, feet, arms, hands,
    shoulders) feed the full layout's segments without --assign; on paper10 the same set places
    only what paper10 has (the neck on its neck), and a position with no segment says so."""
    from limbstream.body import FULL, PAPER10
    from limbstream.services.gateway.slimevr_protocol import position_segment

    assert [position_segment(p, FULL.segment_names) for p in (1, 2, 3, 4, 5, 6, 11, 12, 17, 18, 19)] == [
        "head", "head", "chest", "chest", "hip", "hip", "l_foot", "r_foot", "l_hand", "r_hand", None]
    assert [position_segment(p, PAPER10.segment_names) for p in (1, 2, 3, 6, 11, 17)] == [
        None, "neck", None, "hip", None, None]
    assert position_segment(None, FULL.segment_names) is None and position_segment(24, FULL.segment_names) is None

    g = Running(layout=FULL)
    positions = {0: 1, 1: 3, 2: 6, 3: 11, 4: 12, 5: 17, 6: 18, 7: 19}  # head, upper chest, hip, feet, hands, shoulder
    a = Tracker(g.address, bytes([2, 0, 0, 0, 2, 1]), positions)
    try:
        with streaming([a], {a.mac_text: list(positions)}):
            placed = {"s01/head", "s01/chest", "s01/hip", "s01/l_foot", "s01/r_foot", "s01/l_hand", "s01/r_hand"}
            wait_until(lambda: placed <= set(g.poll()), 10, "points of every placed sensor")
            listing, _ = ask(g)
            assert listed(listing)[f"{a.mac_text}/7"] == (None, "body position 19 has no segment in the layout")
            assert set(g.poll()) == placed
    finally:
        a.close()
        g.close()


def test_the_gateway_command_takes_a_layout_and_announces_it():
    """``gateway slimevr --layout full``: sensors feed the full layout's segments and the devices
    announce its default body (so the aggregator knows the layout); with --height-m, a body of it
    that tall. full is the default; ``--layout paper10`` the paper's 10 segments, with its body."""
    import argparse

    from limbstream.body import FULL, PAPER10
    from limbstream.cli import gateway_slimevr

    def settings(*argv: str):
        parser = argparse.ArgumentParser()
        gateway_slimevr.add_arguments(parser)
        args = parser.parse_args(["--subject", "s01", *argv])
        gateway_slimevr.validate(args)
        return gateway_slimevr.settings_from_args(args)

    full = settings("--layout", "full")
    assert full.layout == FULL and full.segments == FULL.segment_names and full.body.layout == FULL
    tall = settings("--layout", "full", "--height-m", "1.9")
    assert tall.body.layout == FULL and tall.body.height_m == 1.9
    plain = settings()
    assert plain.layout == FULL and plain.segments == FULL.segment_names and plain.body.layout == FULL
    paper = settings("--layout", "paper10")
    assert paper.segments == PAPER10.segment_names and paper.body.layout == PAPER10
    assert settings("--height-m", "1.6").body.layout == FULL
