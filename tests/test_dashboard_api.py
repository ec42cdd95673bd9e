"""Dashboard REST/WebSocket/SSE API against real Zenoh traffic (a router and client sessions
on loopback), with the app's lifespan on."""
from __future__ import annotations

import dataclasses
import json
import math
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient
from support.stack import wait_until
from support.dashboard import AUTH, TOKEN, Device, device_stats, joint_angles, make_client, pose_frame, publish_until
from starlette.websockets import WebSocketDisconnect

from limbstream import wire
from limbstream.services.dashboard.app import create_app
from limbstream.cli.dashboard import parse_http
from limbstream.services.dashboard.settings import DashboardSettings


# ----------------------------------------------------------------------------- REST


def test_health_docs_and_page(client):
    health = client.get("/health").json()
    assert health["status"] == "ok" and health["zenoh"] is True and health["control"] is True, health
    assert client.get("/docs").status_code == 200
    paths = client.get("/openapi.json").json()["paths"]
    for path in ("/api/devices", "/api/devices/{subject}/{segment}", "/api/devices/{subject}/{segment}/history",
                 "/api/devices/{subject}/{segment}/config", "/api/subjects", "/api/subjects/{subject}/pose",
                 "/api/aggregators", "/health", "/metrics"):
        assert path in paths, f"{path} missing from OpenAPI: {sorted(paths)}"
    page = client.get("/")
    assert page.status_code == 200 and "limbstream" in page.text and "uPlot.iife.min.js" in page.text
    assert client.get("/static/vendor/uPlot.iife.min.js").status_code == 200
    assert "WebSocket" in client.get("/static/app.js").text


def test_devices_carry_every_stats_field(client, pub):
    devices = [device_stats("apiA", "hip", icr=0.125, max_len=25),
               device_stats("apiA", "neck", online=False, aad_deg=float("nan"))]
    publish_until(client, lambda: pub.put(wire.stats_key("apiA"), wire.encode_stats("apiA", time.time(), devices)),
                  lambda: len([d for d in client.get("/api/devices").json() if d["subject"] == "apiA"]) == 2,
                  "two devices of apiA")
    listed = {d["device"]: d for d in client.get("/api/devices").json() if d["subject"] == "apiA"}
    hip = listed["apiA/hip"]
    for key in wire.STATS_FIELDS:
        assert key in hip, f"{key} missing from {hip}"
    assert hip["icr"] == 0.125 and hip["msgs_per_s"] == 5.0 and hip["online"] is True, hip
    assert hip["max_len"] == 25 and hip["stale"] is False and hip["subject"] == "apiA", hip
    neck = client.get("/api/devices/apiA/neck").json()
    assert neck["online"] is False and neck["aad_deg"] is None, neck
    subjects = {s["subject"]: s for s in client.get("/api/subjects").json()}
    assert subjects["apiA"]["devices"] == 2 and subjects["apiA"]["online"] == 1, subjects
    assert math.isclose(subjects["apiA"]["msgs_per_s"], 10.0), subjects


def test_one_subject_with_its_devices_and_the_filters(client, pub):
    """``GET /api/subjects/{s}``: the subject as listed, its devices and the segments it has none
    for; ``/api/devices?subject=`` filters; an unknown query parameter is refused (422 naming it),
    on REST and WebSocket alike, so a misspelt filter never answers as if it were not given."""
    def publish(subject: str, segments: tuple[str, ...]) -> None:
        payload = wire.encode_stats(subject, time.time(), [device_stats(subject, seg) for seg in segments])
        publish_until(client, lambda: pub.put(wire.stats_key(subject), payload),
                      lambda: any(s["subject"] == subject for s in client.get("/api/subjects").json()),
                      f"devices of {subject}")
    publish("apiS1", ("hip", "l_thigh"))
    publish("apiS2", ("neck",))
    one = client.get("/api/subjects/apiS1").json()
    listed = next(s for s in client.get("/api/subjects").json() if s["subject"] == "apiS1")
    assert {k: v for k, v in one.items() if k not in ("device_list", "missing_segments", "segments", "joints", "bones",
                                                      "stats_age_s")} == \
        {k: v for k, v in listed.items() if k != "stats_age_s"}, (one, listed)
    assert [d["device"] for d in one["device_list"]] == ["apiS1/hip", "apiS1/l_thigh"], one
    assert one["missing_segments"] == [s for s in wire.SEGMENTS if s not in ("hip", "l_thigh")], one
    assert client.get("/api/subjects/nosuch").status_code == 404
    assert [d["device"] for d in client.get("/api/devices", params={"subject": "apiS2"}).json()] == ["apiS2/neck"]
    assert client.get("/api/devices", params={"subject": "nosuch"}).json() == []
    assert client.get("/api/devices", params={"subject": "bad name"}).status_code == 422
    for url, params in (("/api/devices", {"subjects": "apiS1"}), ("/api/subjects/apiS1", {"x": "1"}),
                        ("/api/devices/apiS1/hip/history", {"second": "5"}), ("/health", {"verbose": "1"})):
        res = client.get(url, params=params)
        assert res.status_code == 422, (url, res.status_code, res.text)
        [error] = res.json()["detail"]
        assert error["loc"] == ["query", next(iter(params))] and "unknown query parameter" in error["msg"], error
    assert client.get("/api/devices/apiS1/hip/history", params={"seconds": "5"}).status_code == 200
    with pytest.raises(WebSocketDisconnect) as closed, client.websocket_connect("/ws/pose/apiS1?kinds=live") as ws:
        ws.receive_text()
    assert closed.value.code == 1008


