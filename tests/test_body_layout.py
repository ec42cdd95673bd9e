"""Body layouts and bodies (limbstream.body, docs/body.md): the built-ins, layout and body files
(good and each bad case), sizes by height and their bounds, and the forward kinematics: paper10's
default body draws exactly what limbstream.skeleton draws, full stands as Winter's table says."""
from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from support import ROOT

from limbstream import quat, wire
from limbstream.body import (FULL, PAPER10, WINTER_HEIGHTS, WINTER_LENGTHS, Bend, Body, layout, layout_from_dict,
                             load_layout, rest_heights)
from limbstream.skeleton import Skeleton
from limbstream.sources import load_npz
from limbstream.sources.generator import GeneratorSource

EXAMPLES = ROOT / "examples" / "layouts"
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def identity(lay) -> np.ndarray:
    return np.tile(IDENTITY, (len(lay.segments), 1))


def at(body: Body, q: np.ndarray, tpose: bool = False) -> dict[str, np.ndarray]:
    """Joint name -> (3,) float64 position."""
    return dict(zip(body.layout.joints, body.positions(q, tpose, np.float64)))


# --- the built-ins ---------------------------------------------------------------------------

def test_paper10_is_the_wire_layout():
    assert PAPER10.segment_names == wire.SEGMENTS and PAPER10.joints == wire.JOINTS
    assert {(b.origin, b.joint) for b in PAPER10.bones} == set(wire.BONES)  # the lines clients draw
    assert PAPER10.segment_index["hip"] == 9 and PAPER10.joint_index["r_wrist"] == 14
    assert PAPER10.root.name == "hip" and PAPER10.segment("l_upperarm").parent == "hip"


def test_full_has_15_segments_and_the_tips():
    assert FULL.segment_names == ("hip", "chest", "head", "l_upperarm", "l_lowerarm", "l_hand", "r_upperarm",
                                  "r_lowerarm", "r_hand", "l_thigh", "l_shank", "l_foot", "r_thigh", "r_shank",
                                  "r_foot")
    assert len(FULL.joints) == 20 and {"head_top", "l_fingertip", "r_fingertip", "l_toe", "r_toe"} <= set(FULL.joints)
    assert set(PAPER10.joints) - set(FULL.joints) == {"head"}  # full's head ends at its top
    parents = {s.name: s.parent for s in FULL.segments}
    assert parents["head"] == "chest" and parents["chest"] == "hip" and parents["l_foot"] == "l_shank"
    assert parents["l_upperarm"] == "chest" and parents["r_hand"] == "r_lowerarm"
    assert layout("full") is FULL and layout("paper10") is PAPER10
    with pytest.raises(ValueError, match="layout must be one of paper10, full or a .toml/.json file, got 'fll'"):
        layout("fll")


# --- forward kinematics: paper10 is the skeleton, bit for bit --------------------------------

def assert_same_bits(body: Body, skeleton: Skeleton, q: np.ndarray) -> None:
    tpose = np.arange(q.shape[0]) % 3 == 0  # per frame, mixed
    for flag in (False, True, tpose):
        for dtype in (np.float32, np.float64):
            mine, theirs = body.positions(q, flag, dtype), skeleton.positions(q, flag, dtype)
            assert mine.dtype == theirs.dtype and mine.shape == theirs.shape
            assert mine.tobytes() == theirs.tobytes()


def test_paper10_default_body_draws_the_skeleton_bit_for_bit_on_the_generator():
    motion = GeneratorSource(seed=3).motion(20.0)
    assert motion.rest_pose == "standing" and motion.segments == wire.SEGMENTS
    assert_same_bits(Body.default(PAPER10), Skeleton(), motion.q)


def test_paper10_default_body_draws_the_skeleton_bit_for_bit_on_cmu_clips(cmu_npz):
    motions = load_npz(cmu_npz)
    assert len(motions) >= 6 and {m.rest_pose for m in motions} == {"tpose"}
    body = Body.default(PAPER10)
    for m in motions:
        assert_same_bits(body, Skeleton(), m.q)
        assert_same_bits(body, Skeleton(rest_pose="tpose"), m.q)


