"""The wearer's dimensions travel with the data (e2e, docs/protocol.md "Body dimensions"): the
devices announce their subject's body in their status, the aggregator draws each subject's pose
frames with it, the dashboard shows it; a malformed body on the wire is counted on its device and
dropped while everything streams on."""
from __future__ import annotations

import signal
import threading

import numpy as np
import pytest
from support import require_data
from support.devices import RawBodies
from support.stack import PAPER10 as PAPER10_FLAGS, StatsWatch, http_json, stack, wait_for_subscribers, wait_until  # noqa: F401  (fixture)

from limbstream import wire, zconfig
from limbstream.body import PAPER10, Body
from limbstream.services.outputs.recording import Recording, RecordingError
from limbstream.services.outputs.subscription import Subscription
from limbstream.sources.bvh import parse_bvh

pytestmark = pytest.mark.e2e

F32 = 2e-6
"""Relative tolerance of a bone length read from float32 joint positions."""


def bone_lengths(joints: np.ndarray) -> dict[str, float]:
    """Bone -> length, m, of one pose frame's joint positions (15, 3) (``paper10``'s bones)."""
    at = PAPER10.joint_index
    return {b.name: float(np.linalg.norm(joints[at[b.joint]].astype(np.float64) - joints[at[b.origin]]))
            for b in PAPER10.bones}


def drawn_with(frame: wire.PoseFrame, body: Body) -> bool:
    """The frame's bones have ``body``'s lengths (float32 positions)."""
    got, want = bone_lengths(frame.joints), body.lengths
    return all(abs(got[b] - want[b]) <= F32 * want[b] for b in want)


def frames_until(endpoint: str, done, what: str, logs, timeout: float = 40.0) -> dict[tuple[str, int], wire.PoseFrame]:
    """The newest pose frame per (subject, kind) once ``done(newest)`` holds."""
    newest: dict[tuple[str, int], wire.PoseFrame] = {}
    with Subscription(zconfig.ZenohSettings(connect=(endpoint,)), "*", (wire.POSE,)) as sub:
        def check() -> bool:
            newest.update(((item.subject, item.value.kind), item.value) for item in sub.drain())
            return done(newest)
        wait_until(check, timeout, what, on_fail=logs)
    return newest


def test_two_subjects_of_1_5_and_1_9_m_stream_together_each_drawn_with_its_own_bones(stack):  # noqa: F811
    stack.router()
    stack.aggregator()
    url = stack.dashboard()
    wait_for_subscribers(stack.endpoint, [wire.seg_key("s01", "hip")], "the aggregator", on_fail=stack.logs)
    stack.emulator(2, 1.0, "--height-m", "1.5,1.9")
    bodies = {"s01": Body.from_height(PAPER10, 1.5), "s02": Body.from_height(PAPER10, 1.9)}

    def both_kinds_drawn(newest) -> bool:
        return all(k in newest and drawn_with(newest[k], bodies[k[0]])
                   for k in [(s, kind) for s in bodies for kind in (wire.KIND_EXACT, wire.KIND_LIVE)])
    frames = frames_until(stack.endpoint, both_kinds_drawn, "both subjects' frames drawn with their bodies", stack.logs)
    legs = {s: bone_lengths(frames[(s, wire.KIND_LIVE)].joints)["l_thigh"] for s in bodies}
    assert legs["s02"] / legs["s01"] == pytest.approx(1.9 / 1.5, rel=1e-5)

    def shown(subject: str):
        status, body = http_json(f"{url}/api/subjects/{subject}")
        return body if status == 200 and body.get("height_m") is not None else None
    for subject, body in bodies.items():
        detail = wait_until(lambda s=subject: shown(s), 30, f"{subject}'s body on the dashboard", on_fail=stack.logs)
        assert detail["layout"] == "paper10" and detail["height_m"] == body.height_m
        assert detail["bones_m"] == pytest.approx(body.lengths, rel=1e-12)


