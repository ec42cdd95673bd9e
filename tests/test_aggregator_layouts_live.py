"""Body layouts from the data over a real Zenoh router (e2e, docs/protocol.md "Body layouts in the
aggregator"): 15 devices announcing a ``full`` body get their subject 512-byte frames of 15
segments drawn with that body, beside an emulated ``paper10`` subject streaming as before; a
device whose segment ``full`` lacks, and one whose status names another layout, are counted on
themselves while the rest streams."""
from __future__ import annotations


import numpy as np
import pytest
import zenoh
from support.devices import FakeDevices, pose_of
from support.stack import StatsWatch, stack, wait_for_subscribers, wait_until  # noqa: F401  (fixture)

from limbstream import wire, zconfig
from limbstream.body import FULL, PAPER10, Body
from limbstream.skeleton import Skeleton

pytestmark = pytest.mark.e2e


def drawn_with(payload: bytes, body: Body) -> bool:
    """The pose frame's joints are ``body``'s at its orientations (float32)."""
    f = wire.decode_pose(payload)
    return bool(np.abs(f.joints - body.positions(f.q.astype(np.float64))).max() < 1e-5)


def test_a_full_subject_streams_512_byte_frames_beside_a_paper10_subject_and_devices_off_its_layout_are_counted(stack):  # noqa: F811
    stack.router()
    stack.aggregator()
    wait_for_subscribers(stack.endpoint, [wire.seg_key("f01", "hip")], "the aggregator", on_fail=stack.logs)
    stack.emulator(1, 1.0)
    tall = Body.from_height(FULL, 1.8)
    frames: dict[tuple[str, int], list[bytes]] = {}
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    subs = [session.declare_subscriber(wire.pose_key(s), zenoh.handlers.FifoChannel(1 << 14)) for s in ("f01", "s01")]
    fakes = FakeDevices(stack.endpoint)
    fakes.add("f01", {s: tall for s in (*FULL.segment_names, "neck")})
    fakes.add("m01", {"hip": Body.default(FULL)})
    watch = StatsWatch(stack.endpoint)
    try:
        wait_until(lambda: watch.poll() and watch.subjects.get("m01", {}).get("layout") == "full", 30,
                   "m01's layout full", on_fail=stack.logs)
        fakes.add("m01", {"l_shank": Body.default(PAPER10)})  # another layout than m01's

        def complete() -> bool:
            for sub in subs:
                while (sample := sub.try_recv()) is not None:
                    payload = sample.payload.to_bytes()
                    frame = wire.decode_pose(payload)
                    # complete: every segment has data (a live frame does not flag a device online
                    # without a point yet; no constant pose here is the identity)
                    if not frame.flags & wire.FRAME_MISSING and (frame.q[:, 0] < 1).all():
                        frames.setdefault((str(sample.key_expr).split("/")[1], frame.kind), []).append(payload)
            return all(len(frames.get((s, k), ())) >= 20 for s in ("f01", "s01") for k in (wire.KIND_EXACT, wire.KIND_LIVE)) \
                and all(drawn_with(frames["f01", k][-1], tall) for k in (wire.KIND_EXACT, wire.KIND_LIVE))
        wait_until(complete, 40, "complete frames of both subjects, both kinds", on_fail=stack.logs)
        for kind in (wire.KIND_EXACT, wire.KIND_LIVE):
            assert {len(p) for p in frames["f01", kind]} == {512}
            assert {len(p) for p in frames["s01", kind]} == {372}
            drawn = [drawn_with(p, tall) for p in frames["f01", kind]]
            # the first frames may be drawn before the body arrives (with full's default), none after
            assert drawn[drawn.index(True):] == [True] * (len(drawn) - drawn.index(True))
            assert all(drawn_with(p, Body.default(FULL)) for p, ok in zip(frames["f01", kind], drawn) if not ok)
            for payload in frames["f01", kind]:
                f = wire.decode_pose(payload)
                want = np.array([pose_of(s) for s in FULL.segment_names])
                assert f.layout == FULL and np.abs(np.abs((f.q * want).sum(axis=1)) - 1).max() < 1e-6
            for payload in frames["s01", kind]:
                f = wire.decode_pose(payload)
                assert f.layout == PAPER10 and np.abs(f.joints - Skeleton().positions(f.q.astype(np.float64))).max() < 1e-6

        def counted():
            devices = watch.poll()
            neck, shank = devices.get("f01/neck", {}), devices.get("m01/l_shank", {})
            return (neck.get("dropped_by_reason") or {}).get("segment_not_in_layout") and \
                (shank.get("dropped_by_reason") or {}).get("status_layout")
        wait_until(counted, 30, "f01/neck and m01/l_shank counted", on_fail=stack.logs)
        devices = watch.poll()
        assert set(devices["f01/neck"]["dropped_by_reason"]) == {"segment_not_in_layout"}
        assert set(devices["m01/l_shank"]["dropped_by_reason"]) == {"status_layout"}
        assert not any(devices[f"f01/{s}"]["dropped_by_reason"] for s in FULL.segment_names)
        assert watch.subjects["f01"]["layout"] == "full" and watch.subjects["m01"]["layout"] == "full"
        assert watch.subjects["s01"]["layout"] == "paper10"
        assert watch.subjects["f01"]["bones_m"] == pytest.approx(tall.lengths)
        points = devices["m01/l_shank"]["points"]
        wait_until(lambda: watch.poll()["m01/l_shank"]["points"] > points + 25, 20, "m01/l_shank's points taken on",
                   on_fail=stack.logs)
    finally:
        watch.close()
        fakes.close()
        session.close()


