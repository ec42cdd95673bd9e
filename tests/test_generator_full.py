"""The generator's ``full`` body: 15 segments, paper10's among them unchanged, feet that roll on
the floor, hands that follow the forearms, a chest that turns against the pelvis."""

from __future__ import annotations

import numpy as np
import pytest

from limbstream import quat
from limbstream.body import FULL, PAPER10, Body, layout_from_dict
from limbstream.sources import SEGMENTS
from limbstream.sources import generator_limbs as limbs
from limbstream.sources.generator import STILL_S, GeneratorSource, JOINT_RANGES, generate

FS = 50.0
BODY = Body.from_height(FULL, 1.75)
J = FULL.joint_index
SEG = FULL.segment_index
ANKLE_M = 0.039 * 1.75  # the ankle's height above the floor standing (the foot's rest drop)
SHARED = [s for s in SEGMENTS if s != "neck"]  # paper10's segments under the same name in full


def _in(q: np.ndarray, segment: str, v) -> np.ndarray:
    """(n, 3) the segment's own vector ``v`` in the world."""
    return quat.rotate(q[:, SEG[segment]], np.asarray(v, np.float64))


def _relative(q: np.ndarray, parent: str, child: str) -> np.ndarray:
    """(n, 4) the child's orientation in its parent's frame."""
    return quat.multiply(quat.conjugate(q[:, SEG[parent]]), q[:, SEG[child]])


def test_full_outputs_fulls_15_segments_in_its_order():
    motion = generate(5.0, FS, seed=1, layout="full")
    assert motion.segments == FULL.segment_names and motion.q.shape == (250, 15, 4)
    assert motion.layout is FULL
    assert GeneratorSource(layout=FULL).segments == FULL.segment_names
    assert GeneratorSource().segments == SEGMENTS == PAPER10.segment_names


def test_same_seed_same_motion_other_seed_other_motion():
    a = generate(20.0, FS, seed=7, noise_deg=1.0, mounting_offsets=True, layout="full")
    b = generate(20.0, FS, seed=7, noise_deg=1.0, mounting_offsets=True, layout="full")
    np.testing.assert_array_equal(a.q, b.q)
    c = generate(20.0, FS, seed=8, noise_deg=1.0, mounting_offsets=True, layout="full")
    assert (np.median(quat.angle_deg(a.q, c.q), axis=0) > 1.0).all()


@pytest.mark.parametrize("noise, mounting", [(0.0, False), (1.5, True)])
def test_full_is_paper10_plus_chest_hands_and_feet(noise, mounting):
    """Every paper10 segment moves in full exactly as in paper10 (its head is paper10's neck),
    noise and mounting offsets included; chunks equal the batch."""
    paper = GeneratorSource(3, FS, noise_deg=noise, mounting_offsets=mounting)
    full = GeneratorSource(3, FS, noise_deg=noise, mounting_offsets=mounting, layout="full")
    for start, count in [(0, 3000), (2 * 1024 - 5, 700), (10_000_000, 3)]:
        _, p = paper.chunk(start, count)
        _, f = full.chunk(start, count)
        for s in SHARED:
            np.testing.assert_array_equal(f[:, SEG[s]], p[:, SEGMENTS.index(s)], err_msg=s)
        np.testing.assert_array_equal(f[:, SEG["head"]], p[:, SEGMENTS.index("neck")])
    batch = generate(60.0, FS, seed=3, noise_deg=noise, mounting_offsets=mounting, layout="full")
    np.testing.assert_array_equal(full.chunk(1000, 500)[1], batch.q[1000:1500])
    if mounting:  # the new segments carry offsets of their own, 5-15 deg
        plain = generate(60.0, FS, seed=3, noise_deg=noise, layout="full")
        offset = quat.angle_deg(plain.q[0], batch.q[0])
        assert ((offset > 4) & (offset < 16)).all(), offset


def test_the_hands_and_feet_are_their_parents_turned_by_their_joints():
    """Each foot is its shank, each hand its forearm, times the elementary rotations of its two
    joint angles (generator_limbs.AXES, in order), to the bit (an exact zero's sign aside)."""
    src = GeneratorSource(4, FS, layout="full")
    t = np.arange(0, src.period_s, 1 / FS)
    q, a = src.orientations(t), src.joint_angles(t)
    for side in "lr":
        for segment, parent, joints in (("foot", "shank", ("ankle_flex", "subtalar")),
                                        ("hand", "lowerarm", ("wrist_flex", "wrist_dev"))):
            want = q[:, SEG[f"{side}_{parent}"]]
            for joint in joints:
                _, sign, axis = next(row for row in limbs.AXES if row[0] == f"{joint}_{side}")
                turn = quat.about_axes(np.radians(sign * a[f"{joint}_{side}"])[None], [int(np.argmax(axis))])[0]
                want = quat.multiply(want, turn)
            np.testing.assert_array_equal(q[:, SEG[f"{side}_{segment}"]], want, err_msg=f"{side}_{segment}")


