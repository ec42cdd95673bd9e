"""The aggregator's joint angles (services/aggregator/angles.py), in process, no Zenoh: one
message per live frame whose angles are ``joints.joint_angles`` of that very frame, no angle for a
joint whose segment is missing, none at all for a subject that is not calibrated (and the reason
on the message), the basis each subject's angles rest on, and the facing a rest-calibrated subject
gets from its knees once it walks."""
from __future__ import annotations

import math

import numpy as np
import pytest

from limbstream import calibration, joints, wire
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
from limbstream.services.aggregator.angles import FACING_FRAMES, JointStage
from limbstream.sources import SEGMENTS, generator

T0 = 1_700_000_000_000_000
STEP_US = 20_000
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


class Run:
    """An aggregator without a session fed one point per device and tick (every sample, so a
    live frame is the samples of its time), its live frames and joint-angle messages kept, the
    stage on a clock that follows the ticks."""

    def __init__(self, **settings):
        self.agg = Aggregator(None, AggregatorSettings(**settings))
        self.now = 0.0
        self.agg.frame_stages = [JointStage(self.agg.fusion, live=self.agg.settings.live_rate > 0,
                                            clock=lambda: self.now)]
        self.frames: dict[tuple[str, int, int], wire.PoseFrame] = {}
        self.angles: list[tuple[str, wire.JointAngles]] = []
        self.agg._publish = self._pose
        self.agg._put = self._angles
        self.k = 0

    def _pose(self, subject: str, payload: bytes) -> None:
        frame = wire.decode_pose(payload)
        self.frames[subject, frame.kind, frame.seq] = frame

    def _angles(self, key: str, kind: str, payload: bytes) -> None:
        assert kind == wire.ANGLES and key.endswith("/angles")
        self.angles.append((wire.parse_subject_key(key)[0], wire.decode_angles(payload)))

    def device(self, subject: str, segment: str, orientations: str | None) -> None:
        """A device online, saying ``orientations`` in its status (None: no status yet)."""
        self.agg.on_alive(wire.alive_key(subject, segment), True)
        if orientations is not None:
            status = wire.DeviceStatus(wire.device_id(subject, segment), wire.DeviceConfig(), 1, 0, 0,
                                       orientations=orientations)
            self.agg.on_config(wire.config_key(subject, segment), wire.encode_status(status))

    def tick(self, q: dict[str, np.ndarray], live: bool = True) -> None:
        """Every device's sample of this tick (``q``: {subject: (10, 4)}, of the devices it has)."""
        keys, payloads = [], []
        for subject, sample in q.items():
            for segment in self.agg.fusion.subjects[subject].tracks:
                point = wire.SegmentPoint(1, self.k, self.k, T0 + self.k * STEP_US,
                                          tuple(sample[SEGMENTS.index(segment)]))
                keys.append(wire.seg_key(subject, segment))
                payloads.append(wire.encode_point(point))
        self.now = self.k * STEP_US / 1e6
        self.agg.take_points(keys, payloads, self.now)
        self.agg.advance(live, now=self.now)
        self.k += 1

    def latest(self, subject: str) -> wire.JointAngles:
        return [a for s, a in self.angles if s == subject][-1]


def walk(seed: int, ticks: int) -> np.ndarray:
    """(ticks, 10, 4) a generated subject walking, at 50 Hz."""
    return generator.GeneratorSource(seed=seed, fs=50.0, activities="walking").orientations(np.arange(ticks) / 50.0 + 2.0)


def test_every_live_frame_gets_the_joint_angles_of_that_frame():
    run = Run()
    for segment in SEGMENTS:
        run.device("s01", segment, "segments")
        if segment != "r_shank":
            run.device("s02", segment, "segments")  # no right shank
    q1, q2 = walk(1, 60), walk(2, 60)
    for k in range(60):
        if k == 40:
            run.agg.on_alive(wire.alive_key("s02", "l_upperarm"), False)  # the left arm's device goes offline
        run.tick({"s01": q1[k], "s02": q2[k]})
    assert len(run.angles) == sum(f.kind == wire.KIND_LIVE for f in run.frames.values()) > 100
    knee_r, hip_r, elbow_l = (wire.JOINT_ANGLES.index(n) for n in ("knee_angle_r", "hip_flexion_r", "elbow_flex_l"))
    for subject, angles in run.angles:
        frame = run.frames[subject, wire.KIND_LIVE, angles.seq]
        assert (angles.t_us, angles.kind) == (frame.t_us, wire.KIND_LIVE)
        assert wire.ANGLE_BASES[angles.basis].name == "segments" and math.isnan(angles.facing_deg)
        present = np.array([s in run.agg.fusion.subjects[subject].tracks for s in SEGMENTS])
        if subject == "s02" and frame.t_us >= T0 + 40 * STEP_US:
            present[SEGMENTS.index("l_upperarm")] = False
        want, want_flags = joints.joint_angles(frame.q, present)  # the frame as published (float32)
        assert angles.flags.tolist() == want_flags.tolist(), (subject, angles.seq)
        assert np.array_equal(np.isnan(angles.angles), np.isnan(want))
        err = np.abs(angles.angles - want)[np.isfinite(want)]
        assert err.max() < 1e-4, (subject, angles.seq, err.max())  # (the message's float32)
    s02 = run.latest("s02")
    assert s02.flags[knee_r] == wire.ANGLE_MISSING and math.isnan(s02.angles[knee_r])  # marked, not zero
    assert s02.flags[elbow_l] & wire.ANGLE_MISSING and math.isnan(s02.angles[elbow_l])  # offline: held, no angle
    assert s02.flags[hip_r] == 0 and math.isfinite(s02.angles[hip_r])
    assert run.latest("s01").flags[knee_r] == 0


