"""VQF in the kernel library (limbstream.kernel.fusion; C: lsw_vqf.cpp, lsw_imu.c): against the PyPI
``vqf`` package (double precision) on BROAD's trials with optical truth, the device's instants, the
raw-sample pipeline against its parts (fusion, then fastSW), the bank's wire messages, and bad
raw samples."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.io

from limbstream import kernel, quat, wire
from limbstream.kernel import fusion
from support import DATA, require_data

vqf = pytest.importorskip("vqf")

BROAD = sorted((DATA / "broad").glob("*.mat"))


def load_broad(path) -> dict:
    d = scipy.io.loadmat(path, squeeze_me=True)
    return {k: np.ascontiguousarray(d[k], np.float64) for k in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat")} | {
        "movement": d["movement"].astype(bool), "rate": float(d["sampling_rate"])}


def total_rmse_deg(est: np.ndarray, truth: np.ndarray, movement: np.ndarray) -> float:
    """BROAD's total error: the angle of estimate * truth^-1 (earth frame), RMS over the movement
    phases where the markers were seen."""
    ok = movement & np.isfinite(truth).all(axis=1)
    return float(np.sqrt(np.mean(quat.angle_deg(est[ok], truth[ok]) ** 2)))


@pytest.mark.parametrize("name", [p.name for p in BROAD] or ["01_undisturbed_slow_rotation_A.mat"])
def test_broad_9d_equals_online_vqf(name):
    """The device's fusion (its filter settings: rest threshold 0.5 deg/s) against online VQF with
    the same settings, and against VQF's defaults: 9D total RMSE within 0.05 deg of both."""
    d = load_broad(require_data(f"broad/{name}"))
    ours = fusion.fuse(d["imu_gyr"], d["imu_acc"], d["imu_mag"], rate_hz=d["rate"])
    e_ours = total_rmse_deg(ours, d["opt_quat"], d["movement"])
    for params in ({"restThGyr": fusion.REST_TH_GYR_DPS, "restThAcc": fusion.REST_TH_ACC}, {}):
        online = vqf.VQF(1.0 / d["rate"], **params).updateBatch(d["imu_gyr"], d["imu_acc"], d["imu_mag"])["quat9D"]
        e_online = total_rmse_deg(online, d["opt_quat"], d["movement"])
        assert abs(e_ours - e_online) <= 0.05, f"{name}: 9D total RMSE {e_ours:.4f} deg, online VQF {params} {e_online:.4f}"
    assert np.isfinite(ours).all() and np.allclose(np.linalg.norm(ours, axis=1), 1.0, atol=1e-5)


@pytest.mark.parametrize("name", ["04_undisturbed_slow_rotation_with_breaks_A.mat",
                                  "08_undisturbed_fast_rotation_with_breaks_A.mat"])
def test_single_precision_errs_as_double_does(name):
    """The firmware's precision, single, against double on the two trials where a float state of
    the accelerometer's low-pass filter lost 0.05 and 0.21 deg (9D): within 0.05 deg of double's
    total error, 9D and 6D (heading aligned at the start), and its own inclination as close."""
    from limbstream.evaluation.fusion import fusion_error

    assert fusion.DEFAULT_VQF_PRECISION == "single"
    d = load_broad(require_data(f"broad/{name}"))
    t = np.arange(len(d["imu_gyr"])) / d["rate"]
    for mag in (d["imu_mag"], None):
        single, double = (fusion_error(fusion.fuse(d["imu_gyr"], d["imu_acc"], mag, rate_hz=d["rate"], vqf_precision=p),
                                       d["opt_quat"], t, d["movement"], align_heading=mag is None)
                          for p in ("single", "double"))
        assert abs(single.total_deg - double.total_deg) <= 0.05, (name, mag is not None, single, double)
        assert abs(single.inclination_deg - double.inclination_deg) <= 0.01, (name, mag is not None, single, double)


def test_filter_settings_and_start_heading_are_vqfs():
    """The rest threshold and start heading reach VQF as its own parameter and state would: the
    kernel's 6D orientation follows online VQF given restThGyr and its gyroscope quaternion."""
    d = load_broad(require_data("broad/04_undisturbed_slow_rotation_with_breaks_A.mat"))
    n = 20000
    g, a = d["imu_gyr"][:n], d["imu_acc"][:n]
    for th, heading in ((0.5, 2.5), (2.0, -1.0)):
        ours = fusion.fuse(g, a, rate_hz=d["rate"], rest_th_gyr_dps=th, heading_rad=heading)
        f = vqf.VQF(1.0 / d["rate"], restThGyr=th)
        state = f.state
        state["gyrQuat"] = np.array([np.cos(heading / 2), 0.0, 0.0, np.sin(heading / 2)])
        f.state = state
        out = f.updateBatch(np.ascontiguousarray(g), np.ascontiguousarray(a))
        gap = quat.angle_deg(ours, out["quat6D"])
        assert gap.max() < 0.2, f"restThGyr {th}, heading {heading}: {gap.max():.3f} deg off online VQF"
        assert abs(np.degrees(2 * np.arctan2(ours[0, 3], ours[0, 0])) - np.degrees(heading)) < 2.0
    with pytest.raises(ValueError, match="rest_th_gyr_dps"):
        fusion.imu_settings(200.0, rest_th_gyr_dps=0.0)


