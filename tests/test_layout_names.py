"""``--names`` on a layout file: a BVH joint or a sensor maps to any segment of the layout in
effect (a layout file's own: ``lower_back``, ``femur_r``), checked once ``--layout`` is known, a
segment the layout lacks refused in one line with its segments; sensors left out for having no
segment of the layout are named in one line (``eval``, ``export``, ``up``, each run as a user runs it)."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

import numpy as np
import pytest
from support import ROOT, require_data
from support.stack import stack, wait_until  # noqa: F401  (stack is a fixture)

from limbstream import quat, wire
from limbstream.body import Body, layout
from limbstream.cli import up as up_cli
from limbstream.sources import load

BACK16 = "examples/layouts/back16.json"


def limbstream(*args: str) -> subprocess.CompletedProcess:
    """``limbstream ARGS`` from the repository's root: its exit status and output."""
    return subprocess.run([sys.executable, "-m", "limbstream.cli", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)


def error_line(result: subprocess.CompletedProcess) -> str:
    """The one line a refused command prints (exit status 2, nothing else on stderr)."""
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, result.stderr
    return lines[0]


def legs_layout(path, names: dict[str, str]) -> str:
    """A layout file of a pelvis and two legs (no feet) whose segments are named by ``names``
    (pelvis, thigh_l, shank_l, thigh_r, shank_r -> the file's own names)."""
    down = [0.0, -1.0, 0.0]
    rows = [{"name": names["pelvis"], "joint": "pelvis", "end": "lumbar", "direction": [0, 1, 0], "height_fraction": 0.1}]
    for side, x in (("l", 1.0), ("r", -1.0)):
        rows += [{"name": names[f"thigh_{side}"], "parent": names["pelvis"], "joint": f"{side}_hip", "end": f"{side}_knee",
                  "direction": down, "height_fraction": 0.245,
                  "offset": {"from": "pelvis", "direction": [x, 0, 0], "height_fraction": 0.04775}},
                 {"name": names[f"shank_{side}"], "parent": names[f"thigh_{side}"], "joint": f"{side}_knee",
                  "end": f"{side}_ankle", "direction": down, "height_fraction": 0.246}]
    path.write_text(json.dumps({"name": "legs5", "segments": rows}))
    return str(path)


def test_eval_maps_bvh_joints_to_a_layout_files_own_segments(cmu_bvh_dir, tmp_path):
    """``eval 131_01.bvh --layout back16.json --names lowerback=lower_back,Chest2=upper_back``:
    the layout file's back segments turn with the joints named, the other segments with those the
    naming schemes find; every segment of back16 is scored."""
    clip = cmu_bvh_dir / "131_01.bvh"
    result = limbstream("eval", str(clip), "--layout", BACK16, "--names", "lowerback=lower_back,Chest2=upper_back",
                        "--algorithms", "fastsw", "--thresholds", "0", "--max-len", "25", "--dump", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert "1 motion, 16 streams" in result.stdout, result.stdout
    dump = np.load(tmp_path / "131_01.npz")
    back16 = layout(BACK16)
    assert tuple(dump["segment_names"]) == back16.segment_names and str(dump["layout"]) == "back16"
    upper = back16.segment_index["upper_back"]
    [named] = load(clip, {"lowerback": "lower_back", "Chest2": "upper_back"}, layout=back16)
    [other] = load(clip, {"lowerback": "lower_back", "Chest": "upper_back"}, layout=back16)
    truth = dump["truth"][:, upper]
    assert quat.angle_deg(truth, named.segment("upper_back")[: len(truth)]).max() < 1e-3
    assert quat.angle_deg(truth, other.segment("upper_back")[: len(truth)]).max() > 5.0


@pytest.mark.parametrize("flags, message", [
    (["--layout", BACK16, "--names", "lowerback=lower_bak"],
     "limbstream eval: error: --names: 'lower_bak' is not a segment of layout back16; its segments: hip, lower_back, "
     "upper_back, head, l_upperarm, l_lowerarm, l_hand, r_upperarm, r_lowerarm, r_hand, l_thigh, l_shank, l_foot, "
     "r_thigh, r_shank, r_foot"),
    (["--names", "Chest2=upper_back"],
     "limbstream eval: error: --names: 'upper_back' is not a segment of a built-in layout (a layout file's with "
     "--layout FILE); theirs: l_shank, r_shank,"),
    (["--names", "Chest=chest"],  # a BVH file is read onto paper10 without --layout
     "131_01.bvh: --names: 'chest' is not a segment of layout paper10; its segments: l_shank, r_shank,"),
], ids=["not in the layout file", "a layout file's segment without it", "full's segment on paper10"])
def test_a_segment_the_layout_lacks_is_one_line_naming_it_and_the_layouts_segments(cmu_bvh_dir, flags, message):
    result = limbstream("eval", str(cmu_bvh_dir / "131_01.bvh"), *flags, "--algorithms", "fastsw", "--thresholds", "0")
    assert message in error_line(result)


def test_an_xsens_recording_on_a_layout_file_that_names_its_sensors(xsens_dir, tmp_path):
    """The OpenSense walk on a layout file of OpenSim's names (pelvis, femur_r, tibia_r, ...): the
    five sensors ``--names`` maps are its segments; the three it does not map are named in one line."""
    legs = legs_layout(tmp_path / "legs.json", {"pelvis": "pelvis", "thigh_l": "femur_l", "shank_l": "tibia_l",
                                                "thigh_r": "femur_r", "shank_r": "tibia_r"})
    mapping = "00B42279=pelvis,00B4227C=femur_r,00B4227D=tibia_r,00B421EE=femur_l,00B421ED=tibia_l"
    result = limbstream("eval", str(xsens_dir), "--layout", legs, "--names", mapping, "--algorithms", "fastsw",
                        "--thresholds", "0")
    assert result.returncode == 0, result.stderr
    assert "1 motion, 5 streams" in result.stdout, result.stdout
    assert "limbstream eval: note: xsens_opensense: 00B421E6, 00B421EF, 00B42268: not named by --names, left out" \
        in result.stderr.splitlines(), result.stderr
    refused = limbstream("eval", str(xsens_dir), "--layout", legs, "--names", mapping + ",00B421EF=r_foot")
    assert "--names: 'r_foot' is not a segment of layout legs5; its segments: pelvis, femur_l, tibia_l, femur_r, " \
           "tibia_r" in error_line(refused)


def test_x_imu3_sensors_on_segments_the_layout_lacks_are_named_in_one_line(xio_dir, tmp_path):
    """The x-IMU3 set read onto a layout file without feet: its feet are left out, one line names
    them (no Python warning, no source line)."""
    legs = legs_layout(tmp_path / "legs.json", {"pelvis": "hip", "thigh_l": "l_thigh", "shank_l": "l_shank",
                                                "thigh_r": "r_thigh", "shank_r": "r_shank"})
    result = limbstream("eval", str(xio_dir), "--layout", legs, "--algorithms", "fastsw", "--thresholds", "0")
    assert result.returncode == 0, result.stderr
    assert "1 motion, 5 streams" in result.stdout, result.stdout
    assert "limbstream eval: note: xio_lower_body: l_foot, r_foot: no segment of layout legs5, left out" \
        in result.stderr.splitlines() and "Warning" not in result.stderr, result.stderr


def test_export_of_a_raw_recording_names_the_sensors_it_leaves_out(tmp_path):
    """The qmt 16-IMU .mat exported: onto ``full`` its lower back has no segment, without a layout
    (the 10-IMU body) its feet, hands and backs have none; one line names them."""
    path = require_data("qmt_full_body/full_body_example_data.mat")
    result = limbstream("export", str(path), "--layout", "full", "-o", str(tmp_path / "full.npz"))
    assert result.returncode == 0, result.stderr
    assert "limbstream export: note: full_body_example_data: lower_back: no segment of layout full, left out" \
        in result.stderr.splitlines(), result.stderr
    result = limbstream("export", str(path), "-o", str(tmp_path / "paper10.npz"))
    assert result.returncode == 0, result.stderr
    assert ("limbstream export: note: full_body_example_data: foot_left, foot_right, lower_back, upper_back, "
            "hand_left, hand_right: no segment of a built-in layout, left out") in result.stderr.splitlines(), \
        result.stderr


def test_up_takes_a_recording_named_onto_a_layout_files_segments(xsens_dir, tmp_path):
    """``up --source <xsens> --layout legs.json --names ...``: each subject's devices are the
    layout file's segments the sensors are named to (a BVH file's: every segment of the layout);
    a segment it lacks is refused by name."""
    legs = legs_layout(tmp_path / "legs.json", {"pelvis": "pelvis", "thigh_l": "femur_l", "shank_l": "tibia_l",
                                                "thigh_r": "femur_r", "shank_r": "tibia_r"})
    parser = argparse.ArgumentParser()
    up_cli.add_arguments(parser)
    mapping = "00B42279=pelvis,00B4227C=femur_r,00B4227D=tibia_r,00B421EE=femur_l,00B421ED=tibia_l"
    args = parser.parse_args(["--source", str(xsens_dir), "--layout", legs, "--names", mapping, "--no-sync"])
    [devices] = up_cli.check(args)
    assert set(devices) == {"pelvis", "femur_r", "tibia_r", "femur_l", "tibia_l"}
    bvh = parser.parse_args(["--source", str(require_data("cmu/131_01.bvh")), "--layout", BACK16,
                             "--names", "Chest2=upper_back", "--no-sync"])  # a BVH file is read onto the layout
    assert up_cli.check(bvh) == [layout(BACK16).segment_names]
    result = limbstream("up", "--source", str(xsens_dir), "--layout", legs, "--names", "00B42279=hip")
    assert "limbstream up: error: --names: 'hip' is not a segment of layout legs5" in result.stderr, result.stderr
    assert result.returncode == 2


def test_emulate_streams_a_bvh_file_on_a_layout_files_segments_named_by_names(stack, cmu_bvh_dir):  # noqa: F811
    """``emulate --source 131_01.bvh --layout back16.json --names Chest2=upper_back`` on a real
    router: a device per segment of back16 (the BVH file read onto it, not onto paper10) publishes
    its points, and announces a body of back16 (its default: back16's pelvis bone ends on CMU's
    pelvis, a bone of length 0 in the file)."""
    from test_emulate_layout import Heard

    back16 = layout(BACK16)
    stack.router()
    heard = Heard(stack.endpoint)
    try:
        stack.emulator(1, 1.0, "--source", str(cmu_bvh_dir / "131_01.bvh"), "--layout", str(ROOT / BACK16),
                       "--names", "Chest2=upper_back")
        want = {("s01", segment) for segment in back16.segment_names}

        def all_heard() -> bool:
            with heard.lock:
                return heard.points >= want
        wait_until(all_heard, 60, "points of back16's 16 segments", on_fail=stack.logs)
        assert {segment for _, segment in heard.points} == set(back16.segment_names)
        status = wait_until(lambda: heard.status("s01", "upper_back"), 30, "upper_back's status")
        body = wire.decode_body(status["body"])
        assert body.layout == back16 and body.lengths == Body.default(back16).lengths
    finally:
        heard.close()