@settings(deadline=None)  # a loaded machine's timing is no property of a body
@given(st.integers(0, 2**32 - 1))
def test_paper10_draws_the_skeleton_bit_for_bit_for_any_orientations(seed):
    q = quat.normalize(np.random.default_rng(seed).normal(size=(7, 10, 4)))
    assert_same_bits(Body.default(PAPER10), Skeleton(), q)


# --- forward kinematics: full stands as Winter's table says ---------------------------------

def test_full_at_1_75_m_stands_at_winters_heights_feet_flat_forward():
    h = 1.75
    body = Body.from_height(FULL, h)
    up = rest_heights(body)
    landmarks = {"head_top": "head_top", "neck_base": "shoulder", "l_shoulder": "shoulder", "l_elbow": "elbow",
                 "l_wrist": "wrist", "l_fingertip": "fingertip", "pelvis": "hip", "l_hip": "hip", "l_knee": "knee",
                 "l_ankle": "ankle"}
    for joint, landmark in landmarks.items():
        # joints chained from Winter's lengths land within 2 mm per metre of his landmark heights
        assert up[joint] == pytest.approx(WINTER_HEIGHTS[landmark] * h, abs=0.002 * h), joint
        assert up[joint] == pytest.approx(up["r" + joint[1:]] if joint.startswith("l_") else up[joint])
    assert up["head_top"] == pytest.approx(h, abs=1e-12)  # the floor to the top of the head
    p = at(body, identity(FULL))
    for s, side in (("l", 1.0), ("r", -1.0)):
        ankle, toe = p[f"{s}_ankle"], p[f"{s}_toe"]
        assert up[f"{s}_toe"] == pytest.approx(0.0, abs=1e-12), "the toes on the floor"
        assert toe[0] == ankle[0] and toe[2] > ankle[2] + 0.2, "the foot points forward (+Z)"
        assert np.linalg.norm(toe - ankle) == pytest.approx(WINTER_LENGTHS["foot"] * h)
        assert side * p[f"{s}_shoulder"][0] == pytest.approx(WINTER_LENGTHS["shoulder_width"] / 2 * h)
        assert side * p[f"{s}_hip"][0] > 0 and side * p[f"{s}_fingertip"][0] > 0, "left is +X"
    t = at(body, identity(FULL), tpose=True)  # arms out: fingertips at shoulder height, an arm span out
    arm = (WINTER_LENGTHS["upper_arm"] + WINTER_LENGTHS["forearm"] + WINTER_LENGTHS["hand"]) * h
    assert t["l_fingertip"] - t["l_shoulder"] == pytest.approx([arm, 0.0, 0.0])
    assert t["r_fingertip"] - t["r_shoulder"] == pytest.approx([-arm, 0.0, 0.0])
    assert t["l_toe"] == pytest.approx(p["l_toe"])


@settings(deadline=None)  # a loaded machine's timing is no property of a body
@given(st.floats(0.5, 2.5), st.sampled_from(["full", "suit17.toml", "back16.json"]))
def test_any_height_stands_that_tall_with_each_bone_its_fraction(height, name):
    lay = layout(name if name == "full" else EXAMPLES / name)
    body = Body.from_height(lay, height)
    assert body.height_m == height
    for bone in lay.bones:
        assert body.lengths[bone.name] == pytest.approx(bone.height_fraction * height, rel=1e-12)
    up = rest_heights(body)
    assert up["head_top"] == pytest.approx(height, rel=1e-12)
    assert up["l_toe"] == pytest.approx(0.0, abs=1e-12)


LAYOUTS_AND_BODIES = [("paper10", None), ("paper10", 1.6), ("full", 1.9), ("suit17.toml", 1.2), ("back16.json", 2.4)]


@pytest.mark.parametrize(("name", "height"), LAYOUTS_AND_BODIES)
@settings(deadline=None)  # a loaded machine's timing is no property of a body
@given(seed=st.integers(0, 2**32 - 1))
def test_bones_keep_their_lengths_and_a_common_turn_turns_the_body(name, height, seed):
    lay = layout(name if name in ("paper10", "full") else EXAMPLES / name)
    body = Body.default(lay) if height is None else Body.from_height(lay, height)
    rng = np.random.default_rng(seed)
    q = quat.normalize(rng.normal(size=(5, len(lay.segments), 4)))
    tpose = rng.random(5) < 0.5
    p = body.positions(q, tpose, np.float64)
    j = lay.joint_index
    for b in lay.bones:
        assert np.linalg.norm(p[:, j[b.joint]] - p[:, j[b.origin]], axis=-1) == pytest.approx(body.lengths[b.name])
    turn = quat.normalize(rng.normal(size=4))
    for flag in (False, True):
        turned = body.positions(np.tile(turn, (len(lay.segments), 1)), flag, np.float64)
        rest = body.positions(identity(lay), flag, np.float64)
        assert turned == pytest.approx(quat.rotate(turn, rest), abs=1e-12)


