"""The synthetic full-body motion generator: determinism, streaming, plausibility."""

from __future__ import annotations

import numpy as np
import pytest

from limbstream import quat
from limbstream.sources import SEGMENTS
from limbstream.sources.generator import (
    ACTIVITIES,
    JOINT_RANGES,
    JOINTS,
    NOISE_BLOCK,
    GeneratorSource,
    generate,
)

FS = 50.0
MAX_STEP_DEG = 15.0  # largest orientation change between consecutive samples at 50 Hz

# Normal active range of motion, degrees (AAOS / Norkin & White tables; flexion, abduction and
# internal rotation positive): the generator's own JOINT_RANGES must sit inside these.
HUMAN_ROM = {
    "hip_flex": (-30, 125),
    "hip_abd": (-30, 45),
    "hip_rot": (-45, 45),
    "knee_flex": (0, 145),
    "shoulder_flex": (-60, 180),
    "shoulder_abd": (0, 180),
    "shoulder_rot": (-90, 90),
    "elbow_flex": (0, 150),
    "trunk_flex": (-30, 80),
    "trunk_lat": (-35, 35),
    "trunk_rot": (-45, 45),
    "neck_flex": (-60, 70),
    "neck_lat": (-45, 45),
    "neck_rot": (-80, 80),
    "pelvis_tilt": (-30, 30),
    "pelvis_obliquity": (-20, 20),
    "pelvis_yaw": (-30, 30),
    "ankle_flex": (-50, 35),  # dorsiflexion positive; loaded (a lunge, a landing): about 35-45, unloaded 20
    "subtalar": (-15, 35),  # inversion positive
    "wrist_flex": (-70, 80),
    "wrist_dev": (-20, 30),  # ulnar deviation positive
}


def _rom(joint: str) -> tuple[float, float]:
    return HUMAN_ROM[joint.removesuffix("_l").removesuffix("_r")]


@pytest.fixture(scope="module")
def default_run():
    """Two loops of the default schedule for subject 0."""
    source = GeneratorSource(seed=0, fs=FS)
    motion = source.motion(2 * source.period_s)
    return source, motion


def test_shape_units_and_names(default_run):
    source, motion = default_run
    assert motion.segments == SEGMENTS and motion.q.shape == (len(motion.t), 10, 4)
    np.testing.assert_allclose(np.diff(motion.t), 1 / FS, atol=1e-12)
    err = np.abs(np.linalg.norm(motion.q, axis=-1) - 1).max()
    assert err < 1e-12, f"norm error {err}"
    labels = set(source.activity_at(motion.t))
    assert labels == set(ACTIVITIES) | {"transition"}, labels


def test_same_seed_identical_other_seed_different():
    a = generate(20.0, seed=7, noise_deg=1.0, mounting_offsets=True)
    b = generate(20.0, seed=7, noise_deg=1.0, mounting_offsets=True)
    np.testing.assert_array_equal(a.q, b.q)
    c = generate(20.0, seed=8, noise_deg=1.0, mounting_offsets=True)
    dev = quat.angle_deg(a.q, c.q)
    assert np.median(dev) > 1.0, (
        f"seeds 7 and 8 differ by a median of {np.median(dev):.3g} deg only"
    )


@pytest.mark.parametrize("noise, mounting", [(0.0, False), (1.5, True)])
def test_chunks_and_samples_equal_the_batch(noise, mounting):
    source = GeneratorSource(seed=3, fs=FS, noise_deg=noise, mounting_offsets=mounting)
    batch = generate(60.0, FS, seed=3, noise_deg=noise, mounting_offsets=mounting)
    for start, count in [(0, 1), (5, 200), (NOISE_BLOCK - 3, 10), (2 * NOISE_BLOCK + 17, 700)]:
        t, q = source.chunk(start, count)
        np.testing.assert_allclose(t, batch.t[start : start + count], atol=1e-12)
        dev = quat.angle_deg(q, batch.q[start : start + count]).max()
        assert dev < 1e-5, f"chunk({start}, {count}) deviates {dev:.3g} deg from the batch"
    for k in (0, 1234, 2999):
        assert quat.angle_deg(source.sample(k), batch.q[k]).max() < 1e-5, k
    # far beyond the batch: still defined, unit norm, continuous with its neighbour
    _, far = source.chunk(10_000_000, 2)
    assert np.abs(np.linalg.norm(far, axis=-1) - 1).max() < 1e-12


