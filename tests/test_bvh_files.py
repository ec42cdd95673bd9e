"""BVH files as other tools write them, made from a CMU clip: other joint-name schemes (Mixamo,
side-suffixed or -prefixed names), six channels on every joint, a floor root below the pelvis, a
zero pose with the arms lowered (an A-pose) or hanging; names no scheme fits, mapped with --names."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.bvh import write_bvh
from support.export import cli

from limbstream import quat, wire
from limbstream.skeleton import bone_axis
from limbstream.sources import MotionFileError, bvh, load
from limbstream.sources.bvh_rest import shortest_arc

CLIP = "02_01"
CMU = {"Hips": "hip", "LeftUpLeg": "l_thigh", "LeftLeg": "l_shank", "RightUpLeg": "r_thigh", "RightLeg": "r_shank",
       "LeftArm": "l_upperarm", "LeftForeArm": "l_lowerarm", "RightArm": "r_upperarm", "RightForeArm": "r_lowerarm",
       "Neck": "neck"}
"""The CMU clip's joint of each segment."""


def scheme(names: dict[str, str]) -> dict[str, str]:
    """CMU joint -> new name, from segment -> new name."""
    return {joint: names[segment] for joint, segment in CMU.items()}


def sided(fmt: str, parts: dict[str, str], hip: str = "Hips", neck: str = "Neck") -> dict[str, str]:
    """CMU joint -> name for ``fmt`` (``{side}``, ``{part}``) with the sides Left/Right spelt by
    ``parts['left']``/``parts['right']``."""
    out = {"hip": hip, "neck": neck}
    for side in ("l", "r"):
        for seg in ("thigh", "shank", "upperarm", "lowerarm"):
            out[f"{side}_{seg}"] = fmt.format(side=parts[side], part=parts[seg])
    return scheme(out)


SCHEMES = {
    "cmu": {},
    "mixamo": {joint: f"mixamorig:{joint}" for joint in CMU},
    "suffix_L": sided("{part}_{side}", {"l": "L", "r": "R", "thigh": "UpperLeg", "shank": "LowerLeg",
                                        "upperarm": "UpperArm", "lowerarm": "LowerArm"}, hip="Pelvis"),
    "thigh_R": sided("{part}_{side}", {"l": "L", "r": "R", "thigh": "Thigh", "shank": "Shin", "upperarm": "Arm",
                                       "lowerarm": "ForeArm"}),
    "prefix_Left": sided("{side}{part}", {"l": "Left", "r": "Right", "thigh": "Thigh", "shank": "Calf",
                                          "upperarm": "UpperArm", "lowerarm": "ForeArm"}),
    "L_prefix": sided("{side}_{part}", {"l": "L", "r": "R", "thigh": "UpperLeg", "shank": "Knee",
                                        "upperarm": "Humerus", "lowerarm": "Elbow"}),
    "lower_case": sided("{side}_{part}", {"l": "l", "r": "r", "thigh": "thigh", "shank": "shank",
                                          "upperarm": "upperarm", "lowerarm": "lowerarm"}, hip="pelvis", neck="neck"),
}


@pytest.fixture(scope="module")
def original(cmu_bvh_dir):
    return bvh.parse_bvh(cmu_bvh_dir / f"{CLIP}.bvh"), bvh.load_bvh(cmu_bvh_dir / f"{CLIP}.bvh", fs=None)


def assert_same_motion(path, reference, **kwargs) -> None:
    got = bvh.load_bvh(path, fs=None, **kwargs)
    assert got.segments == wire.SEGMENTS and got.rest_pose == reference.rest_pose
    assert quat.angle_deg(got.q, reference.q).max() < 1e-4
    assert got.root is not None and np.allclose(got.root, reference.root, atol=1e-6)


@pytest.mark.parametrize("name", SCHEMES)
@pytest.mark.parametrize("layout", ("plain", "six_channels_floor_root"))
def test_other_naming_schemes_and_layouts_read_as_the_clip(name, layout, original, tmp_path):
    clip, reference = original
    path = tmp_path / f"{name}.bvh"
    six = layout != "plain"
    path.write_text(write_bvh(clip, SCHEMES[name], six=six, floor_root="Root" if six else None))
    if six:
        parsed = bvh.parse_bvh(path)
        assert parsed.joints[0] == "Root" and all(len(c) == 6 for c in parsed.channels)
    assert_same_motion(path, reference)


