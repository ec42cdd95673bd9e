"""Emulated IMU readings (limbstream.imu): kinematics against closed forms and scipy, the part's
errors, the per-tick API against a whole recording, and VQF (the PyPI reference) on the result."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from limbstream import imu, quat
from limbstream.calibration import REST_S, STILL_MARGIN_S, SensorModel
from limbstream.evaluation.fusion import fusion_error, reference_vqf
from limbstream.imu import kinematics
from limbstream.imu.devices import BLOCK
from limbstream.skeleton import Skeleton
from limbstream.sources import SEGMENTS, Motion, bvh, load
from limbstream.sources.generator import GeneratorSource, generate

G = imu.GRAVITY
RATE = 200.0


def motion_of(q_fn, seconds=4.0, fs=50.0, root_fn=None) -> Motion:
    """A 10-segment Motion sampled from q_fn(t) -> (n, 10, 4) (and root_fn(t) -> (n, 3))."""
    t = np.arange(round(seconds * fs) + 1) / fs
    return Motion(t, q_fn(t), SEGMENTS, "test", "standing", None if root_fn is None else root_fn(t))


def ideal(motion: Motion, script=False):
    """Ideal readings of a whole motion (no script unless asked)."""
    feed = imu.ReadingFeed(motion, RATE, once=True, script=script)
    return feed.readings(np.arange(feed.length))


def middle(r, seconds=1.0):
    """Samples away from both ends of a short motion (the low-pass filter's edges)."""
    return (r.t > r.t[0] + seconds) & (r.t < r.t[-1] - seconds)


def test_still_sensor_reads_gravity_up_and_no_rate():
    orientations = Rotation.random(10, random_state=1)
    q = quat.from_rotation(orientations)
    r = ideal(motion_of(lambda t: np.broadcast_to(q, (len(t), 10, 4)).copy()))
    assert np.abs(r.gyr).max() < 1e-9, np.abs(r.gyr).max()
    want = orientations.inv().apply([0.0, G, 0.0])  # the world's up (Y) in each sensor's frame
    assert np.allclose(r.acc, want[None], atol=1e-6), np.abs(r.acc - want).max()
    # in the filter's earth frame (Z up, VQF's convention) the reading points up at +g
    up = quat.rotate(imu.to_earth(r.q), r.acc)
    assert np.allclose(up, [0.0, 0.0, G], atol=1e-6), up[0]


def test_integrating_the_rate_gives_back_the_orientations():
    rng = np.random.default_rng(2)
    axes, rates = rng.normal(size=(10, 3)), rng.uniform(1.0, 4.0, (10, 1))

    def wobble(t):  # each segment turns back and forth about its own axis, fast
        angle = np.sin(3.0 * t)[:, None] * rates.T
        return quat.from_rotation(Rotation.from_rotvec((angle[..., None] * axes).reshape(-1, 3))).reshape(len(t), 10, 4)

    r = ideal(motion_of(wobble))
    integrated = Rotation.from_quat(r.q[0][:, [1, 2, 3, 0]])
    worst = 0.0
    for k in range(1, len(r.t)):  # strapdown, as VQF: q[k] = q[k-1] exp(omega[k] Ts)
        integrated = integrated * Rotation.from_rotvec(r.gyr[k] / RATE)
        worst = max(worst, float(quat.angle_deg(quat.from_rotation(integrated), r.q[k]).max()))
    assert worst < 1e-5, worst
    # the mean rate over the interval is the instantaneous body rate at its middle, to O(Ts^2)
    mid = r.t - 0.5 / RATE
    h = 1e-5
    motion = kinematics.SmoothMotion(motion_of(wobble))
    q0, q1 = motion.orientations(mid - h), motion.orientations(mid + h)
    instant = quat.to_rotation(quat.multiply(quat.conjugate(q0), q1)).as_rotvec() / (2 * h)
    keep = middle(r)
    assert np.abs(instant - r.gyr)[keep].max() < 2e-3, np.abs(instant - r.gyr)[keep].max()


def test_specific_force_of_a_shank_turning_about_the_knee():
    omega = 2.0  # rad/s about the lateral axis; thigh and hip still
    s = SEGMENTS.index("r_shank")

    def swing(t):
        q = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 10, 1))
        q[:, s] = quat.from_rotation(Rotation.from_rotvec(np.outer(omega * t, [1.0, 0.0, 0.0])))
        return q

    r = ideal(motion_of(swing, seconds=6.0))
    keep = middle(r, 1.5)
    radius = 0.5 * Skeleton().shank  # the sensor sits halfway down the bone (-Y of the segment)
    seg = Rotation.from_quat(r.q[keep, s][:, [1, 2, 3, 0]])
    want = np.array([0.0, omega**2 * radius, 0.0]) + seg.inv().apply([0.0, G, 0.0])  # centripetal + gravity
    assert np.abs(r.acc[keep, s] - want).max() < 2e-3, np.abs(r.acc[keep, s] - want).max()
    assert np.allclose(r.gyr[keep, s], [omega, 0.0, 0.0], atol=1e-3)


