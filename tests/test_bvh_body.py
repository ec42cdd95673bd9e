"""A BVH file's wearer from its own OFFSETs (limbstream.sources.bvh_body, docs/protocol.md "Body
dimensions"): the same body whatever unit the file is written in, its bones' lengths the OFFSETs',
a skeleton with a bone out of bounds drawn as the default adult, with a warning naming the bound."""
from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from support.bvh import write_bvh

from limbstream.body import PAPER10
from limbstream.sources import bvh, load
from limbstream.sources.bvh_body import UNITS

CMU_UNIT_M = 0.0254 / 0.45
"""The CMU clips' OFFSET unit, m."""


@pytest.fixture(scope="module")
def clip(cmu_bvh_dir):
    return bvh.parse_bvh(cmu_bvh_dir / "01_01.bvh")


def scaled(clip, to_m: float):
    """The clip with its OFFSETs (and End Sites) in a unit of ``to_m`` metres."""
    k = CMU_UNIT_M / to_m
    return dataclasses.replace(clip, offsets=clip.offsets * k, end_offsets=clip.end_offsets * k)


def test_a_cmu_clip_brings_its_own_bones_in_metres(clip, cmu_bvh_dir):
    body = bvh.load_bvh(cmu_bvh_dir / "01_01.bvh").body
    at = {name: j for j, name in enumerate(clip.joints)}
    for bone, joint in (("l_thigh", "LeftLeg"), ("r_shank", "RightFoot"), ("l_upperarm", "LeftForeArm"),
                        ("r_lowerarm", "RightHand")):
        assert body.lengths[bone] == pytest.approx(np.linalg.norm(clip.offsets[at[joint]]) * CMU_UNIT_M, rel=1e-12)
    assert body.layout is PAPER10 and body.height_m is None
    assert body.lengths["l_thigh"] + body.lengths["l_shank"] == pytest.approx(0.827, abs=1e-3)


@pytest.mark.parametrize("unit", list(UNITS))
def test_the_same_body_whatever_unit_the_file_is_in(clip, unit, tmp_path):
    path = tmp_path / "clip.bvh"
    path.write_text(write_bvh(scaled(clip, UNITS[unit])))
    body = load(path)[0].body
    want = bvh.wearer(clip, bvh.bvh_names.segment_map(clip.path, clip.joints, None))
    assert body is not None and want is not None
    for pose in body.vectors:
        assert np.allclose(body.vectors[pose], want.vectors[pose], rtol=1e-5, atol=2e-6), unit  # (6 decimals)


def test_a_bone_of_no_length_gives_the_default_adult_and_says_so_with_its_bound(clip, tmp_path, caplog):
    offsets = clip.offsets.copy()
    offsets[clip.joints.index("LeftForeArm")] = 0.0  # the elbow on the shoulder
    path = tmp_path / "no_upper_arm.bvh"
    path.write_text(write_bvh(clip, offsets=offsets))
    assert bvh.load_bvh(path).body is None
    assert re.search(r"no_upper_arm\.bvh: its skeleton's OFFSETs give no body \(bone 'l_upperarm' must be in "
                     r"\(0, 1\.5\] m, got 0\.0\): drawn with the default adult's bones", caplog.text), caplog.text


def test_a_map_of_other_segments_gives_no_body(clip, cmu_bvh_dir):
    motion = bvh.load_bvh(cmu_bvh_dir / "01_01.bvh", segment_map={"l_thigh": "LeftUpLeg", "l_shank": "LeftLeg"})
    assert motion.body is None


def test_a_bvh_exported_from_a_bvh_source_keeps_its_bones(cmu_bvh_dir, tmp_path):
    from limbstream.services.outputs.export import bvh_text, read_take
    source = cmu_bvh_dir / "01_01.bvh"
    own = bvh.load_bvh(source).body
    path = tmp_path / "exported.bvh"
    path.write_text(bvh_text(read_take(source, None)))
    back = bvh.load_bvh(path).body
    assert back.lengths == pytest.approx(own.lengths, abs=2e-6)  # (OFFSETs in metres, 6 decimals)
    for pose in own.vectors:
        assert np.allclose(back.vectors[pose], own.vectors[pose], atol=2e-6)
