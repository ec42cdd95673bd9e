"""Emulated devices fed raw IMU samples (``--imu raw``): the device bank's raw stage (VQF, then
fastSW, in C), live through router and aggregator, and its parts without a network."""
from __future__ import annotations

import numpy as np
import pytest

from limbstream import imu, wire
from limbstream.calibration import SensorModel
from limbstream.cli import emulate
from limbstream.device.readings import RawFeed, RawSensors, raw_per_sample
from limbstream.sources.generator import GeneratorSource
from support.stack import StatsWatch, stack, wait_until  # noqa: F401 - the fixture
from test_calibration import frames_compared


def test_raw_sensors_read_per_tick_what_a_whole_recording_reads():
    """RawSensors' reads of one tick at a time are imu.record's readings of the same devices
    (same part, mountings and noise), sample for sample."""
    source = GeneratorSource(seed=4, fs=50.0)
    feeds = [RawFeed(source, 200.0, 50.0)]
    sensors = RawSensors(feeds, imu.model("icm42688p"), 200.0, SensorModel(90.0, 180.0, seed=3), stream=1)
    ticks = [sensors.read(k, np.arange(10)) for k in range(30)]
    gyr = np.concatenate([g for g, _ in ticks])
    acc = np.concatenate([a for _, a in ticks])
    same = imu.ImuDevices(10, imu.model("icm42688p"), 200.0, SensorModel(90.0, 180.0, seed=3), stream=1)
    ideal = feeds[0].readings_feed.readings(np.arange(120))
    k = np.repeat(np.arange(120), 10)
    g, a = same.read(np.tile(np.arange(10), 120), k, ideal.gyr.reshape(-1, 3), ideal.acc.reshape(-1, 3))
    assert np.array_equal(gyr.reshape(-1, 3), g) and np.array_equal(acc.reshape(-1, 3), a)
    assert np.array_equal(feeds[0].sample(7), ideal.q[28].astype(np.float32))  # the truth at instant 7
    one_g, one_a = sensors.read(12, np.array([6]))  # one device alone (a firmware device's feed)
    assert np.array_equal(one_g[:, 0], ticks[12][0][:, 6]) and np.array_equal(one_a[:, 0], ticks[12][1][:, 6])


@pytest.mark.parametrize("argv, words", [
    (["--imu", "raw", "--yaw-drift-dps", "0.1"], "--yaw-drift-dps"),
    (["--imu", "raw", "--imu-model", "bmi999"], "--imu-model"),
    (["--imu", "raw", "--imu-rate", "130"], "whole multiple"),
])
def test_raw_sensor_flags_are_checked(argv, words):
    parser = emulate.argparse.ArgumentParser()
    emulate.add_arguments(parser)
    with pytest.raises(ValueError, match=words):
        emulate.flags.sensor_model(parser.parse_args(argv))


def test_raw_per_sample():
    assert raw_per_sample(200.0, 50.0) == 4 and raw_per_sample(50.0, 50.0) == 1
    with pytest.raises(ValueError, match="whole multiple"):
        raw_per_sample(75.0, 50.0)


@pytest.mark.e2e
def test_raw_sensor_devices_calibrate_and_track_the_body_live(stack):  # noqa: F811
    """``emulate --imu raw`` with a real part strapped at up to 90 deg, headings anywhere: every
    device fuses its readings (VQF 6D) and is calibrated from the script, the frames follow the
    true body, and each device reports its filter (mode, bias, rest, bad samples) in its status
    and the stats."""
    stack.router()
    stack.emulator(1, 1.0, "--imu", "raw", "--imu-model", "icm42688p", "--mounting-deg", "90", "--heading-deg", "180",
                   *wire.DeviceConfig(**wire.LIVE_MODE).flags())
    stack.aggregator("--calibrate-on-start")
    watch = StatsWatch(stack.endpoint)
    try:
        def calibrated():
            devices = watch.poll()
            return len(devices) == 10 and all(d["calibrated"] for d in devices.values())
        wait_until(calibrated, 60, "all 10 raw-sensor devices calibrated", interval=0.2, on_fail=stack.logs)
        subject = frames_compared(watch, 300, stack.logs)
        wait_until(lambda: all(d["fusion"] is not None for d in watch.poll().values()), 15, "fusion in the stats")
        status = watch.device_status("s01/l_thigh")
    finally:
        watch.close()
    assert subject["frame_aad_deg"] <= 3.0, subject["frame_aad_deg"]
    assert status["fusion"] == "6D" and len(status["gyro_bias_dps"]) == 3 and isinstance(status["at_rest"], bool)
    assert set(status["raw_faults"]) == {"invalid", "time_back", "gap", "saturated", "gyr_stuck"}, status
    for d in watch.devices.values():
        assert d["fusion"] == "6D" and 0 <= d["gyro_bias_dps"] < 5 and d["at_rest"] in (True, False), d
        assert d["raw_faults"]["invalid"] == 0 and d["raw_faults"]["gap"] == 0, d