def test_a_subject_that_is_not_calibrated_gets_no_numbers_and_is_told_why():
    run = Run()
    for segment in SEGMENTS:
        run.device("s01", segment, "sensors")   # its sensors' readings
        run.device("s02", segment, None)        # not said yet
        run.device("s03", segment, "sensors")   # calibrated from the rest pose only, standing still
        run.device("s04", segment, "sensors")   # and from the mounting pose
        run.device("s05", segment, "segments" if segment != "neck" else "sensors")  # one device uncalibrated
    q = walk(3, 40)
    still = np.tile(IDENTITY, (len(SEGMENTS), 1))
    run.tick({s: still if s == "s03" else q[0] for s in ("s01", "s02", "s03", "s04", "s05")})  # (no calibration yet)
    cal = run.agg.fusion.calibrating.calibrations
    for track in run.agg.fusion.subjects["s03"].tracks.values():
        cal[track.slot] = calibration.Calibration.rest(IDENTITY)
    for track in run.agg.fusion.subjects["s04"].tracks.values():
        cal[track.slot] = calibration.Calibration(("rest", "mounting"), IDENTITY, 0.0)
    assert run.latest("s04").calibration.name == "uncalibrated"
    for k in range(1, 40):  # the stage looks at the calibrations again within REFRESH_S
        run.tick({s: still if s == "s03" else q[k] for s in ("s01", "s02", "s03", "s04", "s05")})
    for subject, basis in (("s01", "uncalibrated"), ("s02", "unknown"), ("s03", "no_facing"), ("s05", "uncalibrated")):
        a = run.latest(subject)
        assert a.calibration.name == basis and not a.calibration.valid, subject
        assert np.isnan(a.angles).all() and (a.flags & wire.ANGLE_UNCALIBRATED).all(), subject
        js = a.to_json(subject)
        assert js["why"] == a.calibration.meaning and set(js["angles"].values()) == {None}
    a = run.latest("s04")
    assert a.calibration.name == "mounting" and np.isfinite(a.angles).all() and not (a.flags & ~np.uint8(2)).any()


def test_a_rest_calibrated_subject_gets_its_facing_from_its_knees_once_it_walks():
    """Devices calibrated from the rest pose alone, in a world turned by 70 degrees (one heading
    for all, as 9D sensors give): no angles until the knees have moved; then the facing, and the
    body's own angles."""
    run = Run()
    for segment in SEGMENTS:
        run.device("s01", segment, "rest")
    h = math.radians(70.0)
    body = walk(4, 400)
    seen = joints.face(body, np.full(len(body), -h))  # yaw(h) q yaw(-h): the rest calibration's view
    first = None
    for k in range(len(body)):
        run.tick({"s01": seen[k]})
        if first is None and run.latest("s01").calibration.name == "functional":
            first = k
    assert first is not None and FACING_FRAMES <= first < 300, first
    a = run.latest("s01")
    assert math.remainder(math.radians(a.facing_deg) - h, math.tau) == pytest.approx(0.0, abs=math.radians(0.5))
    k = (a.t_us - T0) // STEP_US
    want, flags = joints.joint_angles(body[k])
    assert np.abs(a.angles - want)[~(flags & joints.GIMBAL).astype(bool)].max() < 0.5
    assert [x.calibration.name for _, x in run.angles[:40]] == ["no_facing"] * 40


def test_without_live_frames_the_angles_follow_the_exact_frames_and_the_stage_can_be_off():
    run = Run(live_rate=0.0)
    for segment in SEGMENTS:
        run.device("s01", segment, "segments")
    q = walk(5, 30)
    for k in range(30):
        run.tick({"s01": q[k]}, live=False)
    exact = [f for f in run.frames.values() if f.kind == wire.KIND_EXACT]
    assert exact and len(run.angles) == len(exact) and {a.kind for _, a in run.angles} == {wire.KIND_EXACT}
    assert Aggregator(None, AggregatorSettings(joint_angles=False)).frame_stages == []