def test_6d_follows_online_vqf():
    d = load_broad(require_data("broad/06_undisturbed_fast_rotation_A.mat"))
    ours = fusion.fuse(d["imu_gyr"], d["imu_acc"], rate_hz=d["rate"])
    online = vqf.VQF(1.0 / d["rate"]).updateBatch(d["imu_gyr"], d["imu_acc"])["quat6D"]
    gap = quat.angle_deg(ours, online)
    assert gap.max() < 0.5 and gap.mean() < 0.05, f"6D off online VQF by {gap.max():.3f} deg max, {gap.mean():.4f} mean"


def still_sensor(seconds: float, rate_hz: float, bias=(0.01, -0.02, 0.005), seed: int = 3):
    """A still sensor, z up: gyro bias plus noise (rad/s), gravity plus noise (m/s^2)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * rate_hz)
    gyr = np.asarray(bias) + rng.normal(0, 0.002, (n, 3))
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, (n, 3))
    return gyr, acc


def test_rest_and_bias_estimate():
    gyr, acc = still_sensor(20.0, 200.0)
    bank = fusion.ImuBank(1, rate_hz=200.0)
    ticks = np.arange(len(gyr), dtype=np.int64) * 5000
    rest = []
    for i in range(len(gyr)):
        bank.update_raw(ticks[i:i + 1], gyr[i:i + 1], acc[i:i + 1])
        if i in (50, len(gyr) - 1):
            rest.append(bool(bank.imu_status()["rest"][0]))
    status = bank.imu_status()
    assert rest == [False, True], f"rest after 0.25 s and after 20 s: {rest}"
    assert np.allclose(status["bias"][0], (0.01, -0.02, 0.005), atol=2e-3), f"bias {status['bias'][0]}"
    assert bank.mode == "6D" and fusion.ImuBank(1, 200.0, nine_d=True).mode == "9D"


def test_device_instants():
    """BROAD's rate: the first raw sample at or after each 20 ms instant, stamped with its own time."""
    d = load_broad(require_data("broad/01_undisturbed_slow_rotation_A.mat"))
    n = 3000
    ticks = np.round(np.arange(n) / d["rate"] * 1e6).astype(np.int64)
    bank = fusion.ImuBank(1, rate_hz=d["rate"], device_rate_hz=50.0, threshold=0.0)  # every sample a point
    stamps = []
    for i in range(n):
        status, _, _ = bank.update_raw(ticks[i:i + 1], d["imu_gyr"][i:i + 1], d["imu_acc"][i:i + 1])
        if status[0] == kernel.POINT:
            stamps.append(int(bank.segments.points_t()[0]))
    instants = np.arange(len(stamps)) * 20000
    period = 1e6 / d["rate"]
    made = int(bank.imu_status()["outputs"][0])
    assert made == int(ticks[-1] // 20000) + 1 and len(stamps) == made - 1  # the last is no point yet
    late = np.asarray(stamps[1:]) - instants[1:]  # the first point is at 0
    assert late.min() >= 0 and late.max() < period, f"stamps after their instants by {late.min()}..{late.max()} us"
    even = fusion.ImuBank(1, rate_hz=200.0, threshold=0.0)
    got = [even.update_raw([i * 5000], [[0.1, 0, 0]], [[0, 0, 9.81]])[0][0] for i in range(40)]
    assert [i for i, s in enumerate(got) if s != fusion.NO_OUTPUT] == list(range(0, 40, 4))


def test_pipeline_equals_fusion_then_fastsw():
    """The bank's points are fastSW's (live rule) on the orientations :func:`fuse` gives at the
    device's samples turned Y up (as float32 arithmetic does it), bit for bit: one code path."""
    d = load_broad(require_data("broad/21_undisturbed_fast_combined.mat"))
    n = 6000
    g, a = d["imu_gyr"][:n], d["imu_acc"][:n]
    ticks = np.round(np.arange(n) / d["rate"] * 1e6).astype(np.int64)
    bank = fusion.ImuBank(1, rate_hz=d["rate"], threshold=9e-4, max_len=25, live_bound_deg=5.0)
    points, outputs = [], []
    for i in range(n):
        status, index, y = bank.update_raw(ticks[i:i + 1], g[i:i + 1], a[i:i + 1])
        if status[0] != fusion.NO_OUTPUT:
            outputs.append(i)
        if status[0] == kernel.POINT:
            points.append((int(index[0]), y[0].copy(), bank.segments.points_omega()[0]))
    q = y_up(fusion.fuse(g, a, rate_hz=d["rate"], t=ticks / 1e6).astype(np.float32))
    rows = np.asarray(outputs)
    assert np.array_equal(rows, fusion.device_instants(ticks / 1e6, wire.DEVICE_RATE_HZ)), "device_instants is C's rule"
    ref = kernel.segment(ticks[rows] / 1e6, q[rows], 9e-4, 25, live_bound_deg=5.0)
    got_index = [p[0] for p in points]
    assert got_index == list(ref.index[:len(got_index)]), "points at other device samples than fastSW's"
    assert np.array_equal(np.array([p[1] for p in points]), ref.q[:len(points)])
    assert np.allclose(np.array([p[2] for p in points]), ref.omega[:len(points)], rtol=1e-5, atol=1e-6)


def y_up(q: np.ndarray) -> np.ndarray:
    """(n, 4) float32 Z-up orientations turned into limbstream's Y-up world as lsw_imu_y_up does."""
    turned = fusion.y_up(q)
    assert np.allclose(turned, quat.multiply(quat.Z_UP_TO_Y_UP, q), atol=1e-6)
    return turned


def test_bank_wire_messages():
    """update_raw_wire: the bank's points as segment point messages (v2), sample index = the
    device-rate sample, time = its raw sample's stamp."""
    gyr, acc = still_sensor(4.0, 200.0)
    gyr[:, 2] += np.sin(np.arange(len(gyr)) / 40.0)  # turning about z
    count = 3
    bank = fusion.ImuBank(count, rate_hz=200.0, threshold=9e-4, max_len=25, live_bound_deg=5.0, ring=4)
    plain = fusion.ImuBank(count, rate_hz=200.0, threshold=9e-4, max_len=25, live_bound_deg=5.0)
    bank.segments.stream[:count] = (7, 8, 9)
    epoch = 1_700_000_000_000_000
    seen = 0
    for i in range(len(gyr)):
        ticks = np.full(count, i * 5000)
        g = np.repeat(gyr[i:i + 1], count, axis=0) * np.array([[1.0], [0.5], [-1.0]])
        a = np.repeat(acc[i:i + 1], count, axis=0)
        slots, payload, ends = bank.update_raw_wire(ticks, epoch + ticks, g, a)
        status, index, y = plain.update_raw(ticks, g, a)
        assert list(slots) == list(np.flatnonzero(status == kernel.POINT))
        starts = np.concatenate([[0], ends[:-1]])
        for slot, s, e in zip(slots, starts, ends):
            point = wire.decode_point(payload[s:e])
            assert point.stream == 7 + slot and point.index == int(index[slot])
            assert point.t_us == epoch + int(plain.segments.points_t()[slot])
            assert np.array_equal(np.float32(point.q), y[slot]) and point.omega is not None
            seen += 1
    assert seen > 3 * count


def test_bad_raw_samples_counted_and_handled():
    gyr, acc = still_sensor(6.0, 200.0)
    gyr[:, 0] += 0.5 * np.sin(np.arange(len(gyr)) / 30.0)
    ticks = np.arange(len(gyr), dtype=np.int64) * 5000
    gyr[100] = np.nan
    acc[101, 1] = np.inf
    gyr[102, 2] = 1e30
    acc[200:210, 0] = 200.0  # saturated
    acc[210] = 0.0  # all zeros
    gyr[300:320] = 0.0  # stuck
    ticks[400] = ticks[399]  # no time step
    ticks[401] = ticks[399] - 10  # back in time
    ticks[600:] += 1_000_000  # a 1 s jump
    bank = fusion.ImuBank(1, rate_hz=200.0, threshold=9e-4, max_len=25, live_bound_deg=5.0)
    points = []
    for i in range(len(gyr)):
        status, _, y = bank.update_raw(ticks[i:i + 1], gyr[i:i + 1], acc[i:i + 1])
        if i in (100, 101, 102, 400, 401):
            assert status[0] == fusion.SKIPPED, f"sample {i}: status {status[0]}"
        if status[0] == kernel.POINT:
            points.append(y[0].copy())
    report = bank.imu_status()
    counts = {name: int(report[name][0]) for name in fusion.FAULTS}
    assert counts == {"invalid": 3, "time_back": 2, "gap": 1, "saturated": 11, "gyr_stuck": 20}, counts
    assert np.isfinite(np.array(points)).all() and len(points) > 10
    assert np.isfinite(fusion.fuse(gyr, acc, rate_hz=200.0, t=ticks / 1e6)).all()


def test_bad_arguments():
    with pytest.raises(ValueError, match="rate_hz"):
        fusion.ImuBank(1, rate_hz=0.0)
    with pytest.raises(ValueError, match="device_rate_hz"):
        fusion.ImuBank(1, rate_hz=40.0, device_rate_hz=50.0)
    with pytest.raises(ValueError, match="acc must be"):
        fusion.fuse(np.zeros((5, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="mag is required"):
        fusion.ImuBank(1, 100.0, nine_d=True).update_raw([0], [[0, 0, 0]], [[0, 0, 9.8]])