def test_a_subject_without_dimensions_is_the_default_adult_on_the_dashboard(stack):  # noqa: F811
    stack.router()
    stack.aggregator()
    url = stack.dashboard()
    stack.emulator(1)
    frames = frames_until(stack.endpoint, lambda n: ("s01", wire.KIND_EXACT) in n, "s01's frames", stack.logs)
    default = Body.default(PAPER10)
    assert drawn_with(frames[("s01", wire.KIND_EXACT)], default)
    detail = wait_until(lambda: (lambda r: r[1] if r[0] == 200 and r[1].get("bones_m") else None)(
        http_json(f"{url}/api/subjects/s01")), 30, "s01 on the dashboard", on_fail=stack.logs)
    assert detail["layout"] == "paper10" and detail["height_m"] is None  # (the lengths its frames are drawn with)
    assert detail["bones_m"] == pytest.approx(default.lengths, abs=1e-5)


DEFAULT_BONES = {k: v for k, v in Body.default(PAPER10).to_dict().items() if k != "layout"}


@pytest.mark.parametrize("body", [{"layout": "paper10", "height_m": None, "bones": DEFAULT_BONES | {"l_thigh": 1.6}},
                                  {"layout": "paper10", "height_m": 175, "bones": DEFAULT_BONES}],
                         ids=["thigh_1.6_m", "height_175"])
def test_a_malformed_body_on_the_wire_is_counted_on_its_device_and_dropped_the_rest_streams(stack, body):  # noqa: F811
    stack.router()
    stack.aggregator()
    wait_for_subscribers(stack.endpoint, [wire.seg_key("s01", "hip")], "the aggregator", on_fail=stack.logs)
    stack.emulator(1, 1.0, "--height-m", "1.9")
    fake = RawBodies(stack.endpoint)
    fake.add("x01", {"hip": body})
    watch = StatsWatch(stack.endpoint)
    try:
        def counted():
            entry = watch.poll().get("x01/hip")
            return entry if entry and (entry.get("dropped_by_reason") or {}).get("status_body") else None
        entry = wait_until(counted, 30, "the malformed body counted on x01/hip",
                           on_fail=lambda: f"x01/hip's stats: {watch.devices.get('x01/hip')}\n{stack.logs()}")
        assert set(entry["dropped_by_reason"]) == {"status_body"}
        assert watch.subjects["x01"].get("bones_m") is None  # none announced: the aggregator's own skeleton
        tall = Body.from_height(PAPER10, 1.9)
        frames = frames_until(stack.endpoint, lambda n: ("x01", wire.KIND_EXACT) in n and ("s01", wire.KIND_EXACT) in n
                              and drawn_with(n[("s01", wire.KIND_EXACT)], tall), "both subjects streaming", stack.logs)
        assert drawn_with(frames[("x01", wire.KIND_EXACT)], Body.default(PAPER10))
        points = entry["points"]
        wait_until(lambda: watch.poll()["x01/hip"]["points"] > points + 25, 20, "x01/hip's points taken on",
                   on_fail=stack.logs)
    finally:
        watch.close()
        fake.close()


CMU_UNIT_M = 0.0254 / 0.45
"""The CMU clips' OFFSET unit, m."""


def test_a_bvh_source_streams_with_its_own_skeletons_bone_lengths(stack):  # noqa: F811
    path = require_data("cmu/01_01.bvh")
    clip = parse_bvh(path)
    at = {name: j for j, name in enumerate(clip.joints)}

    def offset(joint: str) -> float:  # a bone's length: the OFFSET of the joint it leads to, m
        return float(np.linalg.norm(clip.offsets[at[joint]])) * CMU_UNIT_M
    own = {"l_thigh": offset("LeftLeg"), "l_shank": offset("LeftFoot"), "r_thigh": offset("RightLeg"),
           "r_shank": offset("RightFoot"), "l_upperarm": offset("LeftForeArm"), "l_lowerarm": offset("LeftHand"),
           "r_upperarm": offset("RightForeArm"), "r_lowerarm": offset("RightHand")}
    stack.router()
    stack.aggregator()
    url = stack.dashboard()
    wait_for_subscribers(stack.endpoint, [wire.seg_key("s01", "hip")], "the aggregator", on_fail=stack.logs)
    stack.emulator(1, 1.0, "--source", str(path))

    def drawn(newest) -> bool:
        frame = newest.get(("s01", wire.KIND_EXACT))
        return frame is not None and all(abs(bone_lengths(frame.joints)[b] - m) <= F32 * m + 1e-7 for b, m in own.items())
    frames = frames_until(stack.endpoint, drawn, "s01's frames drawn with the clip's bones", stack.logs)
    assert wire.frame_rest_pose(frames[("s01", wire.KIND_EXACT)].flags) == "tpose"
    def announced():  # until the stats carry the announced body, the page shows its frames' lengths, rounded
        status, detail = http_json(f"{url}/api/subjects/s01")
        bones = detail.get("bones_m") if status == 200 else None
        return detail if bones and {b: bones[b] for b in own} == pytest.approx(own, rel=1e-9) else None
    detail = wait_until(announced, 30, "s01's announced bones on the dashboard", on_fail=stack.logs)
    assert detail["layout"] == "paper10" and detail["height_m"] is None


