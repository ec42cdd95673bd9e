"""Joint angles (limbstream.joints): the convention against independent computations (scipy's
Euler sequences, the generator's own joint angles, constructed poses), gimbal lock, missing
segments, the functional calibration of the facing, and the error figures."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from limbstream import calibration, quat, wire
from limbstream.joints import (ANGLES, GIMBAL, JOINT_TABLE, MISSING, TO_OPENSIM, UNCALIBRATED, Facing, HingeStats,
                               angle_errors, euler_zxy, face, functional_calibration, joint_angles, true_angles)
from limbstream.sources import Motion, generator, imu_files

SEG = {name: i for i, name in enumerate(wire.SEGMENTS)}
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
X, Y, Z = np.eye(3)


def turn(axis, deg) -> np.ndarray:
    return calibration.axis_angle(np.asarray(axis, np.float64), np.radians(deg))


def rest(n: int = 1) -> np.ndarray:
    return np.tile(IDENTITY, (n, len(wire.SEGMENTS), 1))


def angle(values: np.ndarray, name: str):
    return values[..., ANGLES.index(name)]


def test_euler_zxy_matches_scipy_intrinsic_zxy():
    rng = np.random.default_rng(1)
    q = quat.from_rotation(Rotation.random(2000, random_state=rng))
    mine, near = euler_zxy(q)
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("ZXY")
    keep = ~near
    diff = np.remainder(mine[keep] - ref[keep] + math.pi, 2 * math.pi) - math.pi
    assert np.abs(diff).max() < 1e-9, np.abs(diff).max()
    assert near.mean() < 0.2


def test_constructed_poses_give_back_their_angles_in_every_joint():
    """Each joint's child is its parent turned by Rz(a) Rx(b) Ry(c) in OpenSim's axes (scipy
    builds the rotation); the angles read back with the model's signs, whatever the parent's
    orientation."""
    rng = np.random.default_rng(2)
    n = 300
    truth = {name: rng.uniform(-60.0, 60.0, n) for name in ANGLES}
    q = np.tile(IDENTITY, (n, len(wire.SEGMENTS), 1))
    q[:, SEG["hip"]] = quat.from_rotation(Rotation.random(n, random_state=rng))  # any pelvis, any facing
    to_limbstream = quat.conjugate(TO_OPENSIM)
    for joint in JOINT_TABLE:  # parents come before their children in the table
        zxy = np.stack([truth[a] * s if a else np.zeros(n) for a, s in zip(joint.angles, joint.signs)], axis=1)
        local = quat.from_rotation(Rotation.from_euler("ZXY", zxy, degrees=True))  # OpenSim's axes
        local = quat.multiply(quat.multiply(to_limbstream, local), TO_OPENSIM)
        q[:, SEG[joint.child]] = quat.multiply(q[:, SEG[joint.parent]], local)
    got, flags = joint_angles(q)
    assert not flags.any()
    for name in ANGLES:
        err = np.abs(angle(got, name) - truth[name]).max()
        assert err < 1e-6, (name, err)


def test_named_poses_have_the_models_signs():
    q = rest(1)[0]
    q[SEG["r_shank"]] = turn(X, 40)        # the shank swings back: knee flexion
    q[SEG["l_shank"]] = turn(-X, 5)        # ... forward past straight: hyperextension
    q[SEG["r_thigh"]] = turn(-X, 30)       # the thigh forward: hip flexion
    q[SEG["r_shank"]] = quat.multiply(q[SEG["r_thigh"]], turn(X, 40))
    q[SEG["l_thigh"]] = turn(-Z, 10)       # the left thigh towards the midline (-X): adduction
    q[SEG["l_shank"]] = quat.multiply(q[SEG["l_thigh"]], turn(-X, 5))
    q[SEG["r_upperarm"]] = turn(Y, 20)     # the right arm's front turned to the left (medial): internal rotation
    q[SEG["r_lowerarm"]] = quat.multiply(q[SEG["r_upperarm"]], turn(-X, 90))  # elbow flexion
    q[SEG["l_upperarm"]] = turn(Z, 45)     # the left arm out sideways: abduction (negative adduction)
    q[SEG["l_lowerarm"]] = q[SEG["l_upperarm"]]
    q[SEG["neck"]] = turn(-X, 15)          # the head back: extension
    got, flags = joint_angles(q)
    expect = {"knee_angle_r": 40, "knee_angle_l": -5, "hip_flexion_r": 30, "hip_adduction_l": 10,
              "arm_rot_r": 20, "elbow_flex_r": 90, "arm_add_l": -45, "elbow_flex_l": 0, "neck_extension": 15,
              "hip_flexion_l": 0, "arm_flex_r": 0}
    for name, value in expect.items():
        assert angle(got, name) == pytest.approx(value, abs=1e-9), name
    assert not flags.any()


def test_knee_and_elbow_match_the_generators_own_angles():
    """The generator builds each shank from its thigh turned about +X by its knee flexion and each
    forearm about -X by its elbow flexion: the same angles must come back, through every activity."""
    source = generator.GeneratorSource(seed=3, fs=50.0)
    t = np.arange(0.0, source.period_s, 0.02)
    got, flags = joint_angles(source.orientations(t))
    truth = source.joint_angles(t)
    for mine, theirs in (("knee_angle_l", "knee_flex_l"), ("knee_angle_r", "knee_flex_r"),
                         ("elbow_flex_l", "elbow_flex_l"), ("elbow_flex_r", "elbow_flex_r")):
        err = np.abs(angle(got, mine) - truth[theirs]).max()
        assert err < 1e-6, (mine, err)
        assert np.ptp(truth[theirs]) > 30
    assert not (flags & ~np.uint8(GIMBAL)).any()


def test_gimbal_lock_is_flagged_and_still_reproduces_the_rotation():
    """The left arm raised sideways to horizontal (a T-pose arm) is the shoulder's lock: flexion
    and rotation are flagged, adduction is -90 exactly, and the angles still compose to the arm."""
    q = rest(3)
    for k, (tilt, twist) in enumerate(((90.0, 0.0), (90.0, 30.0), (85.0, 30.0))):
        q[k, SEG["l_upperarm"]] = quat.multiply(turn(Z, tilt), turn(Y, twist))
        q[k, SEG["l_lowerarm"]] = q[k, SEG["l_upperarm"]]
    got, flags = joint_angles(q)
    for name in ("arm_flex_l", "arm_rot_l"):
        assert (angle(flags, name) & GIMBAL).all(), name
    assert not (angle(flags, "arm_add_l") & GIMBAL).any()
    assert angle(got, "arm_add_l")[:2] == pytest.approx([-90.0, -90.0], abs=1e-6)
    assert angle(got, "arm_rot_l")[:2] == pytest.approx([0.0, 0.0], abs=1e-9)  # at the lock: third set to 0
    for k in range(3):
        zxy = [angle(got, "arm_flex_l")[k], -angle(got, "arm_add_l")[k], -angle(got, "arm_rot_l")[k]]
        built = quat.from_rotation(Rotation.from_euler("ZXY", zxy, degrees=True))
        seen = quat.multiply(quat.multiply(TO_OPENSIM, q[k, SEG["l_upperarm"]]), quat.conjugate(TO_OPENSIM))
        assert quat.angle_deg(built, seen) < 1e-4
    assert not (angle(flags, "arm_flex_r") & GIMBAL).any()


def test_tpose_data_is_brought_to_the_standing_rest_pose():
    q = rest(1)
    got, flags = joint_angles(q, rest_pose="tpose")
    assert angle(got, "arm_add_l")[0] == pytest.approx(-90.0) and angle(got, "arm_add_r")[0] == pytest.approx(-90.0)
    lowered = q.copy()  # arms hanging, in T-pose terms: the left arm's +X bone turned to -Y
    lowered[0, [SEG["l_upperarm"], SEG["l_lowerarm"]]] = turn(Z, -90)
    lowered[0, [SEG["r_upperarm"], SEG["r_lowerarm"]]] = turn(Z, 90)
    got, flags = joint_angles(lowered, rest_pose="tpose")
    assert np.abs(got).max() < 1e-9 and not flags.any()


def test_a_missing_segment_and_an_uncalibrated_subject_give_no_numbers():
    """Frames x subjects at once: subject 1 lacks its right shank, subject 2 is not calibrated."""
    q = np.tile(IDENTITY, (4, 3, len(wire.SEGMENTS), 1))
    q[..., SEG["r_shank"], :] = turn(X, 30)
    present = np.ones((4, 3, len(wire.SEGMENTS)), bool)
    present[:, 1, SEG["r_shank"]] = False
    q[:, 1, SEG["l_shank"]] = np.nan  # no data at all: missing too
    got, flags = joint_angles(q, present, calibrated=np.array([True, True, False]))
    assert angle(got, "knee_angle_r")[:, 0] == pytest.approx(np.full(4, 30.0))
    for name in ("knee_angle_r", "knee_angle_l"):
        assert np.isnan(angle(got, name)[:, 1]).all() and (angle(flags, name)[:, 1] == MISSING).all()
    assert angle(got, "hip_flexion_r")[:, 1] == pytest.approx(np.zeros(4))
    assert np.isnan(got[:, 2]).all() and (flags[:, 2] & UNCALIBRATED).all()


def walk_with_still_start(seed: int, fs: float = 50.0) -> tuple[np.ndarray, np.ndarray, float]:
    """A generated walk after one still second standing (the subject facing its own heading):
    (m, 10, 4) orientations, (m,) true knee flexion of the left knee, the subject's heading."""
    source = generator.GeneratorSource(seed=seed, fs=fs, activities="walking")
    t = np.arange(round(6 * fs)) / fs + 3.0
    heading = source._subject.heading
    still = np.tile(calibration.yaw(np.radians(heading)), (round(fs), len(wire.SEGMENTS), 1))
    q = np.concatenate([still, source.orientations(t)])
    knee = np.concatenate([np.zeros(len(still)), source.joint_angles(t)["knee_flex_l"]])
    return q, knee, math.radians(heading)


