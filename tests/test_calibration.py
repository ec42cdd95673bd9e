"""Sensor model and calibration (limbstream.calibration), measured against the true segments:
on exact readings, and through fastSW in the offline evaluation."""
from __future__ import annotations

import numpy as np
import pytest

from limbstream import calibration as cal
from limbstream import quat
from limbstream.evaluation import evaluate, streams_of
from limbstream.sources.generator import generate
from limbstream.wire import SEGMENTS

FS = 50.0


def scripted(seconds: float = 20.0, seed: int = 3):
    """(t (n,), q (n, 10, 4) true orientations with the calibration script, rest, mounting, motion start)."""
    motion = generate(seconds, FS, seed=seed)
    q, rest, mounting = cal.with_script(motion.q, FS)
    return np.arange(len(q)) / FS, q, rest, mounting, len(q) - len(motion.q)


def body_error(c: cal.Calibration, reading: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return quat.angle_deg(c.apply(reading), truth)


def test_rest_and_mounting_recover_the_true_segments_and_one_pose_cannot():
    t, q, rest, mounting, start = scripted()
    sensors = cal.SensorModel(mounting_deg=90, heading_deg=180, seed=7).draw(len(SEGMENTS))
    pose = cal.mounting_pose()
    worst_none = worst_rest = worst_full = 0.0
    for k in range(len(SEGMENTS)):
        reading = sensors.report(k, t, q[:, k])
        none = body_error(cal.Calibration.none(), reading[start:], q[start:, k]).mean()
        rest_only = cal.calibrate(reading, rest, None, None, SEGMENTS[k])
        full = cal.calibrate(reading, rest, mounting, pose[k], SEGMENTS[k])
        assert full.heading == pytest.approx(sensors.heading[k], abs=1e-6), SEGMENTS[k]
        worst_none = max(worst_none, none)
        worst_rest = max(worst_rest, body_error(rest_only, reading[start:], q[start:, k]).mean())
        worst_full = max(worst_full, body_error(full, reading[start:], q[start:, k]).max())
    assert worst_full < 1e-4, worst_full
    assert worst_rest > 5.0 and worst_none > 30.0, (worst_rest, worst_none)


def test_a_yaw_reset_follows_a_drifting_heading():
    t, q, rest, mounting, start = scripted(60.0)
    sensors = cal.SensorModel(mounting_deg=60, heading_deg=90, yaw_drift_dps=0.3, seed=2).draw(len(SEGMENTS))
    k = SEGMENTS.index("l_thigh")
    reading = sensors.report(k, t, q[:, k])
    full = cal.calibrate(reading, rest, mounting, cal.mounting_pose()[k])
    # a minute later the subject stands in the rest pose again: what the sensor reads then
    later = 60.0
    again = sensors.report(k, np.array([later]), np.array([[1.0, 0.0, 0.0, 0.0]]))[0]
    reset = full.with_yaw(again)
    now = sensors.report(k, np.full(len(q), later), q[:, k])  # the same motion at the drifted heading
    stale = body_error(full, now[start:], q[start:, k]).mean()
    fresh = body_error(reset, now[start:], q[start:, k]).max()
    # not exact: the heading drifted by 0.3 deg/s x ~2 s between the rest and the mounting pose,
    # which the mounting estimate keeps
    assert stale > 10.0 and fresh < 0.5, (stale, fresh)
    assert reset.poses == ("rest", "mounting", "yaw")


def test_calibration_is_refused_with_a_reason():
    t, q, rest, mounting, start = scripted()
    k = SEGMENTS.index("hip")
    reading = cal.SensorModel(mounting_deg=30, seed=1).draw(len(SEGMENTS)).report(k, t, q[:, k])
    moving = reading.copy()
    moving[rest] = quat.multiply(cal.yaw(np.linspace(0, 0.5, rest.stop - rest.start)), moving[rest])
    with pytest.raises(cal.CalibrationError, match="hip, rest pose: not still"):
        cal.calibrate(moving, rest, mounting, cal.mounting_pose()[k], "hip")
    broken = reading.copy()
    broken[rest.start + 3] = np.nan
    with pytest.raises(cal.CalibrationError, match="not a unit quaternion"):
        cal.calibrate(broken, rest, None, None, "hip")
    with pytest.raises(cal.CalibrationError, match="about the vertical only"):
        cal.Calibration.rest(reading[rest.start]).with_mounting(reading[rest.start], cal.yaw(0.7))
    with pytest.raises(ValueError, match="--mounting-deg"):
        cal.SensorModel(mounting_deg=-1)


def test_evaluation_measures_the_body_error_after_calibration():
    """Through fastSW at make run's settings: calibrated from the reconstruction, the body error
    is the compression error of perfect sensors plus little; uncalibrated it is tens of degrees."""
    motions = [generate(30.0, FS, seed=s) for s in (1, 2)]
    args = (["fastsw"], [9e-4], 25, [5.0])
    ideal = evaluate(streams_of(motions), *args)[0]
    sensors = cal.SensorModel(mounting_deg=90, heading_deg=180, seed=4)
    streams = streams_of(motions, sensors)
    assert all(s.truth is not None and s.motion_from > 0 for s in streams)
    rows = {poses: evaluate(streams, *args, poses=poses)[0] for poses in ((), ("rest",), ("rest", "mounting"))}
    full, rest_only, none = rows[("rest", "mounting")], rows[("rest",)], rows[()]
    assert np.isnan(ideal["body_aad"])
    assert full["body_aad"] <= ideal["aad"] + 0.3, (full["body_aad"], ideal["aad"])
    assert none["body_aad"] >= 10.0 and rest_only["body_aad"] > full["body_aad"] + 1.0, (none, rest_only)
    assert full["aad"] == rest_only["aad"] == none["aad"], "aad stays the compression error"


# ----------------------------------------------------------------------------- in the aggregator


def feed_aggregator(agg, reading: np.ndarray, t0_us: int, stream: int, segment: str, first_seq: int = 0,
                    step: int = 5) -> None:
    """Every ``step``-th reading of one device as a segment point (its own samples: no
    compression error), each arriving as it is taken."""
    from limbstream import wire
    for j, k in enumerate(range(0, len(reading), step)):
        p = wire.SegmentPoint(stream, first_seq + j, k, t0_us + round(k * 1e6 / FS), tuple(reading[k]))
        agg.on_point(wire.seg_key("s01", segment), wire.encode_point(p), now=k / FS)
        if j % 10 == 0:
            agg.advance(live=False, now=k / FS)


def test_the_aggregator_calibrates_each_new_stream_from_its_script_and_refuses_one_without():
    from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
    agg = Aggregator(None, AggregatorSettings(calibrate_on_start=True))
    agg._publish = lambda subject, payload: None
    t, q, rest, mounting, start = scripted(12.0)
    sensors = cal.SensorModel(mounting_deg=90, heading_deg=180, seed=5).draw(len(SEGMENTS))
    k = SEGMENTS.index("r_upperarm")
    reading = sensors.report(k, t, q[:, k])
    t0 = 1_700_000_000_000_000
    feed_aggregator(agg, reading, t0, 1, "r_upperarm")
    track = agg.track("s01", "r_upperarm")
    fusion = agg.fusion
    figures = fusion.calibration_figures(track.slot, fusion.clock)
    assert figures["calibrated"] and figures["calibration_refused"] is None, figures
    n = fusion.store.n[track.slot]
    stored_t = (fusion.store.t[track.slot, :n] - t0) / 1e6
    idx = np.round(stored_t * FS).astype(int)
    err = quat.angle_deg(fusion.store.q[track.slot, :n].astype(np.float64), q[idx, k])
    assert err.max() < 0.05, f"stored points against the true segment: max {err.max():.3f} deg"
    # the device restarts mid-motion: a new stream that does not begin with the script
    feed_aggregator(agg, reading[start:], t0 + 60_000_000, 2, "r_upperarm")
    figures = fusion.calibration_figures(track.slot, fusion.clock)
    assert not figures["calibrated"] and "not still" in figures["calibration_refused"], figures
    # a device whose stream's start never comes (joined late, no history): refused once settled
    late = agg.track("s01", "l_thigh")
    feed_aggregator(agg, reading[start:], t0, 3, "l_thigh", first_seq=40)
    assert "never arrived" in fusion.calibration_figures(late.slot, fusion.clock)["calibration_refused"]


@pytest.mark.e2e
def test_up_with_real_sensors_calibrates_every_device_and_the_body_error_stays_small(stack):  # noqa: F811
    """Emulated sensors strapped at up to 90 deg, headings anywhere: the aggregator calibrates
    every device from the script its stream begins with, and the subject's frames match the true
    segments (frame_aad_deg) as with perfect sensors."""
    from stack import StatsWatch, wait_until

    stack.router()
    stack.emulator(1, 1.0, "--mounting-deg", "90", "--heading-deg", "180", "--threshold", "9e-4",
                   "--live-bound-deg", "5")
    stack.aggregator("--calibrate-on-start")
    watch = StatsWatch(stack.endpoint)
    try:
        def calibrated():
            devices = watch.poll()
            return len(devices) == 10 and all(d["calibrated"] for d in devices.values())
        wait_until(calibrated, 60, "all 10 devices calibrated", interval=0.2, on_fail=stack.logs)

        def compared():
            watch.poll()
            s = watch.subjects.get("s01", {})
            return (s.get("frame_error_frames") or 0) >= 500 and s
        subject = wait_until(compared, 60, "500 frames compared with the truth", interval=0.2, on_fail=stack.logs)
    finally:
        watch.close()
    assert subject["frame_aad_deg"] <= 1.2, subject["frame_aad_deg"]
    assert all(d["calibration_refused"] is None and d["calibration_age_s"] >= 0 for d in watch.devices.values())
