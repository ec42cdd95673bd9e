"""Segment points' and subject truth messages' miss-detection heartbeats
(limbstream.device.io.point_publisher, truth_publisher): sporadic,
so a streaming device sends at most one per period and a paused one a single one after its last
point; the last points before a pause that a subscriber missed (sent while the router was down)
still reach it, as an aggregator subscribes (history on detection, recovery on heartbeat)."""
from __future__ import annotations

import signal
import threading
import time

import numpy as np
import pytest
import zenoh
import zenoh.ext as zext

from limbstream import wire, zconfig
from limbstream.device import io
from limbstream.device.host import Device, DeviceHost, HostSettings
from limbstream.launch import Launcher, free_port, port_open, wait_until

pytestmark = pytest.mark.e2e
HEARTBEAT_S = 0.5


def point(seq: int) -> bytes:
    """A distinct payload per point (what the subscriber sees; not decoded here)."""
    return seq.to_bytes(4, "little") * 9


@pytest.fixture
def router(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Launcher(tmp_path) as launcher:
        yield launcher, endpoint, launcher.router(endpoint)


def device_host(endpoint: str) -> tuple[zenoh.Session, DeviceHost, Device]:
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    host: DeviceHost = DeviceHost(session, HostSettings(truth=False, heartbeat_s=HEARTBEAT_S),
                                  lambda d, c: None, lambda d: wire.DeviceStatus(d.id, d.config, 0, 0, 0))
    d = host.add("s01", "hip")
    host.declare()
    return session, host, d


def test_heartbeats_come_only_after_points(router):
    """Streaming for 2 s: at most one heartbeat per period; pausing for 2 s (four periods): the
    heartbeats stop after the one that says the last point (a periodic heartbeat would beat in
    every period of the pause). That one may follow another: a heartbeat tick that came while the
    last point was still on its way out says the point before it, and the next tick says the last."""
    _, endpoint, _ = router
    observer = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    beats: list[float] = []
    sub = observer.declare_subscriber(wire.seg_key("s01", "hip") + "/@adv/pub/**", lambda s: beats.append(time.monotonic()))
    session, host, d = device_host(endpoint)
    try:
        began = time.monotonic()
        for seq in range(20):  # a point every 0.1 s, 2 s
            time.sleep(0.1)
            host.publish(d, point(seq))
        paused = time.monotonic()  # after the last point
        time.sleep(4 * HEARTBEAT_S)
        streaming = [t for t in beats if began <= t < paused]
        after = [t for t in beats if t >= paused]
        assert len(streaming) <= (paused - began) / HEARTBEAT_S + 1, streaming
        assert 1 <= len(after) <= 2, f"{len(after)} heartbeats in {4 * HEARTBEAT_S} s of pause"
        assert after[0] - paused <= 1.5 * HEARTBEAT_S
        assert after[-1] - paused <= 2.5 * HEARTBEAT_S, after  # none in the pause's last periods
    finally:
        sub.undeclare()
        host.close()
        session.close()
        observer.close()


def test_subject_truth_heartbeats_come_only_after_messages(router, monkeypatch):
    """A subject's truth publisher (io.truth_publisher, its period set to HEARTBEAT_S here): a
    message every 0.1 s for 2 s, at most one heartbeat per period; then a pause of four periods:
    one heartbeat (the per-device publisher's periodic one sent one every period, paused or not)."""
    _, endpoint, _ = router
    monkeypatch.setattr(io, "TRUTH_HEARTBEAT_S", HEARTBEAT_S)
    observer = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    beats: list[float] = []
    sub = observer.declare_subscriber(wire.truth_key("s01") + "/@adv/pub/**", lambda s: beats.append(time.monotonic()))
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    host: DeviceHost = DeviceHost(session, HostSettings(truth_by_subject=True), lambda d, c: None,
                                  lambda d: wire.DeviceStatus(d.id, d.config, 0, 0, 0))
    hip, head = host.add("s01", "hip"), host.add("s01", "head")
    host.declare()
    try:
        began = time.monotonic()
        for k in range(20):
            time.sleep(0.1)
            payload, ends = wire.encode_raws(np.array([1, 2]), np.array([k, k]), np.array([1, 1]),
                                             np.array([k, k], np.int64), np.tile(np.float32([1, 0, 0, 0]), (2, 1)))
            host.publish_raws(np.array([hip.slot, head.slot]), payload, ends)
        paused = time.monotonic()
        time.sleep(4 * HEARTBEAT_S)
        streaming = [t for t in beats if began <= t < paused]
        after = [t for t in beats if t >= paused]
        assert len(streaming) <= (paused - began) / HEARTBEAT_S + 1, streaming
        assert len(after) == 1, f"{len(after)} heartbeats in {4 * HEARTBEAT_S} s of pause (one says the last message)"
    finally:
        sub.undeclare()
        host.close()
        session.close()
        observer.close()


def test_points_sent_while_the_router_was_down_reach_a_subscriber_after_a_pause(router):
    """Points 0-9 delivered; the router killed; points 10-12 published (lost to the subscriber,
    kept in the device's cache) and the device pauses; the router restarted on the same port:
    the subscriber gets 10-12, in order, with no new point to reveal the gap."""
    launcher, endpoint, proc = router
    sub_session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    got: list[bytes] = []
    lock = threading.Lock()

    def take(sample: zenoh.Sample) -> None:
        with lock:
            got.append(sample.payload.to_bytes())
    sub = zext.declare_advanced_subscriber(
        sub_session, wire.device_selector(wire.SEG, "*"), take,
        history=zext.HistoryConfig(detect_late_publishers=True, max_samples=512),
        recovery=zext.RecoveryConfig(heartbeat=True), subscriber_detection=True)
    session, host, d = device_host(endpoint)
    try:
        for seq in range(10):
            host.publish(d, point(seq))
        wait_until(lambda: len(got) == 10, 10, "points 0-9")
        proc.signal(signal.SIGKILL)
        proc.popen.wait()
        wait_until(lambda: not port_open("127.0.0.1", int(endpoint.rsplit(":", 1)[1])), 5, "the router to be gone")
        for seq in range(10, 13):
            host.publish(d, point(seq))
        time.sleep(2 * HEARTBEAT_S)  # its one heartbeat goes out while the router is down
        launcher.router(endpoint)
        wait_until(lambda: len(got) >= 13, 20, "points 10-12 after the restart")
        with lock:
            assert got == [point(seq) for seq in range(13)]
    finally:
        sub.undeclare()
        host.close()
        session.close()
        sub_session.close()


def test_an_aggregator_gets_the_points_sent_while_the_router_was_down_before_a_pause(router):
    """As above, through the aggregator (which subscribes without Zenoh's late-publisher detection:
    docs/benchmarks.md, "Late-publisher detection"): the device's liveliness token coming back
    makes it ask the device's cache for the points after its newest (``HistoryQueries.resume``), so
    points 10-12 reach its store, in order, with no gap and nothing counted dropped."""
    from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings

    launcher, endpoint, proc = router
    points = [wire.SegmentPoint(1, seq, 3 * seq, 60_000 * seq, (1.0, 0.0, 0.0, 0.0), 0) for seq in range(13)]
    agg_session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    agg = Aggregator(agg_session, AggregatorSettings(subjects=("s01",)))
    session, host, d = device_host(endpoint)
    host.online(d)
    try:
        agg.open()

        def drained(until):
            return lambda: agg.drain(time.perf_counter()) >= 0 and until()
        for p in points[:10]:
            host.publish(d, wire.encode_point(p))
        wait_until(drained(lambda: (t := agg.known("s01", "hip")) is not None and t.points == 10), 10, "points 0-9")
        track = agg.known("s01", "hip")
        proc.signal(signal.SIGKILL)
        proc.popen.wait()
        wait_until(lambda: not port_open("127.0.0.1", int(endpoint.rsplit(":", 1)[1])), 5, "the router to be gone")
        for p in points[10:]:
            host.publish(d, wire.encode_point(p))
        time.sleep(2 * HEARTBEAT_S)  # its one heartbeat goes out while the router is down
        launcher.router(endpoint)
        wait_until(drained(lambda: track.next_seq == 13), 20, "points 10-12 after the restart",
                   on_fail=lambda: print(track.points, track.next_seq, dict(track.dropped)))
        assert agg.fusion.store.t[track.slot, :agg.fusion.store.n[track.slot]].tolist() == [p.t_us for p in points]
        assert (track.points, track.gaps, sum(track.dropped.values())) == (13, 0, 0)
    finally:
        agg.close()
        host.close()
        session.close()
        agg_session.close()


def test_a_subscription_gets_the_points_sent_while_the_router_was_down_before_a_pause(router):
    """The same through :class:`Subscription` (``limbstream record``, ``watch``): points 10-12
    reach it after the restart, each once, in order."""
    from limbstream.services.outputs.subscription import Subscription

    launcher, endpoint, proc = router
    points = [wire.encode_point(wire.SegmentPoint(1, seq, 3 * seq, 60_000 * seq, (1.0, 0.0, 0.0, 0.0), 0))
              for seq in range(13)]
    session, host, d = device_host(endpoint)
    host.online(d)
    got: list[bytes] = []

    def take(sub):
        return lambda: got.extend(item.payload for item in sub.drain()) or got
    with Subscription(zconfig.ZenohSettings(connect=(endpoint,)), "s01", ("seg",)) as sub:
        try:
            for p in points[:10]:
                host.publish(d, p)
            wait_until(lambda: len(take(sub)()) == 10, 10, "points 0-9")
            proc.signal(signal.SIGKILL)
            proc.popen.wait()
            wait_until(lambda: not port_open("127.0.0.1", int(endpoint.rsplit(":", 1)[1])), 5, "the router to be gone")
            for p in points[10:]:
                host.publish(d, p)
            time.sleep(2 * HEARTBEAT_S)  # its one heartbeat goes out while the router is down
            launcher.router(endpoint)
            wait_until(lambda: len(take(sub)()) >= 13 and not sub.resuming, 20, "points 10-12 after the restart")
            assert take(sub)() == points
        finally:
            host.close()
            session.close()