def facing_of(rest: np.ndarray) -> tuple[np.ndarray, Facing]:
    """The anatomical orientations of rest-calibrated segments (m, 10, 4) and the facing the
    hinges told (as the export finds it)."""
    stats = HingeStats.empty()
    stats.add(rest)
    facing = stats.facing()
    return face(rest, facing.heading), facing


@pytest.mark.parametrize("up", ["y", "z"])
def test_functional_calibration_finds_the_facing_of_shared_heading_sensors(up):
    """Sensors in one world (heading h, their world's up axis ``up``), strapped on with any
    mounting: the rest calibration of the still second (an IMU recording's loader for a Z-up
    world, ``imu_files.to_body``) leaves the facing; the knees give it."""
    q, knee, heading = walk_with_still_start(seed=4)
    h = math.radians(70.0)
    mounting = quat.from_rotation(Rotation.random(len(wire.SEGMENTS), random_state=5))
    world = quat.multiply(calibration.axis_angle(X, math.pi / 2) if up == "z" else IDENTITY, calibration.yaw(h))
    readings = quat.multiply(quat.multiply(world, q), mounting)
    if up == "z":
        motion = imu_files.to_body(Motion(np.arange(len(q)) / 50.0, readings, wire.SEGMENTS, "walk",
                                          orientations="sensors"))
        assert motion.orientations == "rest"
        rest_q = motion.q
    else:
        rest_q = calibration.calibrate_start(readings, 50.0, wire.SEGMENTS)
    anatomical, facing = facing_of(rest_q)
    assert facing.counted[:2].all()
    want = math.remainder(h + heading - float(facing.heading), math.tau)
    assert abs(math.degrees(want)) < 0.5, facing.describe()
    got, flags = joint_angles(anatomical)
    truth, _ = joint_angles(q)  # the body's own angles
    assert np.nanmax(np.abs(got - truth)) < 0.5
    assert np.abs(angle(got, "knee_angle_l") - knee).max() < 0.5