def test_positions_refuse_orientations_of_another_layout():
    with pytest.raises(ValueError, match=r"orientations must be \(\.\.\., 15, 4\) for layout full, got \(3, 10, 4\)"):
        Body.default(FULL).positions(np.tile(IDENTITY, (3, 10, 1)))


# --- bodies: heights, files, vectors and their bounds ----------------------------------------

@pytest.mark.parametrize("height", [0.49, 2.51, 0.0, -1.75, math.nan, math.inf, 175])
def test_heights_out_of_bounds_are_refused_with_the_bound(height):
    with pytest.raises(ValueError, match=r"height must be within \[0.5, 2.5\] m, got"):
        Body.from_height(FULL, height)


def test_heights_on_the_bounds_are_taken():
    assert rest_heights(Body.from_height(FULL, 0.5))["head_top"] == pytest.approx(0.5)
    assert rest_heights(Body.from_height(FULL, 2.5))["head_top"] == pytest.approx(2.5)


def lengths_of(lay) -> dict[str, float]:
    return {name: round(v, 6) for name, v in Body.from_height(lay, 1.8).lengths.items()}


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_a_body_file_gives_each_bone(tmp_path, suffix):
    bones = lengths_of(FULL) | {"l_thigh": 0.5}
    path = tmp_path / f"me{suffix}"
    path.write_text(json.dumps(bones) if suffix == ".json" else "\n".join(f"{k} = {v}" for k, v in bones.items()))
    body = Body.from_file(FULL, path)
    assert body.lengths == pytest.approx(bones) and body.height_m is None
    p = at(body, identity(FULL))
    assert p["l_hip"][1] - p["l_knee"][1] == pytest.approx(0.5) and p["r_hip"][1] - p["r_knee"][1] == pytest.approx(0.441)


@pytest.mark.parametrize(("change", "message"), [
    ({"l_thigh": 1.6}, r"me.toml: bone 'l_thigh' must be in \(0, 1.5\] m, got 1.6"),
    ({"l_shank": 0}, r"bone 'l_shank' must be in \(0, 1.5\] m, got 0"),
    ({"head": -0.2}, r"bone 'head' must be in \(0, 1.5\] m, got -0.2"),
    ({"l_hand": "nan"}, r"bone 'l_hand' must be in \(0, 1.5\] m, got nan"),
    ({"l_hand": "true"}, r"bone 'l_hand' must be a length in m or a finite 3-vector, got True"),
    ({"l_shoulder": "[0.3, 2.0, 0.0]"}, r"bone 'l_shoulder' must be in \(0, 1.5\] m, got 2.02"),
    ({"l_tail": 0.3}, r"me.toml: layout full has no bone 'l_tail'"),
    ({"l_foot": None, "r_foot": None}, r"me.toml: missing bone 'l_foot', 'r_foot' of layout full"),
    ({"layout": '"paper10"'}, r"me.toml: a body of layout 'paper10', not 'full'"),
])
def test_bad_body_files_are_refused_naming_the_bone(tmp_path, change, message):
    bones = {k: str(v) for k, v in lengths_of(FULL).items()} | {k: str(v) for k, v in change.items()}
    path = tmp_path / "me.toml"
    path.write_text("\n".join(f"{k} = {v}" for k, v in bones.items() if v != "None"))
    with pytest.raises(ValueError, match=message):
        Body.from_file(FULL, path)


def test_a_bone_of_exactly_the_bound_is_taken(tmp_path):
    assert Body(FULL, lengths_of(FULL) | {"l_thigh": 1.5}).lengths["l_thigh"] == 1.5