def test_a_layout_of_known_segments_takes_them_by_name_and_others_are_refused():
    rows = [{"name": "hip", "joint": "pelvis", "end": "spine", "direction": [0, 1, 0]},
            {"name": "l_thigh", "parent": "hip", "joint": "pelvis", "end": "l_knee", "direction": [0, -1, 0]},
            {"name": "l_shank", "parent": "l_thigh", "joint": "l_knee", "end": "l_ankle", "direction": [0, -1, 0]},
            {"name": "l_foot", "parent": "l_shank", "joint": "l_ankle", "end": "l_toe", "direction": [0, 0, 1]}]
    legs = layout_from_dict({"name": "left_leg", "segments": rows}, "left_leg")
    q = GeneratorSource(2, FS, layout=legs).chunk(0, 400)[1]
    full = GeneratorSource(2, FS, layout="full").chunk(0, 400)[1]
    np.testing.assert_array_equal(q, full[:, [SEG[s] for s in legs.segment_names]])
    rows[3]["name"] = "l_skate"
    with pytest.raises(ValueError, match="layout left_leg: the generator moves no segment 'l_skate'"):
        GeneratorSource(layout=layout_from_dict({"name": "left_leg", "segments": rows}, "x"))
    with pytest.raises(ValueError, match="layout must be one of paper10, full"):
        GeneratorSource(layout="fullest")


def _cycles(hip_flex: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) sample of each whole gait cycle: heel strike at the hip's greatest flexion."""
    peaks = [k for k in range(1, len(hip_flex) - 1) if hip_flex[k - 1] < hip_flex[k] >= hip_flex[k + 1]]
    return list(zip(peaks[:-1], peaks[1:]))


@pytest.mark.parametrize("seed", [0, 1, 5])
def test_walking_feet_strike_with_the_heel_stand_flat_and_lift_the_heel(seed):
    src = GeneratorSource(seed, FS, activities="walking", layout="full")
    t = np.arange(0, 30, 1 / FS)
    a, q = src.joint_angles(t), src.orientations(t)
    for side in ("l", "r"):
        ankle = a[f"ankle_flex_{side}"]
        lo, hi = JOINT_RANGES[f"ankle_flex_{side}"]
        assert lo <= ankle.min() and ankle.max() <= hi
        assert ankle.min() < -3 and ankle.max() > 10, (ankle.min(), ankle.max())  # plantar- and dorsiflexed
        forward, up = _in(q, f"{side}_foot", [0, 0, 1]), _in(q, f"{side}_foot", [0, 1, 0])
        pitch = np.degrees(np.arcsin(forward[:, 1]))  # toe up, world
        tilt = np.degrees(np.arccos(np.clip(up[:, 1], -1, 1)))  # the sole off the horizontal
        cycles = _cycles(a[f"hip_flex_{side}"])
        assert len(cycles) >= 10
        for first, last in cycles:
            def at(fraction: float, first=first, last=last) -> int:  # the sample at that fraction of the cycle
                return first + round(fraction * (last - first))
            assert pitch[first] > 10, "heel strike: the toe up"
            mid = slice(at(0.2), at(0.4))
            assert np.abs(pitch[mid]).max() < 2 and tilt[mid].max() < 5, "mid-stance: the foot flat"
            assert pitch[at(0.62)] < -10, "push-off: the heel up, the toe down"
            assert ankle[at(0.62):at(0.75)].min() < ankle[at(0.4):at(0.62)].max() - 10, "toe-off: it plantarflexes"


@pytest.mark.parametrize("activities", ["walking", "running", "standing", "jumping_jacks", "arm_circles", None])
def test_no_toe_goes_into_the_floor(activities):
    """The floor is where the lower ankle stands (its height above it; the body turns about a
    fixed pelvis): no toe more than 2 cm below it in an activity, 5 cm in a cross-fade (where
    subject 15's knees bend from running into walking, its ankle's range ends: 4.3 cm)."""
    for seed in (0, 4, 15):
        src = GeneratorSource(seed, FS, activities=activities, layout="full")
        t = np.arange(0, src.period_s if activities is None else 20.0, 1 / FS)
        xyz = BODY.positions(src.orientations(t), dtype=np.float64)
        floor = xyz[:, [J["l_ankle"], J["r_ankle"]], 1].min(axis=1) - ANKLE_M
        toes = xyz[:, [J["l_toe"], J["r_toe"]], 1]
        below = (floor[:, None] - toes).max(axis=1)
        fading = src.activity_at(t) == "transition"
        assert below[~fading].max() < 0.02 and below.max() < 0.05, (below[~fading].max(), below.max())