def test_functional_calibration_finds_no_facing_for_a_subject_that_did_not_move():
    _, facing = facing_of(rest(200))
    assert not facing.found and "no facing" in facing.describe()


def test_hinge_stats_are_incremental_and_batch_over_subjects():
    q, _, _ = walk_with_still_start(seed=6)
    other = face(q, np.full(len(q), 1.0))  # a second subject: the same walk turned
    whole = HingeStats.empty()
    whole.add(q)
    parts = HingeStats.empty()
    for chunk in np.array_split(q, 7):
        parts.add(chunk)
    assert parts.scatter == pytest.approx(whole.scatter) and parts.n == pytest.approx(whole.n)
    both = HingeStats.empty((2,))
    both.add(np.stack([q, other]))
    facing = both.facing()
    assert facing.heading[0] == pytest.approx(float(whole.facing().heading), abs=1e-9)
    assert math.remainder(float(facing.heading[1] - facing.heading[0]) + 1.0, math.tau) == pytest.approx(0.0, abs=1e-3)
    early = HingeStats.empty()
    early.add(q[:30])  # the still second only: nothing to tell yet
    assert not early.facing().found and "no facing" in early.facing().describe()


def test_functional_calibration_object_gives_the_anatomical_frame():
    h, m = 1.1, quat.from_rotation(Rotation.from_rotvec([0.3, -0.5, 0.2]))
    body = turn([0.2, 0.9, 0.1], 40)
    reading = quat.multiply(quat.multiply(calibration.yaw(h), body), m)
    cal = calibration.Calibration.rest(quat.multiply(calibration.yaw(h), m))
    done = functional_calibration(cal, h)
    assert done.poses == ("rest", "functional")
    assert quat.angle_deg(done.apply(reading[None])[0], body) < 1e-4