def test_aggregators_report_their_loop_and_bad_entries_are_counted(client, pub):
    """Each stats message carries its aggregator's loop figures: the dashboard keeps the latest
    per aggregator, with the subjects it serves, and exports them; malformed entries are counted."""
    loop = {"ticks": 5000, "late": 25, "load": 0.38, "max_tick_ms": 45.0, "recent_max_tick_ms": 12.5,
            "recent_backlog": 300, "max_backlog": 700, "missed": 0, "points": 1234, "frames": 5678,
            "subjects": 2, "bad_keys": {"key": 3}}

    def publish():
        for subject, aid in (("aggA1", "hostA:1"), ("aggA2", "hostA:1"), ("aggB1", "hostB:2")):
            pub.put(wire.stats_key(subject), wire.encode_stats(subject, time.time(), [device_stats(subject, "hip")],
                                                               {"aggregator": loop | {"id": aid}}))

    def both():
        return {a["id"] for a in client.get("/api/aggregators").json()} >= {"hostA:1", "hostB:2"}

    publish_until(client, publish, both, "two aggregators")
    wait_until(lambda: client.get("/api/aggregators").json()[0]["serving"] == ["aggA1", "aggA2"], 5, "both subjects")
    views = {a["id"]: a for a in client.get("/api/aggregators").json()}
    a = views["hostA:1"]
    assert a["serving"] == ["aggA1", "aggA2"] and views["hostB:2"]["serving"] == ["aggB1"], views
    assert a["late_pct"] == 0.5 and a["load"] == 0.38 and a["recent_backlog"] == 300 and not a["stale"], a
    assert a["bad_keys"] == {"key": 3}, a
    text = client.get("/metrics").text
    assert 'limbstream_aggregator_late_ticks_total{aggregator="hostA:1"} 25.0' in text
    assert 'limbstream_aggregator_load{aggregator="hostB:2"} 0.38' in text
    assert 'limbstream_aggregator_bad_keys_total{aggregator="hostA:1",reason="key"} 3.0' in text

    def errors():
        return {line.split()[0]: float(line.split()[1]) for line in client.get("/metrics").text.splitlines()
                if line.startswith("limbstream_dashboard_errors_total")}

    def counted():
        e = errors()
        return sum(e.get(f'limbstream_dashboard_errors_total{{reason="{r}"}}', 0.0) for r in ("stats_aggregator", "json"))

    before = counted()
    bad_entries = ({"ticks": 1}, {"id": ""}, {"id": 7}, ["not", "a", "dict"], {"id": "x" * 500},
                   {"id": "hostC:3", "bad_keys": {"bogus": "x"}}, {"id": "hostC:3", "load": "high"})
    for bad in bad_entries:  # raw JSON: the encoder itself refuses most of these
        pub.put(wire.stats_key("aggA1"), json.dumps({"subject": "aggA1", "t": time.time(), "devices": [],
                                                     "aggregator": bad}).encode())
    wait_until(lambda: counted() >= before + len(bad_entries), 5, "every malformed aggregator entry counted")
    assert "hostC:3" not in {a["id"] for a in client.get("/api/aggregators").json()}
    assert {a["id"] for a in client.get("/api/aggregators").json()} >= {"hostA:1", "hostB:2"}


def test_unknown_and_malformed_ids(client):
    r = client.get("/api/devices/nobody/hip")
    assert r.status_code == 404 and "nobody/hip" in r.json()["detail"], r.text
    assert client.get("/api/devices/bad%20name/hip").status_code == 422
    assert client.get("/api/subjects/ghost/pose").status_code == 404
    assert client.get("/api/devices/ghost/hip/history").status_code == 404