@pytest.mark.parametrize(("name", "text", "message"), [
    ("me.yaml", "l_thigh: 0.4", r"me.yaml: a layout or body file is .toml or .json, got '.yaml'"),
    ("me.toml", "l_thigh = ", r"me.toml: not valid TOML"),
    ("me.json", "[0.4]", r"me.json: must hold a table at the top, got list"),
])
def test_unreadable_files_are_refused_naming_them(tmp_path, name, text, message):
    (tmp_path / name).write_text(text)
    with pytest.raises(ValueError, match=message):
        Body.from_file(FULL, tmp_path / name)
    with pytest.raises(ValueError, match=message):
        load_layout(tmp_path / name)


def test_paper10_default_body_written_and_read_back_is_the_same(tmp_path):
    path = tmp_path / "paper10.json"
    path.write_text(json.dumps(Body.default(PAPER10).to_dict()))
    assert json.loads(path.read_text())["l_shoulder"] == [0.19, -0.05, 0.0]  # off its axis: a vector
    back = Body.from_file(PAPER10, path)
    for pose in wire.REST_POSES:
        assert back.vectors[pose].tobytes() == Body.default(PAPER10).vectors[pose].tobytes()


def test_bvh_style_vectors_keep_their_own_rest_pose_and_take_the_layouts_in_the_other():
    """T-pose offsets of a skeleton file: arms along +-X (a bit off), legs down."""
    vectors = dict(zip(PAPER10.bone_names, Body.default(PAPER10).vectors["tpose"]))
    vectors["l_upperarm"] = np.array([0.3, 0.0, -0.04])  # a little behind the shoulder, as BVH arms are
    body = Body.from_vectors(PAPER10, vectors, rest_pose="tpose")
    i = PAPER10.bone_names.index("l_upperarm")
    assert body.vectors["tpose"][i].tolist() == [0.3, 0.0, -0.04]
    with pytest.raises(ValueError, match="read-only"):
        body.vectors["tpose"][i] = 0.0
    assert body.vectors["standing"][i] == pytest.approx([0.0, -math.hypot(0.3, 0.04), 0.0])
    t = at(body, identity(PAPER10), tpose=True)
    assert t["l_elbow"] - t["l_shoulder"] == pytest.approx([0.3, 0.0, -0.04])
    same = [n for n in PAPER10.bone_names if n != "l_upperarm"]
    k = [PAPER10.bone_names.index(n) for n in same]
    assert np.array_equal(body.vectors["standing"][k], Body.default(PAPER10).vectors["standing"][k])
    with pytest.raises(ValueError, match=r"bone 'neck' must be a length in m or a finite 3-vector, got \[0.0, nan"):
        Body.from_vectors(PAPER10, vectors | {"neck": [0.0, math.nan, 0.0]})
    with pytest.raises(ValueError, match=r"bone 'neck' must be a length in m or a finite 3-vector, got \[0.1, 0.2\]"):
        Body.from_vectors(PAPER10, vectors | {"neck": [0.1, 0.2]})
    with pytest.raises(ValueError, match=r"rest pose must be one of standing, tpose, got 'sitting'"):
        Body.from_vectors(PAPER10, vectors, rest_pose="sitting")


def test_a_layout_without_height_fractions_has_no_body_by_height():
    rows = [dict(r) for r in FULL.to_dict()["segments"]]
    del rows[1]["height_fraction"], rows[3]["offset"]["height_fraction"]
    lay = layout_from_dict({"name": "bare", "segments": rows})
    with pytest.raises(ValueError, match="layout bare gives no height fraction for bone 'chest', 'l_shoulder'"):
        Body.from_height(lay, 1.7)


# --- layout files ----------------------------------------------------------------------------

def test_the_example_layouts_load():
    suit = load_layout(EXAMPLES / "suit17.toml")
    assert suit.name == "suit17" and len(suit.segments) == 17 and len(suit.joints) == 20
    assert suit.segment("l_upperarm").parent == "l_clavicle" and suit.segment("l_clavicle").parent == "chest"
    back = load_layout(EXAMPLES / "back16.json")
    assert back.name == "back16" and len(back.segments) == 16 and back.joints[:3] == ("pelvis", "lumbar", "thorax")
    assert [s.parent for s in back.segments[:3]] == [None, "hip", "lower_back"]
    spine = load_layout(EXAMPLES / "spine17.json")  # CMU's spine: the lower back and the thorax off the pelvis and neck
    assert spine.name == "spine17" and len(spine.segments) == 17 and len(spine.joints) == 20
    assert spine.segment("lower_back").joint == "pelvis" and spine.segment("head").parent == "thorax"