def test_true_angles_and_error_figures():
    source = generator.GeneratorSource(seed=7, fs=50.0, activities="walking")
    motion = source.motion(4.0)
    truth, flags = true_angles(motion)
    assert angle(truth, "knee_angle_r") == pytest.approx(source.joint_angles(motion.t)["knee_flex_r"], abs=1e-6)
    estimate = truth + 2.0
    estimate[:10, 0] += 20.0  # 10 frames of hip_flexion_r off by 22 deg
    errors = angle_errors(estimate, truth, flags)
    assert errors["knee_angle_r"] == {"mean": pytest.approx(2.0), "p99": pytest.approx(2.0),
                                      "bias": pytest.approx(2.0), "n": len(truth), "gimbal": 0}
    assert errors["hip_flexion_r"]["p99"] == pytest.approx(22.0)
    wrapped = angle_errors(np.full((1, len(ANGLES)), 179.0), np.full((1, len(ANGLES)), -179.0))
    assert wrapped["knee_angle_l"]["bias"] == pytest.approx(-2.0)
    lacking = Motion(motion.t, motion.q[:, 1:], motion.segments[1:], "no left shank")
    assert np.isnan(angle(true_angles(lacking)[0], "knee_angle_l")).all()
    for orientations in ("rest", "sensors"):
        with pytest.raises(ValueError, match="real sensors"):
            true_angles(Motion(motion.t, motion.q, motion.segments, "imu", orientations=orientations))


def test_eval_scores_the_calibrated_angles_against_the_truth(cmu_npz):
    """The emulated target (CMU clips, mounting <= 90 deg, heading +-180 deg, rest and mounting
    poses): knee and elbow flexion within 2 deg on average, hip flexion within 3; the rest pose
    alone, which leaves each sensor's heading, is far off."""
    from limbstream.evaluation import evaluate, streams_of
    from limbstream.sources import load

    streams = streams_of(load(cmu_npz), calibration.SensorModel(mounting_deg=90.0, heading_deg=180.0))
    (row,) = evaluate(streams, ["fastsw"], [9e-4], 25, None, "rate", ("rest", "mounting"), angles=True)
    errors = row["joints"]
    print("\n" + "\n".join(f"{a}: {errors[a]['mean']:.2f} / {errors[a]['p99']:.2f} / {errors[a]['bias']:+.2f}"
                           for a in ANGLES))
    for side in "lr":
        assert errors[f"knee_angle_{side}"]["mean"] <= 2.0 and errors[f"elbow_flex_{side}"]["mean"] <= 2.0
        assert errors[f"hip_flexion_{side}"]["mean"] <= 3.0
        assert abs(errors[f"knee_angle_{side}"]["bias"]) < 0.5
    assert all(e["n"] > 2500 for e in errors.values())
    (rest_only,) = evaluate(streams, ["fastsw"], [9e-4], 25, None, "rate", ("rest",), angles=True)
    assert rest_only["joints"]["hip_flexion_r"]["mean"] > 5.0