def test_history_is_bounded_and_windowed(router, pub):
    with make_client(router, history_seconds=10) as c:
        wait_until(lambda: c.get("/health").status_code == 200, 10, "zenoh session")
        t0 = time.time()
        publish_until(c, lambda: pub.put(wire.stats_key("histB"), wire.encode_stats("histB", t0, [device_stats("histB", "hip")])),
                      lambda: c.get("/api/devices/histB/hip").status_code == 200, "histB/hip")
        for i in range(1, 61):  # 60 s of stats at 1 Hz (stats time t drives the window)
            pub.put(wire.stats_key("histB"), wire.encode_stats("histB", t0 + i, [device_stats("histB", "hip", icr=i / 100)]))
        wait_until(lambda: c.get("/api/devices/histB/hip").json()["icr"] == 0.6, 10, "last stats applied")
        h = c.get("/api/devices/histB/hip/history", params={"seconds": 1000}).json()
        assert len(h["t"]) == 11 and h["t"][-1] == t0 + 60 and h["t"][0] == t0 + 50, h["t"]
        assert h["icr"][-1] == 0.6 and len(h["icr"]) == len(h["t"]), h["icr"]
        h5 = c.get("/api/devices/histB/hip/history", params={"seconds": 5}).json()
        assert h5["t"] == [t0 + k for k in range(55, 61)], h5["t"]
        assert c.get("/api/devices/histB/hip/history", params={"seconds": -1}).status_code == 422


def test_latest_pose_and_kinds(client, pub):
    exact, live = pose_frame(7), pose_frame(8, wire.KIND_LIVE)
    exact = dataclasses.replace(exact, flags=wire.FRAME_TPOSE)  # a T-pose subject's frame

    def publish():
        pub.put(wire.pose_key("poseC"), wire.encode_pose(exact))
        pub.put(wire.pose_key("poseC"), wire.encode_pose(live))

    publish_until(client, publish, lambda: client.get("/api/subjects/poseC/pose?kind=live").status_code == 200,
                  "poseC frames")
    got = client.get("/api/subjects/poseC/pose", params={"kind": "exact"}).json()
    expected = exact.to_json("poseC")
    assert got["seq"] == 7 and got["kind"] == "exact" and got["t"] == expected["t"], got
    assert got["rest_pose"] == expected["rest_pose"] == "tpose"  # the rest pose travels with the frame
    for joint, xyz in expected["joints"].items():
        assert np.allclose(got["joints"][joint], xyz, atol=1e-4), (joint, got["joints"][joint], xyz)
    assert client.get("/api/subjects/poseC/pose?kind=auto").json()["kind"] == "live"  # wire.auto_kind: live came
    assert client.get("/api/subjects/poseC/pose?kind=live").json()["seq"] == 8
    assert client.get("/api/subjects/poseC/pose?kind=live").json()["rest_pose"] == "standing"
    assert client.get("/api/subjects/poseC/pose?kind=sideways").status_code == 422
    skeleton = client.get("/api/skeleton").json()
    assert skeleton["joints"] == list(wire.JOINTS) and len(skeleton["bones"]) == len(wire.BONES)


