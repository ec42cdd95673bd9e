"""The dashboard's live pose streams (WebSocket, SSE, kinds, latency, slow clients) and the
Python client against real Zenoh traffic (a router and client sessions on loopback), with the
app's lifespan on; the REST API and device control: tests/test_dashboard_api.py."""
from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
import threading
import time

import pytest
from support.stack import ROOT, wait_until
from support.dashboard import pose_frame, publish_until
from starlette.websockets import WebSocketDisconnect

from limbstream import wire, zconfig
from limbstream.cli.watch import render, subscribe_pose
from limbstream.services.dashboard.state import LiveState
from limbstream.services.dashboard.views import Views


# ----------------------------------------------------------------------------- live streams


def test_websocket_streams_frames_in_order(client, pub):
    publish_until(client, lambda: pub.put(wire.pose_key("wsK"), wire.encode_pose(pose_frame(0))),
                  lambda: client.get("/api/subjects/wsK/pose").status_code == 200, "wsK first frame")
    with client.websocket_connect("/ws/pose/wsK") as ws:
        first = json.loads(ws.receive_text())  # the latest frame, sent on connect
        assert first["subject"] == "wsK" and first["seq"] == 0 and first["rest_pose"] == "standing", first
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
    view = {s["subject"]: s for s in Views(state).subject_views()}["latO"]
    assert math.isclose(view["exact_latency_p50_ms"], 200.0, abs_tol=1.01), view
    assert math.isclose(view["exact_latency_p99_ms"], 298.0, abs_tol=1.01), view
    state.apply_pose(wire.pose_key("liveOnlyO"), wire.encode_pose(pose_frame(1, wire.KIND_LIVE)))
    view = {s["subject"]: s for s in Views(state).subject_views()}["liveOnlyO"]
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
    slow, fast = state.fanout.add("s", "exact", None), state.fanout.add("s", "exact", None)
    received = []
    for seq in range(100):
        state.apply_pose(wire.pose_key("s"), wire.encode_pose(pose_frame(seq)))
        received.append(json.loads(fast.queue.get_nowait())["seq"])
    assert received == list(range(100)), received[:10]
    kept = [json.loads(slow.queue.get_nowait())["seq"] for _ in range(slow.queue.qsize())]
    assert kept == [96, 97, 98, 99] and slow.skipped == 96, (kept, slow.skipped)
    state.fanout.remove(slow)
    state.fanout.remove(fast)
    assert state.fanout.count() == 0 and state.fanout.skipped_total() == 96


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