def test_eval_joint_angles_table(tmp_path, cmu_npz, xio_dir, capsys):
    """``eval --joint-angles`` prints one line per (row, angle) with a legend; an angle whose
    segments the source lacks shows – (a lower body: no arm angles). It needs explicit rows and
    sources with true angles (motion files, not a recording of real sensors)."""
    from limbstream import cli
    from limbstream.sources import load_npz

    motion = load_npz(cmu_npz)[0]
    legs = [wire.SEGMENTS.index(s) for s in ("hip", "l_thigh", "l_shank", "r_thigh", "r_shank")]
    np.savez(tmp_path / "legs.npz", clip_legs=motion.q[:, legs], fs=np.float64(motion.fs),
             segment_names=np.array([wire.SEGMENTS[k] for k in legs]), rest_pose=np.array(motion.rest_pose))
    assert cli.main(["eval", str(tmp_path / "legs.npz"), "--thresholds", "1e-3,1e-2", "--joint-angles",
                     "--json", str(tmp_path / "rows.json")]) == 0
    text = capsys.readouterr().out
    lines = [line.split() for line in text.split("joint angles of the reconstruction")[1].splitlines()
             if line.startswith("fastsw ")]
    assert [(ln[2], ln[3]) for ln in lines] == [(th, a) for th in ("1.00e-03", "1.00e-02") for a in ANGLES], text
    scored = {ln[3]: ln[4:] for ln in lines if ln[2] == "1.00e-02"}
    assert scored["elbow_flex_r"] == ["–", "–", "–", "0", "0"], scored
    assert float(scored["knee_angle_l"][0]) > 0 and scored["knee_angle_l"][3] == str(len(motion.t)), scored
    assert "  bias (deg)" in text and "  frames " in text and "does not apply to the row" in text and "nan" not in text
    rows = json.loads((tmp_path / "rows.json").read_text())
    assert rows[1]["joints"]["elbow_flex_r"] == {"mean": None, "p99": None, "bias": None, "n": 0, "gimbal": 0}
    assert rows[1]["joints"]["knee_angle_l"]["mean"] == pytest.approx(float(scored["knee_angle_l"][0]), abs=0.01)

    assert cli.main(["eval", str(cmu_npz), "--joint-angles"]) == 2
    assert "--thresholds TH[,TH...]" in capsys.readouterr().err
    assert cli.main(["eval", str(xio_dir), "--thresholds", "1e-3", "--joint-angles"]) == 2
    assert "no true joint angles" in capsys.readouterr().err


OPENSIM_JOINTS = (  # (joint, parent body, child body, segment, ((coordinate, axis, coefficient) x 1 or 3))
    ("hip_r", "pelvis", "femur_r", "r_thigh", (("hip_flexion_r", "0 0 1", 1), ("hip_adduction_r", "1 0 0", 1),
                                               ("hip_rotation_r", "0 1 0", 1))),
    ("hip_l", "pelvis", "femur_l", "l_thigh", (("hip_flexion_l", "0 0 1", 1), ("hip_adduction_l", "1 0 0", -1),
                                               ("hip_rotation_l", "0 1 0", -1))),
    ("knee_r", "femur_r", "tibia_r", "r_shank", (("knee_angle_r", "0 0 -1", 1),)),
    ("knee_l", "femur_l", "tibia_l", "l_shank", (("knee_angle_l", "0 0 -1", 1),)),
    ("acromial_r", "pelvis", "humerus_r", "r_upperarm", (("arm_flex_r", "0 0 1", 1), ("arm_add_r", "1 0 0", 1),
                                                         ("arm_rot_r", "0 1 0", 1))),
    ("acromial_l", "pelvis", "humerus_l", "l_upperarm", (("arm_flex_l", "0 0 1", 1), ("arm_add_l", "-1 0 0", 1),
                                                         ("arm_rot_l", "0 -1 0", 1))),
    ("elbow_r", "humerus_r", "ulna_r", "r_lowerarm", (("elbow_flex_r", "0 0 1", 1),)),
    ("elbow_l", "humerus_l", "ulna_l", "l_lowerarm", (("elbow_flex_l", "0 0 1", 1),)),
    ("neck", "pelvis", "head", "neck", (("neck_extension", "0 0 1", 1), ("neck_bending", "1 0 0", 1),
                                        ("neck_rotation", "0 1 0", 1))),
)
"""A skeleton of the Rajagopal model's joints as its file defines them (hinge tilts left out), the
neck with its back joint's axes."""