def test_joint_angles_latest_history_and_their_calibration(client, pub):
    """GET /api/subjects/{s}/joints: the newest message and the last seconds of the angles asked
    for, column-wise (null where an angle has no number); a subject without angles is told why;
    bad queries are refused (422), bad payloads counted."""
    live = lambda seq: wire.encode_angles(joint_angles(seq, knee=float(seq)))  # noqa: E731
    publish_until(client, lambda: pub.put(wire.angles_key("angF"), live(0)),
                  lambda: client.get("/api/subjects/angF/joints").status_code == 200, "angF joint angles")
    for seq in range(100, 120):
        pub.put(wire.angles_key("angF"), live(seq))
    pub.put(wire.angles_key("angF"), wire.encode_angles(joint_angles(7, wire.KIND_EXACT)))
    wait_until(lambda: client.get("/api/subjects/angF/joints").json()["latest"]["seq"] == 119, 10, "the burst")
    got = client.get("/api/subjects/angF/joints").json()
    assert got["kind"] == "live" and got["names"] == list(wire.JOINT_ANGLES)
    assert got["angles"]["knee_angle_r"][-20:] == list(range(100, 120)) and got["seq"][-20:] == list(range(100, 120))
    assert set(got["angles"]["elbow_flex_l"]) == {None} and len(got["t"]) == len(got["seq"])
    latest = got["latest"]
    assert (latest["calibration"], latest["valid"], latest["why"]) == ("segments", True, None)
    assert latest["flags"] == {"elbow_flex_l": ["missing"]} and latest["angles"]["elbow_flex_l"] is None
    some = client.get("/api/subjects/angF/joints", params=[("angle", "knee_angle_l"), ("angle", "hip_flexion_r"),
                                                            ("seconds", "0.5")]).json()
    assert some["names"] == ["hip_flexion_r", "knee_angle_l"] and set(some["angles"]) == set(some["names"])
    assert client.get("/api/subjects/angF/joints", params={"kind": "exact"}).json()["latest"]["seq"] == 7
    for bad in ({"angle": "knee"}, {"seconds": 0}, {"seconds": 1e6}, {"kind": "sideways"}, {"joint": "knee_angle_r"}):
        assert client.get("/api/subjects/angF/joints", params=bad).status_code == 422, bad
    assert client.get("/api/subjects/nobodyF/joints").status_code == 404
    publish_until(client, lambda: pub.put(wire.angles_key("angG"), wire.encode_angles(joint_angles(1, basis="unknown"))),
                  lambda: client.get("/api/subjects/angG/joints").status_code == 200, "angG joint angles")
    told = client.get("/api/subjects/angG/joints").json()["latest"]
    assert not told["valid"] and told["why"] == wire.ANGLE_BASES[wire.BASIS["unknown"]].meaning
    assert set(told["angles"].values()) == {None} and all("uncalibrated" in f for f in told["flags"].values())
    assert len(told["flags"]) == len(wire.JOINT_ANGLES)
    publish_until(client, lambda: pub.put(wire.angles_key("angF"), b"\x01" * 115),
                  lambda: 'reason="angles_version"' in client.get("/metrics").text, "a bad message counted")


def test_bad_payloads_are_counted_not_fatal(client, pub):
    def publish():
        pub.put(wire.pose_key("junkD"), b"\x01\x02\x03")
        pub.put(wire.stats_key("junkD"), b"{not json")
    # the two keys' messages come on two subscriptions: wait for both counts
    publish_until(client, publish, lambda: 'reason="pose_size"' in (text := client.get("/metrics").text)
                  and 'reason="json"' in text, "pose and stats error counts")
    text = client.get("/metrics").text
    assert 'limbstream_dashboard_errors_total{reason="json"}' in text, text[-800:]
    assert client.get("/health").status_code == 200
    assert client.get("/api/subjects/junkD/pose").status_code == 404


def test_metrics_have_per_device_labels(client, pub):
    stats = [device_stats("metE", "l_shank", msgs_per_s=7.5, icr=0.2, gaps=3)]
    publish_until(client, lambda: pub.put(wire.stats_key("metE"), wire.encode_stats("metE", time.time(), stats)),
                  lambda: 'subject="metE"' in client.get("/metrics").text, "metE metrics")
    text = client.get("/metrics").text
    assert 'limbstream_device_messages_per_second{segment="l_shank",subject="metE"} 7.5' in text
    assert 'limbstream_device_icr{segment="l_shank",subject="metE"} 0.2' in text
    assert 'limbstream_device_gaps_total{segment="l_shank",subject="metE"} 3.0' in text
    assert 'limbstream_device_online{segment="l_shank",subject="metE"} 1.0' in text


def test_liveliness_marks_devices_alive(client, pub):
    token = pub.liveliness().declare_token(wire.alive_key("aliveF", "hip"))
    try:
        wait_until(lambda: client.get("/api/devices/aliveF/hip").status_code == 200
                   and client.get("/api/devices/aliveF/hip").json()["alive"], 10, "alive token seen")
        d = client.get("/api/devices/aliveF/hip").json()
        assert d["online"] is True and d["stale"] is True and d["icr"] is None, d
    finally:
        token.undeclare()
    wait_until(lambda: client.get("/api/devices/aliveF/hip").json()["alive"] is False, 10, "token gone")
    assert client.get("/api/devices/aliveF/hip").json()["online"] is False


# ----------------------------------------------------------------------------- control


def announce(client, pub, subject, segment):
    publish_until(client, lambda: pub.put(wire.stats_key(subject), wire.encode_stats(
        subject, time.time(), [device_stats(subject, segment)])),
        lambda: client.get(f"/api/devices/{subject}/{segment}").status_code == 200, f"{subject}/{segment}")