def test_a_recording_replays_its_subjects_body(stack, tmp_path):  # noqa: F811
    """Recorded devices' statuses carry their body: the replayed devices announce it again (at the
    aggregator's next poll once the replay has read them: the recording is replayed in a loop)."""
    path = tmp_path / "session.mcap"
    stack.router()
    stack.aggregator()
    recorder = stack.start("record", "record", str(path), "--connect", stack.endpoint)
    wait_for_subscribers(stack.endpoint, [wire.seg_key("s01", "hip")],
                         "the aggregator and the recorder", on_fail=stack.logs)
    stack.emulator(1, 1.0, "--height-m", "1.5")
    small = Body.from_height(PAPER10, 1.5)
    frames_until(stack.endpoint, lambda n: ("s01", wire.KIND_EXACT) in n and drawn_with(n[("s01", wire.KIND_EXACT)], small),
                 "s01 drawn at 1.5 m", stack.logs)

    def statuses() -> int:
        try:
            return len({e.key for e in Recording(path).entries(["config"])})
        except RecordingError:
            return 0
    wait_until(lambda: statuses() == 10, 30, "every device's status recorded", on_fail=stack.logs)
    recorder.signal(signal.SIGTERM)
    assert recorder.popen.wait(20) == 0, stack.logs()
    stack.start("replay", "replay", str(path), "--connect", stack.endpoint, "--subject-prefix", "r-", "--loop")
    frames_until(stack.endpoint, lambda n: ("r-s01", wire.KIND_EXACT) in n
                 and drawn_with(n[("r-s01", wire.KIND_EXACT)], small), "the replayed r-s01 drawn at 1.5 m", stack.logs)


def test_slimevr_trackers_announce_their_wearers_height(stack):  # noqa: F811
    from limbstream.device_emulator.slimevr_tracker import Fleet
    from support.slimevr import free_udp_port
    stack.router()
    stack.aggregator()
    port = free_udp_port()
    stack.start("gateway", "gateway", "slimevr", "--connect", stack.endpoint, "--udp", f"127.0.0.1:{port}",
                "--subject", "sv01", "--height-m", "1.6", "--no-sync", *PAPER10_FLAGS)
    t = np.arange(500) / 50.0
    q = np.zeros((len(t), len(wire.SEGMENTS), 4))
    q[..., 0], q[..., 2] = np.cos(0.3 * np.sin(t))[:, None], np.sin(0.3 * np.sin(t))[:, None]  # turning about Y
    fleet = Fleet(("127.0.0.1", port), q, wire.SEGMENTS, 50.0)
    stop = threading.Event()
    sender = threading.Thread(target=lambda: (fleet.connect(), fleet.run(stop)))
    sender.start()
    try:
        tall = Body.from_height(PAPER10, 1.6)
        frames_until(stack.endpoint, lambda n: ("sv01", wire.KIND_EXACT) in n
                     and drawn_with(n[("sv01", wire.KIND_EXACT)], tall), "sv01 drawn at 1.6 m", stack.logs, 60)
    finally:
        stop.set()
        sender.join()
        fleet.close()