@pytest.mark.parametrize("lay", [PAPER10, FULL], ids=["paper10", "full"])
def test_a_built_in_written_to_a_file_loads_back_equal(tmp_path, lay):
    path = tmp_path / f"{lay.name}.json"
    path.write_text(json.dumps(lay.to_dict()))
    back = load_layout(path)
    assert back == lay and back.bones == lay.bones
    assert hash(back) == hash(lay) and len({back, lay, FULL, PAPER10}) == 2  # a layout can key a cache
    assert Body.from_height(back, 1.7).vectors["tpose"].tobytes() == Body.from_height(lay, 1.7).vectors["tpose"].tobytes()


SMALL = """name = "small"
[[segments]]
name = "hip"
joint = "pelvis"
end = "neck_base"
direction = [0, 1, 0]
[[segments]]
name = "l_thigh"
parent = "hip"
joint = "l_hip"
end = "l_knee"
direction = [0, -1, 0]
offset = { from = "pelvis", direction = [1, 0, 0] }
[[segments]]
name = "l_shank"
parent = "l_thigh"
joint = "l_knee"
end = "l_ankle"
direction = [0, -1, 0]
"""


def test_a_small_toml_layout_and_its_derived_joints():
    lay = layout_from_dict(tomllib.loads(SMALL))
    assert lay.joints == ("pelvis", "neck_base", "l_hip", "l_knee", "l_ankle")
    assert lay.bone_names == ("hip", "l_hip", "l_thigh", "l_shank")
    assert [(b.origin, b.segment) for b in lay.bones] == [("pelvis", "hip"), ("pelvis", "hip"), ("l_hip", "l_thigh"),
                                                          ("l_knee", "l_shank")]
    p = at(Body(lay, {"hip": 0.5, "l_hip": 0.1, "l_thigh": 0.4, "l_shank": 0.4}), identity(lay))
    assert p["l_ankle"] == pytest.approx([0.1, -0.8, 0.0])