def test_config_is_forwarded_and_confirmed(client, pub):
    device = Device(pub, "ctlG", "hip")
    try:
        announce(client, pub, "ctlG", "hip")
        r = client.put("/api/devices/ctlG/hip/config", json={"threshold": 0.05, "max_len": 10}, headers=AUTH)
        assert r.status_code == 200, r.text
        assert r.json() == {"device": "x/hip", "threshold": 0.05, "max_len": 10, "live_bound_deg": 0.0, "stream": 7,
                            "samples": 10, "points": 1}
        assert device.config == wire.DeviceConfig(0.05, 10)
        r = client.put("/api/devices/ctlG/hip/config", json={"threshold": 0.002}, headers=AUTH)
        assert r.status_code == 200 and r.json()["max_len"] == 10 and r.json()["threshold"] == 0.002, r.text
    finally:
        device.queryable.undeclare()


def test_config_validation_messages(client, pub):
    announce(client, pub, "ctlH", "hip")
    cases = [({"threshold": -1}, "threshold"), ({"max_len": 0}, "max_len"), ({}, "give some of threshold, max_len"),
             ({"threshold": 0.1, "colour": 1}, "colour"), ({"max_len": 1.5}, "max_len")]
    for body, needle in cases:
        r = client.put("/api/devices/ctlH/hip/config", json=body, headers=AUTH)
        assert r.status_code == 422 and needle in r.text, (body, r.status_code, r.text)
    r = client.put("/api/devices/ctlH/hip/config", content=b"not json", headers=AUTH | {"Content-Type": "application/json"})
    assert r.status_code == 422, r.text


def test_config_rejected_or_unanswered(client, pub):
    device = Device(pub, "ctlI", "hip", reject="max_len beyond the device buffer")
    try:
        announce(client, pub, "ctlI", "hip")
        r = client.put("/api/devices/ctlI/hip/config", json={"threshold": 0.1, "max_len": 50}, headers=AUTH)
        assert r.status_code == 422 and "beyond the device buffer" in r.json()["detail"], r.text
    finally:
        device.queryable.undeclare()
    announce(client, pub, "ctlJ", "hip")  # stats but no device answering
    start = time.monotonic()
    r = client.put("/api/devices/ctlJ/hip/config", json={"threshold": 0.1, "max_len": 5}, headers=AUTH)
    assert r.status_code == 504 and "did not confirm" in r.json()["detail"], r.text
    assert time.monotonic() - start < 5, "timeout not honoured"
    r = client.put("/api/devices/nobody/hip/config", json={"threshold": 0.1}, headers=AUTH)
    assert r.status_code == 404, r.text


def test_auth_failures(client, router):
    body = {"threshold": 0.1}
    r = client.put("/api/devices/x/hip/config", json=body)
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", r.text
    r = client.put("/api/devices/x/hip/config", json=body, headers={"Authorization": "Bearer wrong"})
    assert r.status_code == 403 and "invalid token" in r.text, r.text
    r = client.put("/api/devices/x/hip/config", json=body, headers={"Authorization": f"Basic {TOKEN}"})
    assert r.status_code == 401, r.text
    settings = DashboardSettings(router=router, mode="production", api_token=None)
    assert settings.with_token() == (settings, False), "production must not invent a token"
    with TestClient(create_app(settings)) as prod:
        r = prod.put("/api/devices/x/hip/config", json=body, headers=AUTH)
        assert r.status_code == 403 and "LIMBSTREAM_API_TOKEN" in r.json()["detail"], r.text
        assert prod.get("/health").json()["control"] is False
    dev, generated = DashboardSettings(router=router, mode="development", api_token=None).with_token()
    assert generated and len(dev.api_token.get_secret_value()) >= 24


def test_settings_from_environment(monkeypatch):
    monkeypatch.setenv("LIMBSTREAM_API_TOKEN", "from-env")
    monkeypatch.setenv("LIMBSTREAM_MODE", "production")
    monkeypatch.setenv("LIMBSTREAM_ROUTER", "tcp/10.0.0.1:7447,tcp/10.0.0.2:7447")
    s = DashboardSettings()
    assert s.api_token.get_secret_value() == "from-env" and s.mode == "production"
    assert s.zenoh_settings().connect == ("tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447")
    assert "from-env" not in repr(s)
    assert parse_http("0.0.0.0:9000") == ("0.0.0.0", 9000) and parse_http(":80") == ("127.0.0.1", 80)
    with pytest.raises(Exception, match="HOST:PORT"):
        parse_http("localhost")