def test_names_no_scheme_fits_are_refused_with_the_joints_then_mapped(original, tmp_path):
    clip, reference = original
    rename = {joint: f"J{k:02d}" for k, joint in enumerate(clip.joints)}
    path = tmp_path / "numbered.bvh"
    path.write_text(write_bvh(clip, rename))
    with pytest.raises(MotionFileError, match=r"match no naming scheme.*joints: J00, J01, .*--names JOINT=SEGMENT"):
        load(path)
    mapping = {rename[joint]: segment for joint, segment in CMU.items()}
    assert_same_motion(path, reference, names=mapping)
    listed = ",".join(f"{joint}={segment}" for joint, segment in mapping.items())
    result = cli(str(path), "--names", listed, "-o", str(tmp_path / "out.npz"))
    assert result.returncode == 0, result.stderr
    assert quat.angle_deg(load(tmp_path / "out.npz")[0].q, reference.q).max() < 1e-3
    result = cli(str(path), "--names", "J00=hip", "-o", str(tmp_path / "out.npz"))
    assert result.returncode == 2 and "no joint for segment l_shank" in result.stderr and "J30" in result.stderr
    result = cli(str(path), "--names", "Pelvis=hip", "-o", str(tmp_path / "out.npz"))
    assert result.returncode == 2 and "--names: no joint named 'Pelvis'" in result.stderr, result.stderr


def test_a_joint_missing_for_a_segment_is_named(original, tmp_path):
    clip, _ = original
    path = tmp_path / "no_forearm.bvh"
    path.write_text(write_bvh(clip, {**SCHEMES["thigh_R"], "LeftForeArm": "Crook_L"}))
    with pytest.raises(MotionFileError, match=r"no joint for segment l_lowerarm .*joints: .*Crook_L"):
        load(path)


def _posed(clip, j: int, c: np.ndarray) -> tuple[np.ndarray, dict[int, Rotation]]:
    """Offsets and local rotations of ``clip`` with the bones below joint ``j`` (its child and
    grandchild) turned by ``c`` at rest, and the motion turned back so the arm moves as before."""
    offsets = clip.offsets.copy()
    child = int(np.flatnonzero(clip.parents == j)[0])
    grandchild = int(np.flatnonzero(clip.parents == child)[0])
    r = quat.to_rotation(c)
    offsets[child] = r.apply(offsets[child])
    offsets[grandchild] = r.apply(offsets[grandchild])
    return offsets, {j: bvh.local_rotations(clip, j) * r.inv(), child: r * bvh.local_rotations(clip, child) * r.inv()}


@pytest.mark.parametrize("lowered_deg, rest_pose", ((40.0, "tpose"), (60.0, "standing"), (90.0, "standing")))
def test_the_rest_pose_comes_from_the_offsets(lowered_deg, rest_pose, original, tmp_path):
    """Arms lowered at rest by 40 deg (nearer a T-pose), 60 deg (an A-pose nearer standing), 90 deg
    (hanging): the segments point where the clip's do, from the rest pose the offsets show."""
    clip, reference = original
    offsets, locals_ = clip.offsets, {}
    for side, sign in (("Left", -1.0), ("Right", 1.0)):
        c = quat.from_rotation(Rotation.from_rotvec([0.0, 0.0, sign * np.radians(lowered_deg)]))
        offsets, more = _posed(dataclasses.replace(clip, offsets=offsets), clip.joints.index(f"{side}Arm"), c)
        locals_.update(more)
    path = tmp_path / f"lowered{lowered_deg:g}.bvh"
    path.write_text(write_bvh(clip, offsets=offsets, locals_=locals_))
    got = bvh.load_bvh(path, fs=None)
    assert got.rest_pose == rest_pose
    for k, seg in enumerate(wire.SEGMENTS):
        mine = quat.rotate(got.q[:, k], bone_axis(seg, rest_pose))
        theirs = quat.rotate(reference.q[:, k], bone_axis(seg, "tpose"))
        assert np.degrees(np.arccos(np.clip(np.sum(mine * theirs, axis=-1), -1, 1))).max() < 1e-3, seg
    if rest_pose == "tpose":
        assert quat.angle_deg(got.q, reference.q).max() < 1e-3


def test_cmu_clips_rest_pose_from_their_offsets(cmu_bvh_dir):
    """Subjects 1-5 stand in a T-pose at zero; subject 131's hierarchy hangs its arms."""
    assert {c: load(cmu_bvh_dir / f"{c}.bvh")[0].rest_pose for c in ("01_01", "02_01", "131_01")} == {
        "01_01": "tpose", "02_01": "tpose", "131_01": "standing"}
    assert shortest_arc(np.array([1.0, 0, 0]), np.array([-1.0, 0, 0]))[0] == pytest.approx(0.0)
