"""Emulated devices fed raw IMU samples (``--imu raw``): the device bank's raw stage (VQF, then
fastSW, in C), live through router and aggregator, and its parts without a network."""
from __future__ import annotations

import numpy as np
import pytest
import zenoh

from limbstream import imu, wire
from limbstream.calibration import SensorModel
from limbstream.cli import emulate
from limbstream.device.readings import RawFeed, RawSensors, raw_per_sample
from limbstream.sources.generator import GeneratorSource
from support.stack import StatsWatch, stack, wait_until  # noqa: F401 - the fixture
from test_calibration import all_calibrated, frames_compared


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
        all_calibrated(watch, stack.logs, "all 10 raw-sensor devices calibrated")
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


def test_bad_raw_samples_are_counted_per_device_and_no_nan_reaches_a_point():
    """The device bank's raw stage, on a real Zenoh session: NaN and Inf samples, a saturated
    accelerometer, a stuck gyro, a time step back and one that jumps 1 s are counted per device in
    its status (C's counts), and every point published is a finite unit quaternion."""
    from limbstream import zconfig
    from limbstream.device.bank import DeviceBank, RawStage
    from limbstream.device.host import DeviceHost, HostSettings

    session = zconfig.open_session(zconfig.ZenohSettings(mode="peer", connect=()))
    host = DeviceHost(session, HostSettings(truth=False, config=wire.DeviceConfig(**wire.LIVE_MODE)),
                      lambda d, c: None, lambda d: bank.status(d, None))
    for segment in ("hip", "l_thigh"):
        host.add("s01", segment)
    points = session.declare_subscriber(wire.device_selector("seg"), zenoh.handlers.FifoChannel(100_000))
    host.declare()
    bank = DeviceBank(host, 2, 8, RawStage(200.0, np.array([0.5, -2.0])))
    for d in host.devices:
        bank.start_stream(d, 0)
    rng = np.random.default_rng(5)
    n = 1200
    t = np.arange(n) * 5000
    t[700:] += 1_000_000  # a 1 s jump: the filter starts again
    gyr = rng.normal(0, 1.0, (n, 2, 3))
    acc = np.tile([0.0, 0.0, 9.81], (n, 2, 1)) + rng.normal(0, 0.3, (n, 2, 3))
    bad = {"invalid": [100, 101, 102], "saturated": [200, 201], "gyr_stuck": [300, 301, 302, 303], "time_back": [400]}
    gyr[100, 1, 0], acc[101, 1, 2], gyr[102, 1, 1] = np.nan, np.inf, -np.inf
    acc[200, 1, 0], acc[201, 1] = 400.0, 0.0
    gyr[300:304, 1] = 0.0
    ticks = np.stack([t, t], axis=1)
    ticks[400, 1] = ticks[399, 1]  # the same time again
    for i in range(n):
        bank.update_raw(ticks[i].astype(np.uint32), ticks[i] + 1_700_000_000_000_000, gyr[i], acc[i])
    status = [wire.decode_status(wire.encode_status(bank.status(d, None))) for d in host.devices]
    got = []
    while (sample := points.try_recv()) is not None:
        got.append(wire.decode_point(sample.payload.to_bytes()))
    host.close()
    session.close()
    assert status[0].fusion.raw_faults == {"invalid": 0, "time_back": 0, "gap": 1, "saturated": 0, "gyr_stuck": 0}
    want = {kind: len(rows) for kind, rows in bad.items()} | {"gap": 1}
    assert status[1].fusion.raw_faults == want, status[1].fusion
    assert status[1].fusion.fusion == "6D" and np.all(np.isfinite(status[1].fusion.gyro_bias_dps))
    assert len(got) > 50 and all(np.isfinite(p.q).all() and abs(np.linalg.norm(p.q) - 1) < 1e-5 for p in got)
    assert {p.stream for p in got} == {int(s) for s in bank.kernel.stream[:2]}