def test_a_full_body_places_its_hand_sensor_on_the_hand():
    """The full layout's sensors sit on its own body: the left arm turning about the shoulder at
    omega (lateral axis), the hand's sensor, halfway down the hand, reads the centripetal
    acceleration of its distance from the shoulder."""
    from limbstream.body import FULL, Body

    omega = 1.5
    arm = [FULL.segment_index[s] for s in ("l_upperarm", "l_lowerarm", "l_hand")]

    def swing(t):
        q = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), len(FULL.segments), 1))
        q[:, arm] = quat.from_rotation(Rotation.from_rotvec(np.outer(omega * t, [1.0, 0.0, 0.0])))[:, None]
        return q

    t = np.arange(round(6.0 * 50) + 1) / 50
    m = Motion(t, swing(t), FULL.segment_names, "test", "standing")
    r = ideal(m)
    keep = middle(r, 1.5)
    lengths = Body.default(FULL).lengths
    radius = lengths["l_upperarm"] + lengths["l_lowerarm"] + 0.5 * lengths["l_hand"]
    h = FULL.segment_index["l_hand"]
    seg = Rotation.from_quat(r.q[keep, h][:, [1, 2, 3, 0]])
    want = np.array([0.0, omega**2 * radius, 0.0]) + seg.inv().apply([0.0, G, 0.0])
    assert np.abs(r.acc[keep, h] - want).max() < 2e-3, np.abs(r.acc[keep, h] - want).max()
    still = [FULL.segment_index[s] for s in ("hip", "chest", "l_foot")]
    assert np.abs(r.acc[keep][:, still] - [0.0, G, 0.0]).max() < 1e-6  # the rest of the body stands still


def test_root_travel_reaches_every_sensor():
    a0 = np.array([0.8, -0.3, 1.5])  # m/s^2, constant
    still = np.tile([1.0, 0.0, 0.0, 0.0], (1, 10, 1))
    m = motion_of(lambda t: np.repeat(still, len(t), axis=0), root_fn=lambda t: 0.5 * np.outer(t**2, a0))
    r = ideal(m)
    keep = middle(r)
    assert np.abs(r.acc[keep] - (a0 + [0.0, G, 0.0])).max() < 1e-6, np.abs(r.acc[keep] - (a0 + [0.0, G, 0.0])).max()


def test_mounting_turns_the_readings_into_the_sensor_frame():
    m = generate(4.0, fs=50.0, seed=3)
    r = ideal(m)
    devices = imu.ImuDevices(10, imu.model("ideal"), RATE, SensorModel(mounting_deg=120.0, seed=4))
    n = len(r.t)
    gyr, acc = devices.read(np.tile(np.arange(10), n), np.repeat(np.arange(n), 10),
                            r.gyr.reshape(-1, 3), r.acc.reshape(-1, 3))
    gyr, acc = gyr.reshape(n, 10, 3), acc.reshape(n, 10, 3)
    sensor = quat.multiply(r.q, devices.mounting[None])  # world <- sensor
    # the mounted sensor's rate integrates to its own orientation; its force is the same vector
    integrated = Rotation.from_quat(sensor[0][:, [1, 2, 3, 0]])
    for k in range(1, n):
        integrated = integrated * Rotation.from_rotvec(gyr[k] / RATE)
    assert quat.angle_deg(quat.from_rotation(integrated), sensor[-1]).max() < 1e-6
    assert np.allclose(quat.rotate(sensor, acc), quat.rotate(r.q, r.acc), atol=1e-9)