def opensim_model_text() -> str:
    """The OpenSim model file of :data:`OPENSIM_JOINTS` (pelvis welded to the ground)."""
    bodies = ["pelvis"] + [child for _, _, child, _, _ in OPENSIM_JOINTS]
    body_xml = "".join(f'<Body name="{b}"><mass>1</mass><mass_center>0 0 0</mass_center>'
                       f'<inertia>1 1 1 0 0 0</inertia></Body>' for b in bodies)
    joints_xml = ['<WeldJoint name="ground_pelvis"><socket_parent_frame>/ground</socket_parent_frame>'
                  '<socket_child_frame>/bodyset/pelvis</socket_child_frame></WeldJoint>']
    for name, parent, child, _, coordinates in OPENSIM_JOINTS:
        axes = list(coordinates) + ([("", "1 0 0", 0), ("", "0 1 0", 0)] if len(coordinates) == 1 else [])  # hinges: about Z
        rotations = "".join(
            f'<TransformAxis name="rotation{i + 1}"><coordinates>{c}</coordinates><axis>{a}</axis>'
            + (f'<LinearFunction name="function"><coefficients> {k} 0</coefficients></LinearFunction>' if c
               else '<Constant name="function"><value>0</value></Constant>') + '</TransformAxis>'
            for i, (c, a, k) in enumerate(axes))
        translations = "".join(f'<TransformAxis name="translation{i + 1}"><coordinates></coordinates><axis>{a}</axis>'
                               f'<Constant name="function"><value>0</value></Constant></TransformAxis>'
                               for i, a in enumerate(("1 0 0", "0 1 0", "0 0 1")))
        coords = "".join(f'<Coordinate name="{c}"/>' for c, _, _ in coordinates)
        joints_xml.append(f'<CustomJoint name="{name}"><socket_parent_frame>/bodyset/{parent}</socket_parent_frame>'
                          f'<socket_child_frame>/bodyset/{child}</socket_child_frame><coordinates>{coords}'
                          f'</coordinates><SpatialTransform>{rotations}{translations}</SpatialTransform></CustomJoint>')
    return (f'<?xml version="1.0" encoding="UTF-8" ?><OpenSimDocument Version="40000"><Model name="joints">'
            f'<BodySet name="bodyset"><objects>{body_xml}</objects></BodySet>'
            f'<JointSet name="jointset"><objects>{"".join(joints_xml)}</objects></JointSet></Model></OpenSimDocument>')


def test_opensims_own_kinematics_give_the_same_angles(tmp_path):
    """OpenSim poses a model whose joints are the Rajagopal model's (axes, coefficients) from
    random coordinates; its bodies' orientations, taken into limbstream's axes, give the
    coordinates back: the Euler order, the axes carried by the rotations before, and every sign."""
    import opensim

    (tmp_path / "joints.osim").write_text(opensim_model_text())
    model = opensim.Model(str(tmp_path / "joints.osim"))
    state = model.initSystem()
    rng = np.random.default_rng(8)
    for _ in range(10):
        values = {c: rng.uniform(-60.0, 60.0) for *_, coordinates in OPENSIM_JOINTS for c, _, _ in coordinates}
        for name, value in values.items():
            model.getCoordinateSet().get(name).setValue(state, math.radians(value))
        model.realizePosition(state)
        q = np.tile(IDENTITY, (len(wire.SEGMENTS), 1))
        for _, _, body, segment, _ in OPENSIM_JOINTS:
            r = model.getBodySet().get(body).getTransformInGround(state).R()
            matrix = np.array([[r.get(i, k) for k in range(3)] for i in range(3)])
            in_opensim = quat.from_rotation(Rotation.from_matrix(matrix))
            q[SEG[segment]] = quat.multiply(quat.multiply(quat.conjugate(TO_OPENSIM), in_opensim), TO_OPENSIM)
        got, _ = joint_angles(q)
        for name, value in values.items():
            assert angle(got, name) == pytest.approx(value, abs=1e-9), name