def test_joint_angles_within_human_range(default_run):
    source, motion = default_run
    angles = source.joint_angles(motion.t)
    assert set(angles) == set(JOINTS) == set(JOINT_RANGES)
    for joint, (lo, hi) in JOINT_RANGES.items():
        rom_lo, rom_hi = _rom(joint)
        assert rom_lo <= lo and hi <= rom_hi, (
            f"{joint}: declared range {lo, hi} outside human {rom_lo, rom_hi}"
        )
    for seed in (0, 1, 2, 3):
        src = GeneratorSource(seed=seed, fs=FS)
        angles = src.joint_angles(np.arange(0, 2 * src.period_s, 1 / FS))
        for joint, (lo, hi) in JOINT_RANGES.items():
            v = angles[joint]
            assert lo <= v.min() and v.max() <= hi, (
                f"seed {seed} {joint}: [{v.min():.1f}, {v.max():.1f}] outside [{lo}, {hi}]"
            )


def test_hinge_joints_match_relative_segment_rotation(default_run):
    source, motion = default_run
    angles = source.joint_angles(motion.t)
    q = {s: motion.segment(s) for s in SEGMENTS}
    for side in ("l", "r"):
        knee = quat.angle_deg(q[f"{side}_thigh"], q[f"{side}_shank"])
        elbow = quat.angle_deg(q[f"{side}_upperarm"], q[f"{side}_lowerarm"])
        for name, measured in ((f"knee_flex_{side}", knee), (f"elbow_flex_{side}", elbow)):
            dev = np.abs(measured - np.abs(angles[name])).max()
            assert dev < 1e-4, (
                f"{name}: relative rotation differs from the joint angle by {dev:.3g} deg"
            )


def test_no_discontinuities(default_run):
    _, motion = default_run
    step = quat.angle_deg(motion.q[1:], motion.q[:-1])
    worst = dict(zip(SEGMENTS, step.max(axis=0).round(2)))
    assert step.max() < MAX_STEP_DEG, f"max step per segment {worst}"
    dots = np.sum(motion.q[1:] * motion.q[:-1], axis=-1)
    assert dots.min() > 0, "quaternion sign flips between consecutive samples"
    noisy = generate(120.0, FS, seed=0, noise_deg=1.0)
    assert np.sum(noisy.q[1:] * noisy.q[:-1], axis=-1).min() > 0


def test_segment_directions_follow_the_activity():
    """Hanging limbs point along -Y in their segment frame; check where they point in the world."""
    down = np.array([0.0, -1.0, 0.0])
    walk = GeneratorSource(seed=2, fs=FS, activities="walking")
    t = np.arange(0, 10, 1 / FS)
    q = walk.orientations(t)
    a = walk.joint_angles(t)
    forward = quat.rotate(q[:, SEGMENTS.index("hip")], [0.0, 0.0, 1.0])
    thigh = quat.rotate(q[:, SEGMENTS.index("l_thigh")], down)
    k = np.argmax(a["hip_flex_l"])
    assert np.dot(thigh[k], forward[k]) > 0.3, "a flexed hip swings the thigh forward"
    jacks = GeneratorSource(seed=2, fs=FS, activities="jumping_jacks")
    a = jacks.joint_angles(t)
    k = np.argmax(a["shoulder_abd_l"])
    q = jacks.orientations(t[k : k + 1])[0]
    left = quat.rotate(q[SEGMENTS.index("hip")], [1.0, 0.0, 0.0])
    arm = quat.rotate(q[SEGMENTS.index("l_upperarm")], down)
    assert arm[1] > 0.75 and np.dot(arm, left) > 0, f"arm overhead and to the left, got {arm}"
    shank = quat.rotate(q[SEGMENTS.index("l_shank")], down)
    assert shank[1] < -0.8, f"legs stay below the hip, shank direction {shank}"


