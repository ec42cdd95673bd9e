"""Dashboard REST/WebSocket/SSE API against real Zenoh traffic (a router and client sessions
on loopback), with the app's lifespan on."""
from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import zenoh
from fastapi.testclient import TestClient
from stack import ROOT, free_port, wait_until
from starlette.websockets import WebSocketDisconnect

from limbstream import wire, zconfig
from limbstream.cli.watch import render, subscribe_pose
from limbstream.services.dashboard.app import create_app
from limbstream.cli.dashboard import parse_http
from limbstream.services.dashboard.settings import DashboardSettings
from limbstream.services.dashboard.state import LiveState

TOKEN = "test-token-123"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def router():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zconfig.open_session(zconfig.ZenohSettings(mode="router", connect=(), listen=(endpoint,)))
    yield endpoint
    session.close()


@pytest.fixture(scope="module")
def pub(router):
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(router,)))
    yield session
    session.close()


def make_client(router: str, **overrides) -> TestClient:
    settings = DashboardSettings(router=router, api_token=TOKEN, config_timeout_s=1.0, **overrides)
    return TestClient(create_app(settings))


@pytest.fixture
def client(router):
    with make_client(router) as c:
        wait_until(lambda: c.get("/health").status_code == 200, 10, "zenoh session")
        yield c


def device_stats(subject: str, segment: str, **values) -> dict:
    base = {k: None for k in wire.STATS_FIELDS}
    base.update(device=f"{subject}/{segment}", segment=segment, online=True, samples=500, points=50,
                icr=0.1, msgs_per_s=5.0, bytes_per_s=180.0, aad_deg=1.5, p99_deg=4.0, max_deg=6.0,
                live_err_deg=9.0, watermark_lag_s=0.4, gaps=0, dropped=0, threshold=0.01)
    base.update(values)
    return base


def publish_until(client: TestClient, publish, predicate, what: str, timeout: float = 10.0):
    """Publish repeatedly until ``predicate()`` holds (the subscriber may join late)."""
    def step():
        publish()
        return predicate()
    return wait_until(step, timeout, what, interval=0.05)