def test_ideal_part_adds_nothing_and_a_real_part_its_datasheet():
    n, m = 4, 40000
    devices = np.repeat(np.arange(n), m // n)
    k = np.tile(np.arange(m // n), n)
    zero = np.zeros((m, 3))
    g, a = imu.ImuDevices(n, imu.model("ideal"), RATE).read(devices, k, zero, zero + [0, G, 0])
    assert np.all(g == 0.0) and np.all(a == [0.0, G, 0.0])
    part = imu.model("icm42688p")
    icm = imu.ImuDevices(n, part, RATE, SensorModel(seed=7))
    g, a = icm.read(devices, k, zero, zero)
    lsb_g, lsb_a = np.radians(2000.0) / 32768, 16 * G / 32768
    assert np.allclose(g / lsb_g, np.round(g / lsb_g)) and np.allclose(a / lsb_a, np.round(a / lsb_a))
    assert np.all(np.abs(icm.gyro_offset) <= np.radians(0.5)) and np.all(np.abs(icm.accel_offset) <= 0.020 * G)
    early = k < 200  # the first second: before the sensor warms; the mean is the turn-on offset
    for d in range(n):
        mine = (devices == d) & early
        assert np.allclose(g[mine].mean(axis=0), icm.gyro_offset[d], atol=np.radians(0.01))
    spread = np.concatenate([g[devices == d] - g[devices == d].mean(axis=0) for d in range(n)])
    # the noise density over the Nyquist band, and the rounding to the 16-bit grid (LSB^2 / 12)
    want = np.hypot(np.radians(0.0028) * np.sqrt(RATE / 2), lsb_g / np.sqrt(12))
    assert abs(spread.std() / want - 1) < 0.03, (spread.std(), want)
    # a reading beyond the full scale saturates at it
    g, a = icm.read(np.zeros(1, int), np.zeros(1, int), np.array([[100.0, 0, 0]]), np.array([[0, 0, -1e3]]))
    assert g[0, 0] == pytest.approx(np.radians(2000.0) * 32767 / 32768) and a[0, 2] == pytest.approx(-16 * G)
    # and is found at it: a clipped rate or force, not a reading one count inside the scale
    inside = np.radians(2000.0) * 32765 / 32768
    gyr = np.vstack([g, [[0.0, -inside, 0.0]], [[0.0, 0.0, 0.0]]])
    acc = np.vstack([[[0.0, G, 0.0]], [[0.0, G, 0.0]], a])
    assert part.at_full_scale(gyr, acc).tolist() == [True, False, True]
    assert not imu.model("ideal").at_full_scale(gyr * 100, acc * 100).any()


def test_a_device_reads_the_same_one_tick_at_a_time_as_in_a_whole_recording():
    motion = generate(3.0, fs=50.0, seed=5)
    model, sensors = imu.model("icm42688p"), SensorModel(mounting_deg=90.0, heading_deg=180.0, seed=2)
    whole = imu.record(motion, imu.ImuDevices(10, model, RATE, sensors), script=False)
    feed, devices = imu.ReadingFeed(motion, RATE, once=True, script=False), imu.ImuDevices(10, model, RATE, sensors)
    rng = np.random.default_rng(0)
    gyr = np.full(whole.gyr.shape, np.nan)
    start = 0
    while start < feed.length:  # ticks of 1-7 samples, devices in shuffled order, crossing noise blocks
        k = np.arange(start, min(start + int(rng.integers(1, 8)), feed.length))
        order = rng.permutation(10)
        r = feed.readings(k)
        g, _ = devices.read(np.tile(order, len(k)), np.repeat(k, 10), r.gyr[:, order].reshape(-1, 3),
                            r.acc[:, order].reshape(-1, 3))
        gyr[k[:, None], order[None]] = g.reshape(len(k), 10, 3)
        start = k[-1] + 1
    assert feed.length > BLOCK and np.array_equal(gyr, whole.gyr)


def test_raw_sensors_refuse_the_drift_formula():
    with pytest.raises(ValueError, match="yaw-drift-dps"):
        imu.ImuDevices(2, imu.model("ideal"), RATE, SensorModel(yaw_drift_dps=0.1))
    with pytest.raises(ValueError, match="imu-model"):
        imu.model("mpu6050")


STILL_DPS, STILL_MS2 = 0.5, 0.05
"""A still sensor as VQF's rest detection sees it (its thresholds: 2 deg/s, 0.5 m/s^2)."""


def assert_still(r):
    assert np.degrees(np.abs(r.gyr)).max() < STILL_DPS, np.degrees(np.abs(r.gyr)).max()
    assert np.abs(np.linalg.norm(r.acc, axis=-1) - G).max() < STILL_MS2


def test_the_script_is_still_where_calibration_reads_it_and_loops_join_smoothly():
    motion = generate(6.0, fs=50.0, seed=1)
    feed = imu.ReadingFeed(motion, RATE)  # looped, each pass with the script
    rest = np.arange(round(STILL_MARGIN_S * RATE), round((REST_S - STILL_MARGIN_S) * RATE))
    assert_still(feed.readings(rest))
    once = imu.ReadingFeed(motion, RATE, once=True)
    period = once.length + round(0.5 * RATE)  # the pass plus the move back to the rest pose
    r = feed.readings(np.arange(period - 400, period + 400))  # no jump where one pass joins the next
    assert np.degrees(np.abs(r.gyr)).max() < 1000 and np.abs(r.acc).max() < 3 * G
    assert_still(feed.readings(period + rest))  # the next pass is in its rest pose again
    with pytest.raises(IndexError):
        once.readings(np.array([once.length]))


def test_the_generator_streams_endlessly_with_the_script_first():
    feed = imu.ReadingFeed(GeneratorSource(seed=4), RATE)
    assert feed.length is None
    assert_still(feed.readings(np.arange(round(0.5 * RATE), round(2.5 * RATE))))
    far = feed.readings(np.arange(100_000, 100_010))  # 500 s on
    assert np.isfinite(far.acc).all() and np.degrees(np.abs(far.gyr)).max() < 1000


def test_vqf_6d_recovers_a_still_sensors_inclination():
    q = quat.from_rotation(Rotation.random(10, random_state=3))
    m = motion_of(lambda t: np.broadcast_to(q, (len(t), 10, 4)).copy(), seconds=6.0)
    rec = imu.record(m, imu.ImuDevices(10, imu.model("ideal"), RATE), script=False)
    estimate = reference_vqf(rec.gyr, rec.acc, RATE)
    for s in range(10):
        e = fusion_error(estimate[:, s], rec.truth[:, s], rec.t, align_heading=True)
        assert e.inclination_deg < 0.05 and abs(e.heading_drift_dpm) < 0.01, (s, e)


def test_vqf_6d_on_an_ideal_cmu_clip_recovers_every_inclination(cmu_npz):
    clip = next(m for m in load(cmu_npz) if m.name == "02_01")  # a walk
    rec = imu.record(clip, imu.ImuDevices(10, imu.model("ideal"), RATE))
    estimate = reference_vqf(rec.gyr, rec.acc, RATE)
    for s, segment in enumerate(rec.segments):
        e = fusion_error(estimate[:, s], rec.truth[:, s], rec.t, rec.movement, align_heading=True)
        assert e.inclination_deg < 1.5 and abs(e.heading_drift_dpm) < 1.0, (segment, e)


def test_a_start_heading_turns_the_filters_earth_frame():
    m = generate(12.0, fs=50.0, seed=2)
    devices = imu.ImuDevices(10, imu.model("icm42688p"), RATE, SensorModel(90.0, 180.0, 0.0, 1))
    rec = imu.record(m, devices)
    turned = imu.earth_heading(devices.heading)
    # 6D: starting the filter turned is turning its every output, but for its motion bias estimate,
    # which clips its correction per earth axis
    for motion_bias, bound in ((False, 1e-5), (True, 0.05)):  # 1e-5: angle_deg's resolution
        started, plain = (np.stack([vqf_6d(rec, s, heading, motion_bias) for s in range(10)], axis=1)
                          for heading in (turned, None))
        worst = quat.angle_deg(started, quat.multiply(turned[None], plain)).max()
        assert worst < bound, (motion_bias, worst)
    assert np.allclose(reference_vqf(rec.gyr, rec.acc, RATE, start_heading=turned)[:, 3], vqf_6d(rec, 3, turned, True))


def vqf_6d(rec, s, heading, motion_bias):
    """PyPI VQF 6D on sensor s of rec, started at heading[s] (or identity)."""
    from vqf import VQF

    f = VQF(1.0 / RATE)
    f.setMotionBiasEstEnabled(motion_bias)
    if heading is not None:
        state = f.state
        state["gyrQuat"] = heading[s]
        f.state = state
    return f.updateBatch(np.ascontiguousarray(rec.gyr[:, s]), np.ascontiguousarray(rec.acc[:, s]))["quat6D"]


def test_bvh_clips_bring_their_root_path_in_metres(cmu_bvh_dir):
    m = bvh.load_bvh(cmu_bvh_dir / "02_01.bvh")  # a walk, resampled to 50 Hz
    native = bvh.load_bvh(cmu_bvh_dir / "02_01.bvh", fs=None)
    assert m.root.shape == (len(m.t), 3) and native.root.shape == (len(native.t), 3)
    assert 0.9 < np.median(m.root[:, 1]) < 1.2  # pelvis height of the default skeleton's scale
    speed = np.linalg.norm(np.diff(native.root[:, [0, 2]], axis=0), axis=1) * native.fs
    assert 0.8 < np.median(speed) < 2.0  # walking pace, m/s
    assert np.allclose(np.interp(m.t, native.t, native.root[:, 2]), m.root[:, 2])


def test_uneven_samples_are_refused():
    t = np.array([0.0, 0.02, 0.05, 0.06, 0.08])
    m = Motion(t, np.tile([1.0, 0.0, 0.0, 0.0], (5, 10, 1)), SEGMENTS, "jitter")
    for script in (True, False):
        with pytest.raises(ValueError, match="evenly spaced"):
            imu.ReadingFeed(m, RATE, script=script)