def _dominant_hz(x: np.ndarray, fs: float) -> float:
    spec = np.abs(np.fft.rfft(x - x.mean()))
    return float(np.fft.rfftfreq(len(x), 1 / fs)[np.argmax(spec)])


@pytest.mark.parametrize("activity, steps_hz", [("walking", 1.8), ("running", 2.7)])
def test_cadence(activity, steps_hz):
    """The thigh swings once per stride (two steps); measured from the orientations."""
    rates = []
    for seed in (0, 1, 2):
        m = generate(60.0, FS, seed=seed, activities=activity)
        hip = quat.angle_deg(m.segment("hip"), m.segment("l_thigh"))
        rates.append(2 * _dominant_hz(hip, FS))
    assert all(0.9 * steps_hz < r < 1.1 * steps_hz for r in rates), f"{activity}: steps/s {rates}"
    assert len(set(np.round(rates, 3))) > 1, f"subjects share one cadence {rates}"


def test_noise_and_mounting_offsets():
    clean = generate(60.0, FS, seed=4)
    noisy = generate(60.0, FS, seed=4, noise_deg=2.0)
    rms = np.sqrt(np.mean(quat.angle_deg(clean.q, noisy.q) ** 2))
    assert 1.8 < rms < 2.2, f"RMS noise {rms:.3f} deg, asked for 2"
    mounted = generate(60.0, FS, seed=4, mounting_offsets=True)
    offset = quat.angle_deg(clean.q, mounted.q)
    assert np.ptp(offset, axis=0).max() < 1e-5, "a mounting offset is constant in time"
    assert np.all((offset[0] > 4.99) & (offset[0] < 15.01)), f"offsets {offset[0]}"


def test_transitions_are_cross_fades():
    source = GeneratorSource(seed=5, fs=FS, activities=[("standing", 4.0), ("jumping_jacks", 4.0)])
    t = np.arange(0, 16, 1 / FS)
    labels = source.activity_at(t)
    assert labels[0] == "standing" and labels[int(4.5 * FS)] == "transition"
    assert labels[int(6 * FS)] == "jumping_jacks" and labels[int(8.5 * FS)] == "transition"
    abd = source.joint_angles(t)["shoulder_abd_l"]
    assert np.abs(np.diff(abd)).max() < 20.0, "joint angles change smoothly through transitions"


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"activities": "swimming"}, "unknown activity 'swimming'"),
        ({"activities": [("walking", 1.0)]}, "must exceed"),
        ({"activities": []}, "empty"),
        ({"fs": 0.0}, "fs must be > 0"),
        ({"noise_deg": -1.0}, "noise_deg must be >= 0"),
        ({"seed": -1}, "seed must be >= 0"),
    ],
)
def test_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        GeneratorSource(**kwargs)


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_the_default_motion_holds_the_rest_pose_still_about_every_30_s(seed):
    """Twice a loop the default motion stands perfectly still in the rest pose (every segment at
    the subject's heading alone) for STILL_S seconds: no still moment is more than 33 s from the
    last one, so a rest calibration asked for at any time finds one soon."""
    from limbstream.sources.generator import STILL_S
    src = GeneratorSource(seed, FS)
    t = np.arange(0, 2 * src.period_s, 1 / FS)
    q = src.orientations(t)
    heading = np.broadcast_to(q[:, :1], q.shape)
    rest = quat.angle_deg(q.reshape(-1, 4), heading.reshape(-1, 4)).reshape(len(t), -1).max(axis=1) < 1e-6
    still = rest[1:] & rest[:-1] & (quat.angle_deg(q[1:].reshape(-1, 4), q[:-1].reshape(-1, 4))
                                    .reshape(len(t) - 1, -1).max(axis=1) < 1e-9)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]])))
    runs = edges.reshape(-1, 2) / FS  # (start, end) s of each still run
    assert len(runs) >= 4 and ((runs[:, 1] - runs[:, 0]) >= STILL_S - 2 / FS).all(), runs
    assert np.diff(runs[:, 0]).max() <= 33.0 and runs[0, 0] <= 33.0, runs
    assert set(src.activity_at(runs[:, 0] + 1.0)) == {"still"}