def pose_frame(seq: int, kind: int = wire.KIND_EXACT, seed: int = 0) -> wire.PoseFrame:
    rng = np.random.default_rng(seed + seq)
    q = rng.normal(size=(10, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    joints = rng.uniform(-1, 1, size=(len(wire.JOINTS), 3))
    return wire.PoseFrame(seq, 1_700_000_000_000_000 + seq * 20_000, kind, 0, q.astype(np.float32),
                          joints.astype(np.float32))


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
    assert {k: v for k, v in one.items() if k not in ("device_list", "missing_segments", "stats_age_s")} == \
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

    def publish():
        pub.put(wire.pose_key("poseC"), wire.encode_pose(exact))
        pub.put(wire.pose_key("poseC"), wire.encode_pose(live))

    publish_until(client, publish, lambda: client.get("/api/subjects/poseC/pose?kind=live").status_code == 200,
                  "poseC frames")
    got = client.get("/api/subjects/poseC/pose", params={"kind": "exact"}).json()
    expected = exact.to_json("poseC")
    assert got["seq"] == 7 and got["kind"] == "exact" and got["t"] == expected["t"], got
    for joint, xyz in expected["joints"].items():
        assert np.allclose(got["joints"][joint], xyz, atol=1e-4), (joint, got["joints"][joint], xyz)
    assert client.get("/api/subjects/poseC/pose?kind=auto").json()["kind"] == "live"  # wire.auto_kind: live came
    assert client.get("/api/subjects/poseC/pose?kind=live").json()["seq"] == 8
    assert client.get("/api/subjects/poseC/pose?kind=sideways").status_code == 422
    skeleton = client.get("/api/skeleton").json()
    assert skeleton["joints"] == list(wire.JOINTS) and len(skeleton["bones"]) == len(wire.BONES)


def test_bad_payloads_are_counted_not_fatal(client, pub):
    def publish():
        pub.put(wire.pose_key("junkD"), b"\x01\x02\x03")
        pub.put(wire.stats_key("junkD"), b"{not json")
    publish_until(client, publish, lambda: 'reason="pose_size"' in client.get("/metrics").text, "pose error count")
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


class Device:
    """A device's config queryable, as the contract describes it (the emulator implements the
    same in the end-to-end test)."""

    def __init__(self, session: zenoh.Session, subject: str, segment: str, reject: str | None = None):
        self.config = wire.DeviceConfig(0.01, 25)
        self.reject = reject
        self.queryable = session.declare_queryable(wire.config_key(subject, segment), self.on_query)

    def on_query(self, query: zenoh.Query) -> None:
        if query.payload is not None:
            if self.reject:
                query.reply_err(json.dumps({"error": self.reject}))
                return
            try:
                self.config = wire.decode_config(query.payload.to_bytes(), self.config)
            except wire.WireError as exc:
                query.reply_err(json.dumps({"error": str(exc)}))
                return
        query.reply(query.key_expr, wire.encode_status(wire.DeviceStatus("x/hip", self.config, 7, 10, 1)))


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


# ----------------------------------------------------------------------------- live streams


def test_websocket_streams_frames_in_order(client, pub):
    publish_until(client, lambda: pub.put(wire.pose_key("wsK"), wire.encode_pose(pose_frame(0))),
                  lambda: client.get("/api/subjects/wsK/pose").status_code == 200, "wsK first frame")
    with client.websocket_connect("/ws/pose/wsK") as ws:
        first = json.loads(ws.receive_text())  # the latest frame, sent on connect
        assert first["subject"] == "wsK" and first["seq"] == 0, first
        stop = threading.Event()

        def publish():
            seq = 1
            while not stop.is_set() and seq < 500:
                pub.put(wire.pose_key("wsK"), wire.encode_pose(pose_frame(seq)))
                seq += 1
                stop.wait(0.005)

        threading.Thread(target=publish, daemon=True).start()
        seqs = [json.loads(ws.receive_text())["seq"] for _ in range(20)]
        stop.set()
    assert seqs == sorted(seqs) and len(set(seqs)) == 20 and seqs[0] >= 1, seqs


def test_websocket_rejects_foreign_origin(client):
    with pytest.raises(WebSocketDisconnect) as info, \
            client.websocket_connect("/ws/pose/wsK", headers={"Origin": "http://evil.example"}) as ws:
        ws.receive_text()
    assert info.value.code == 1008, info.value
    with client.websocket_connect("/ws/pose/wsK", headers={"Origin": "http://testserver"}) as ws:
        assert ws is not None


def test_sse_streams_frames(client, pub):
    publish_until(client, lambda: pub.put(wire.pose_key("sseL"), wire.encode_pose(pose_frame(3))),
                  lambda: client.get("/api/subjects/sseL/pose").status_code == 200, "sseL frame")
    r = client.get("/sse/pose/sseL", params={"limit": 1})
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream"), r.headers
    events = [json.loads(line[6:]) for line in r.text.splitlines() if line.startswith("data: ")]
    assert [e["seq"] for e in events] == [3] and events[0]["subject"] == "sseL", r.text


def test_pose_streams_filter_by_kind(client, pub):
    """``?kind=live|exact`` on the WebSocket and SSE streams: only frames of that kind (the page
    draws live frames by default); an unknown kind is refused."""
    stop = threading.Event()

    def publish():  # exact and live frames interleaved, as an aggregator sends them
        seq = 0
        while not stop.is_set() and seq < 3000:
            pub.put(wire.pose_key("kindN"), wire.encode_pose(pose_frame(seq)))
            pub.put(wire.pose_key("kindN"), wire.encode_pose(pose_frame(seq, wire.KIND_LIVE)))
            seq += 1
            stop.wait(0.005)

    publisher = threading.Thread(target=publish, daemon=True)
    publisher.start()
    try:
        wait_until(lambda: client.get("/api/subjects/kindN/pose?kind=live").status_code == 200
                   and client.get("/api/subjects/kindN/pose?kind=exact").status_code == 200, 10, "both kinds")
        for kind in ("live", "exact"):
            with client.websocket_connect(f"/ws/pose/kindN?kind={kind}") as ws:
                frames = [json.loads(ws.receive_text()) for _ in range(20)]
            assert {f["kind"] for f in frames} == {kind}, [f["kind"] for f in frames]
            seqs = [f["seq"] for f in frames]
            assert seqs == sorted(seqs) and len(set(seqs)) == 20, seqs
            r = client.get("/sse/pose/kindN", params={"kind": kind, "limit": 5})
            events = [json.loads(line[6:]) for line in r.text.splitlines() if line.startswith("data: ")]
            assert r.status_code == 200 and len(events) == 5 and {e["kind"] for e in events} == {kind}, r.text
        with client.websocket_connect("/ws/pose/kindN") as ws:  # auto: live frames while they come
            assert json.loads(ws.receive_text())["kind"] == "live"
    finally:
        stop.set()
        publisher.join()
    r = client.get("/sse/pose/kindN", params={"kind": "sideways", "limit": 1})
    assert r.status_code == 422 and "kind" in r.text, r.text
    with pytest.raises(WebSocketDisconnect) as info, client.websocket_connect("/ws/pose/kindN?kind=sideways") as ws:
        ws.receive_text()
    assert info.value.code == 1008, info.value


def test_exact_latency_is_measured_per_subject():
    """Frame time -> received, over each subject's last exact frames; live frames do not count."""
    state = LiveState()
    t0 = 1_800_000_000.0
    for i in range(200):  # latencies 100, 101, ..., 299 ms
        frame = wire.PoseFrame(i, int((t0 + i * 0.02) * 1e6), wire.KIND_EXACT, 0, pose_frame(i).q,
                               pose_frame(i).joints)
        state.apply_pose(wire.pose_key("latO"), wire.encode_pose(frame), rx=t0 + i * 0.02 + (100 + i) / 1e3)
        live = wire.PoseFrame(i, int((t0 + i * 0.02) * 1e6), wire.KIND_LIVE, 0, frame.q, frame.joints)
        state.apply_pose(wire.pose_key("latO"), wire.encode_pose(live), rx=t0 + 60.0)
    view = {s["subject"]: s for s in state.subject_views()}["latO"]
    assert math.isclose(view["exact_latency_p50_ms"], 200.0, abs_tol=1.01), view
    assert math.isclose(view["exact_latency_p99_ms"], 298.0, abs_tol=1.01), view
    state.apply_pose(wire.pose_key("liveOnlyO"), wire.encode_pose(pose_frame(1, wire.KIND_LIVE)))
    view = {s["subject"]: s for s in state.subject_views()}["liveOnlyO"]
    assert view["exact_latency_p50_ms"] is None and view["exact_latency_p99_ms"] is None, view


def test_subjects_carry_the_exact_latency(client, pub):
    def publish():
        frame = pose_frame(0)
        now_us = int((time.time() - 0.3) * 1e6)  # a frame 300 ms old when sent
        pub.put(wire.pose_key("latP"), wire.encode_pose(wire.PoseFrame(0, now_us, wire.KIND_EXACT, 0, frame.q,
                                                                        frame.joints)))

    def measured():
        s = {s["subject"]: s for s in client.get("/api/subjects").json()}.get("latP")
        return s is not None and s["exact_latency_p50_ms"] is not None

    publish_until(client, publish, measured, "latP's exact latency")
    s = {s["subject"]: s for s in client.get("/api/subjects").json()}["latP"]
    assert 300 <= s["exact_latency_p50_ms"] <= s["exact_latency_p99_ms"] < 3000, s


def test_slow_client_skips_frames_without_stalling_others():
    state = LiveState(ws_queue=4)
    slow, fast = state.add_client("s", "exact"), state.add_client("s", "exact")
    received = []
    for seq in range(100):
        state.apply_pose(wire.pose_key("s"), wire.encode_pose(pose_frame(seq)))
        received.append(json.loads(fast.queue.get_nowait())["seq"])
    assert received == list(range(100)), received[:10]
    kept = [json.loads(slow.queue.get_nowait())["seq"] for _ in range(slow.queue.qsize())]
    assert kept == [96, 97, 98, 99] and slow.skipped == 96, (kept, slow.skipped)
    state.remove_client(slow)
    state.remove_client(fast)
    assert state.client_count() == 0 and state.clients_skipped == 96


# ----------------------------------------------------------------------------- python client


def test_subscribe_pose_and_watch_command(router, pub):
    got = []
    arrived = threading.Event()

    def on_frame(subject, frame):
        got.append((subject, frame.seq))
        arrived.set()

    with zconfig.open_session(zconfig.ZenohSettings(connect=(router,))) as session, \
            subscribe_pose(session, "watchM", on_frame) as sub:
        wait_until(lambda: pub.put(wire.pose_key("watchM"), wire.encode_pose(pose_frame(5))) or arrived.is_set(),
                   10, "a frame through subscribe_pose")
        pub.put(wire.pose_key("watchM"), b"broken")
        wait_until(lambda: sub.errors == 1, 5, "bad frame counted")
    assert got[0] == ("watchM", 5), got
    with pytest.raises(ValueError, match="subject"):
        subscribe_pose(zconfig.ZenohSettings(connect=(router,)), "bad/subject", on_frame)
    text = render("watchM", pose_frame(5), 50.0)
    assert "watchM  exact #5" in text and "l_wrist" in text and "°" in text, text
    assert render("watchM", pose_frame(6, wire.KIND_LIVE), 50.0).startswith("watchM  live #6")
    missing = dataclasses.replace(pose_frame(7), flags=wire.FRAME_MISSING)
    devices = {s: s != "hip" for s in ("hip", "l_thigh", "r_thigh", "l_shank", "r_shank", "l_foot")}
    assert render("watchM", missing, 50.0, devices).splitlines()[0].endswith(
        "MISSING (no device: l_lowerarm, r_lowerarm, l_upperarm, r_upperarm, neck; offline: hip)")
    assert render("watchM", missing, 50.0).splitlines()[0].endswith("MISSING (no stats yet)")

    def watch(*flags: str) -> str:
        """Run ``limbstream watch watchM`` while exact and live frames come interleaved."""
        proc = subprocess.Popen([sys.executable, "-m", "limbstream.cli", "watch", "watchM", "--connect", router,
                                 "--count", "3", "--timeout", "20", "--refresh", "20", *flags], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            seq = 10
            while proc.poll() is None and seq < 3000:
                pub.put(wire.pose_key("watchM"), wire.encode_pose(pose_frame(seq)))
                pub.put(wire.pose_key("watchM"), wire.encode_pose(pose_frame(seq, wire.KIND_LIVE)))
                seq += 1
                time.sleep(0.01)  # publishing rate of the stand-in aggregator, not a synchronisation
            out, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        assert proc.returncode == 0, err
        assert "frames/s" in out and "joints (m, Y up)" in out, out
        return out

    headers = [line for line in watch().splitlines() if line.startswith("watchM  ")]
    assert headers and all(h.startswith("watchM  live #") for h in headers), headers  # live by default
    headers = [line for line in watch("--kind", "exact").splitlines() if line.startswith("watchM  ")]
    assert headers and all(h.startswith("watchM  exact #") for h in headers), headers