BAD_LAYOUTS = [
    ('name = "l_shank"\nparent = "l_thigh"', 'name = "hip"\nparent = "l_thigh"', r"duplicate segment 'hip'"),
    ('parent = "l_thigh"\njoint = "l_knee"', 'parent = "l_knee"\njoint = "l_knee"',
     r"segment 'l_shank' has a missing parent 'l_knee'"),
    ('name = "hip"\njoint = "pelvis"', 'name = "hip"\nparent = "l_shank"\njoint = "pelvis"',
     r"cycle of parents (hip -> l_shank -> l_thigh -> hip|l_thigh -> hip -> l_shank -> l_thigh)"),
    ('parent = "l_thigh"\njoint = "l_knee"', 'joint = "l_knee"', r"one segment has no parent \(the root\), here hip, l_shank"),
    ('joint = "l_knee"\nend = "l_ankle"', 'joint = "l_kne"\nend = "l_ankle"',
     r"segment 'l_shank' starts at unknown joint 'l_kne' \(not l_hip or l_knee of its parent 'l_thigh'; give it an offset\)"),
    ('from = "pelvis"', 'from = "spine"', r"offset of segment 'l_thigh' from unknown joint 'spine' \(not pelvis or neck_base"),
    ('end = "l_ankle"', 'end = "neck_base"', r"joint 'neck_base' placed twice \(segment 'hip' and segment 'l_shank'\)"),
    ('end = "l_ankle"\ndirection = [0, -1, 0]', 'end = "l_ankle"\ndirection = [0, 0, 0]',
     r"segment 'l_shank': direction must be finite and non-zero, got \[0.0, 0.0, 0.0\]"),
    ('end = "l_ankle"\ndirection = [0, -1, 0]', 'end = "l_ankle"\ndirection = [nan, -1, 0]',
     r"segment 'l_shank': direction must be finite and non-zero, got \[nan"),
    ('end = "l_ankle"\ndirection = [0, -1, 0]', 'end = "l_ankle"\ndirection = [0, -1]',
     r"segment 'l_shank': direction must be 3 numbers, got \[0, -1\]"),
    ('direction = [1, 0, 0] }', 'direction = [inf, 0, 0] }', r"segment 'l_thigh' offset: direction must be finite and non-zero"),
    ('end = "l_ankle"\ndirection = [0, -1, 0]', 'end = "l_ankle"\ndirection = { tpose = [1, 0, 0] }',
     r"segment 'l_shank': direction needs its 'standing' rest pose"),
    ('end = "l_ankle"\ndirection = [0, -1, 0]', 'end = "l_ankle"\ndirection = { standing = [0, -1, 0], sit = [1, 0, 0] }',
     r"segment 'l_shank': rest pose must be one of standing, tpose, got 'sit'"),
    ('end = "l_ankle"\n', 'end = "l_ankle"\nheight_fraction = 1.2\n', r"segment 'l_shank': height fraction must be in \(0, 1\], got 1.2"),
    ('end = "l_ankle"\n', 'end = "l_ankle"\nlength = 0.4\n', r"segment 'l_shank': unknown key 'length'"),
    ('name = "l_shank"', 'name = 3', r"segment 3: 'name' must be a name, got 3"),
    ('name = "small"', 'name = "small"\njoints = ["pelvis", "neck_base", "l_hip", "l_knee", "l_toe"]',
     r"layout small: unknown joint 'l_toe' in its joints order"),
    ('name = "small"', 'name = "small"\njoints = ["pelvis", "neck_base", "l_hip", "l_knee"]',
     r"layout small: joints order misses l_ankle"),
    ('name = "small"', 'name = "small"\njoints = ["pelvis", "pelvis", "neck_base", "l_hip", "l_knee", "l_ankle"]',
     r"layout small: joint 'pelvis' twice in its joints order"),
    ('name = "l_shank"', 'name = "l_hip"', r"bone name 'l_hip' used twice \(an offset is named by its joint\)"),
    ('name = "hip"\njoint = "pelvis"', 'name = "hip"\njoint = "pelvis"\noffset = { from = "pelvis", direction = [1, 0, 0] }',
     r"the root segment 'hip' takes no offset \(its joint is the origin\)"),
    ('end = "l_ankle"\n', 'end = "l_ankle"\nbend = { toward = "hip", share = 0.5 }\n',
     r"segment 'l_shank' bends toward 'hip', not its parent or a child \(l_thigh\)"),
    ('end = "l_knee"\n', 'end = "l_knee"\nbend = { toward = "l_shank", share = 1 }\n',
     r"segment 'l_thigh' bend: share must be in \(0, 1\), got 1"),
    ('end = "l_knee"\n', 'end = "l_knee"\nbend = { toward = "l_shank", share = "half" }\n',
     r"segment 'l_thigh' bend: share must be in \(0, 1\), got 'half'"),
    ('end = "l_knee"\n', 'end = "l_knee"\nbend = { toward = "l_shank", by = 0.5 }\n',
     r"segment 'l_thigh' bend: unknown key 'by'"),
    ('end = "l_knee"\n', 'end = "l_knee"\nbend = "l_shank"\n', r"segment 'l_thigh': 'bend' must be a table"),
]
BENT_SMALL = SMALL.replace('end = "neck_base"\n', 'end = "neck_base"\nbend = { toward = "l_thigh", share = 0.5 }\n')


def test_a_bend_turns_its_bone_part_of_the_way_toward_its_neighbour():
    """full's lumbar spine: the pelvis's bone (to the chest's joint) turns halfway from the pelvis
    to the chest, and everything above it follows; the legs, off the pelvis, do not."""
    assert [(b.name, b.bend) for b in FULL.bones if b.bend] == [("hip", Bend("chest", 0.5))]
    body = Body.default(FULL)
    q = identity(FULL)
    q[FULL.segment_index["chest"]] = quat.from_rotation(Rotation.from_rotvec([0.8, 0.0, 0.0]))
    rest, bent = at(body, identity(FULL)), at(body, q)
    lumbar = quat.rotate(quat.from_rotation(Rotation.from_rotvec([0.4, 0.0, 0.0])), rest["spine"])
    assert bent["spine"] == pytest.approx(lumbar, abs=1e-12)
    chest = quat.rotate(q[FULL.segment_index["chest"]], rest["neck_base"] - rest["spine"])
    assert bent["neck_base"] == pytest.approx(lumbar + chest, abs=1e-12)
    for joint in ("l_hip", "l_knee", "l_toe", "r_ankle"):
        assert bent[joint] == pytest.approx(rest[joint], abs=1e-12)
    rigid = FULL.part("rigid", FULL.segment_names)  # (a part with every segment keeps the bend)
    assert rigid.segment("hip").bend == FULL.segment("hip").bend
    straight = layout_from_dict({**FULL.to_dict(), "segments": [{k: v for k, v in row.items() if k != "bend"}
                                                                for row in FULL.to_dict()["segments"]]})
    assert at(Body.default(straight), q)["spine"] == pytest.approx(rest["spine"], abs=1e-12)