def test_hands_follow_the_forearms_within_the_wrists_range():
    src = GeneratorSource(6, FS, layout="full")
    t = np.arange(0, src.period_s, 1 / FS)
    q, a = src.orientations(t), src.joint_angles(t)
    xyz = BODY.positions(q, dtype=np.float64)
    for side, lat in (("l", 1.0), ("r", -1.0)):
        v = quat.rotate(_relative(q, f"{side}_lowerarm", f"{side}_hand"), [0.0, -1.0, 0.0])  # the hand, forearm frame
        # the palm faces the thigh: flexion turns the hand medially (-X on the left), ulnar deviation back
        flexion = np.degrees(np.arctan2(-lat * v[:, 0], -v[:, 1]))
        deviation = np.degrees(np.arcsin(np.clip(-v[:, 2], -1.0, 1.0)))
        for name, measured in (("wrist_flex", flexion), ("wrist_dev", deviation)):
            lo, hi = JOINT_RANGES[f"{name}_{side}"]
            assert lo - 1 <= measured.min() and measured.max() <= hi + 1, (name, measured.min(), measured.max())
            assert np.ptp(a[f"{name}_{side}"]) > 10, f"{name}_{side} hardly moves"
        np.testing.assert_allclose(flexion, a[f"wrist_flex_{side}"], atol=1.5)
        hanging = np.isin(src.activity_at(t), ["standing", "walking", "still"])
        wrist, elbow, tip = (xyz[hanging, J[f"{side}_{j}"], 1] for j in ("wrist", "elbow", "fingertip"))
        assert (tip < wrist).all() and (wrist < elbow).all(), "hanging arms: the hands below the elbows"


def test_arm_circles_and_jumping_jacks_move_the_wrists():
    for activity in ("arm_circles", "jumping_jacks"):
        a = GeneratorSource(2, FS, activities=activity, layout="full").joint_angles(np.arange(2, 10, 1 / FS))
        for name in ("wrist_flex_l", "wrist_dev_r"):
            assert np.ptp(a[name]) > 8, (activity, name, np.ptp(a[name]))


def test_the_chest_turns_against_the_pelvis_in_gait():
    src = GeneratorSource(1, FS, activities="walking", layout="full")
    t = np.arange(0, 20, 1 / FS)
    q = src.orientations(t)

    def yaw(qq):  # heading of a segment's forward axis, degrees
        f = quat.rotate(qq, [0.0, 0.0, 1.0])
        return np.degrees(np.arctan2(f[:, 0], f[:, 2]))

    pelvis = yaw(q[:, SEG["hip"]])
    chest_on_pelvis = yaw(_relative(q, "hip", "chest"))
    assert np.ptp(chest_on_pelvis) > 8 and np.ptp(pelvis) > 6
    assert np.corrcoef(pelvis, chest_on_pelvis)[0, 1] < -0.95, "counter-rotation"
    a = src.joint_angles(t)
    up = quat.rotate(_relative(q, "hip", "chest"), [0.0, 1.0, 0.0])  # the chest's axis on the pelvis
    np.testing.assert_allclose(np.degrees(np.arctan2(up[:, 2], up[:, 1])), a["trunk_flex"], atol=0.5)
    np.testing.assert_allclose(-np.degrees(np.arcsin(up[:, 0])), a["trunk_lat"], atol=1.0)  # (its turn mixes in)
    head = _relative(q, "chest", "head")
    assert quat.angle_deg(head, np.array([1.0, 0, 0, 0])).max() > 3, "the head turns on the chest"


@pytest.mark.parametrize("seed", [0, 7])
def test_the_still_moments_hold_the_whole_body_still(seed):
    src = GeneratorSource(seed, FS, layout="full")
    t = np.arange(0, src.period_s, 1 / FS)
    q = src.orientations(t)
    heading = np.broadcast_to(q[:, :1], q.shape)
    rest = quat.angle_deg(q, heading).max(axis=1) < 1e-6
    still = rest[1:] & rest[:-1] & (quat.angle_deg(q[1:], q[:-1]).max(axis=1) < 1e-9)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]]))).reshape(-1, 2) / FS
    assert len(edges) >= 2 and ((edges[:, 1] - edges[:, 0]) >= STILL_S - 2 / FS).all(), edges
    xyz = BODY.positions(q[still.nonzero()[0][:1]], dtype=np.float64)[0]
    assert xyz[J["l_toe"], 1] == pytest.approx(xyz[J["l_ankle"], 1] - ANKLE_M, abs=1e-9), "feet flat"