def test_an_emulated_full_subject_streams_its_15_segments_drawn_with_the_body_it_announces(stack):  # noqa: F811
    """The generator's full body (``emulate --layout full``): its devices announce full's default
    body, and its frames are full's, drawn with it."""
    stack.router()
    stack.aggregator()
    wait_for_subscribers(stack.endpoint, [wire.seg_key("s01", "hip")], "the aggregator", on_fail=stack.logs)
    stack.emulator(1, 1.0, "--layout", "full")
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    sub = session.declare_subscriber(wire.pose_key("s01"), zenoh.handlers.FifoChannel(1 << 14))
    angles = session.declare_subscriber(wire.angles_key("s01"), zenoh.handlers.FifoChannel(1 << 14))
    watch = StatsWatch(stack.endpoint)
    frames: dict[int, list[bytes]] = {}
    try:
        def complete() -> bool:
            while (sample := sub.try_recv()) is not None:
                payload = sample.payload.to_bytes()
                frame = wire.decode_pose(payload)
                if not frame.flags & wire.FRAME_MISSING:
                    frames.setdefault(frame.kind, []).append(payload)
            return all(len(frames.get(k, ())) >= 20 for k in (wire.KIND_EXACT, wire.KIND_LIVE))
        wait_until(complete, 40, "complete frames of s01, both kinds", on_fail=stack.logs)
        body = Body.default(FULL)
        for kind in (wire.KIND_EXACT, wire.KIND_LIVE):
            assert {len(p) for p in frames[kind]} == {512}
            for payload in frames[kind]:
                f = wire.decode_pose(payload)
                assert f.layout == FULL and np.abs(f.joints - body.positions(f.q.astype(np.float64))).max() < 1e-5
        message = wire.decode_angles(wait_until(angles.try_recv, 20, "s01's joint angles").payload.to_bytes())
        assert message.layout == FULL and len(message.angles) == len(wire.joint_angles("full"))
        wait_until(lambda: watch.poll() and watch.subjects.get("s01", {}).get("layout") == "full", 20,
                   "s01's layout in its stats", on_fail=stack.logs)
        devices = watch.poll()
        assert {d.split("/")[1] for d in devices if d.startswith("s01/")} == set(FULL.segment_names)
        assert not any(set(d["dropped_by_reason"] or ()) & {"segment_not_in_layout", "status_layout", "status_body"}
                       for d in devices.values())
    finally:
        watch.close()
        session.close()