@settings(deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_the_c_chain_bends_as_quat_slerp_and_rotate_do(seed):
    """The chain's bent bone (in C) against the same forward kinematics spelled out with
    limbstream.quat, bone by bone, in both rest poses: equal to 1e-12 m."""
    rng = np.random.default_rng(seed)
    body = Body.from_height(FULL, 1.6 + 0.3 * rng.random())
    q = quat.normalize(rng.normal(size=(7, len(FULL.segments), 4)))
    tpose = rng.random(7) < 0.5
    s, j = FULL.segment_index, FULL.joint_index
    want = np.zeros((7, len(FULL.joints), 3))
    for k, bone in enumerate(FULL.bones):
        turn = q[:, s[bone.segment]]
        if bone.bend is not None:
            turn = quat.slerp(turn, q[:, s[bone.bend.toward]], bone.bend.share)
        vec = np.where(tpose[:, None], body.vectors["tpose"][k], body.vectors["standing"][k])
        start = 0.0 if bone.origin == FULL.root.joint else want[:, j[bone.origin]]
        want[:, j[bone.joint]] = start + quat.rotate(turn, vec)
    assert np.abs(body.positions(q, tpose, np.float64) - want).max() < 1e-12


def test_a_layout_part_drops_a_bend_toward_a_segment_it_leaves_out():
    legs = FULL.part("legs", ("hip", "l_thigh", "l_shank", "l_foot"))
    assert legs.segment_names == ("hip", "l_thigh", "l_shank", "l_foot") and legs.segment("hip").bend is None
    assert layout_from_dict(legs.to_dict()) == legs


def test_a_bend_in_a_layout_file_loads_and_round_trips():
    """The small layout's pelvis bone bends toward the thigh, which starts off the pelvis (its
    proximal joint); starting the thigh off the bent bone's end is refused."""
    lay = layout_from_dict(tomllib.loads(BENT_SMALL))
    assert lay.bones[0].bend == Bend("l_thigh", 0.5) and lay.bones[0].turned_by == ("hip", "l_thigh")
    assert layout_from_dict(lay.to_dict()) == lay
    body = Body(lay, {"hip": 0.5, "l_hip": 0.1, "l_thigh": 0.4, "l_shank": 0.4})
    q = identity(lay)
    q[1] = quat.from_rotation(Rotation.from_rotvec([0.0, 0.0, 1.0]))
    assert at(body, q)["neck_base"] == pytest.approx(quat.rotate(quat.slerp(IDENTITY, q[1], 0.5), [0.0, 0.5, 0.0]))
    off_end = BENT_SMALL.replace('from = "pelvis"', 'from = "neck_base"')
    with pytest.raises(ValueError, match=r"segment 'hip' bends, so no child may start off its distal joint "
                                         r"'neck_base'; 'l_thigh' does \(start it at 'neck_base' or off 'pelvis'\)"):
        layout_from_dict(tomllib.loads(off_end))


@pytest.mark.parametrize("suffix", [".toml", ".json"])
@pytest.mark.parametrize(("old", "new", "message"), BAD_LAYOUTS)
def test_bad_layout_files_are_refused_at_load_naming_the_problem(tmp_path, suffix, old, new, message):
    assert SMALL.count(old) == 1
    text = SMALL.replace(old, new)
    path = tmp_path / f"bad{suffix}"
    if suffix == ".json":
        path.write_text(json.dumps(tomllib.loads(text)))
    else:
        path.write_text(text)
    with pytest.raises(ValueError, match=message) as caught:
        load_layout(path)
    assert str(caught.value).startswith(str(path)) and "\n" not in str(caught.value)
