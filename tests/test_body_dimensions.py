"""The wearer's dimensions in the wire contract (a device status's ``"body"``, docs/protocol.md
"Body dimensions") and on the command line (``--height-m``, ``--body`` of ``emulate`` and ``up``):
read back equal, old statuses without them still read, bad ones refused with the bound."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from support import ROOT

from limbstream import wire
from limbstream.body import FULL, PAPER10, Body, load_layout

STATUS = wire.DeviceStatus("s01/hip", wire.DeviceConfig(), 3, 100, 12)


def decoded(body) -> wire.DeviceStatus:
    """A status carrying ``body`` (any JSON) as its ``"body"``, decoded."""
    return wire.decode_status(json.dumps(STATUS.as_dict() | {"body": body}).encode())


def same_bones(a: Body, b: Body) -> bool:
    return all(np.array_equal(a.vectors[p], b.vectors[p]) for p in wire.REST_POSES)


@pytest.mark.parametrize("body", [Body.from_height(PAPER10, 1.5), Body.from_height(PAPER10, 1.9),
                                  Body.default(PAPER10)], ids=["1.5_m", "1.9_m", "default"])
def test_a_status_carries_its_body_and_reads_back_the_same_bones(body):
    status = wire.decode_status(wire.encode_status(STATUS.__class__(**{**STATUS.__dict__, "body": body})))
    assert status.body is not None and status.body_error is None
    assert same_bones(status.body, body) and status.body.height_m == body.height_m
    assert status.body.layout is PAPER10


def test_an_old_status_without_a_body_still_reads_as_the_default_adult():
    old = {k: v for k, v in STATUS.as_dict().items() if k != "body"}
    status = wire.decode_status(json.dumps(old).encode())
    assert status.body is None and status.body_error is None and status.config == STATUS.config
    assert "body" not in STATUS.as_dict()


BONES = {k: v for k, v in Body.default(PAPER10).to_dict().items() if k != "layout"}


@pytest.mark.parametrize("body, said", [
    ({"layout": "paper10", "bones": BONES | {"l_thigh": 1.6}}, "bone 'l_thigh' must be in (0, 1.5] m, got 1.6"),
    ({"layout": "paper10", "bones": BONES | {"l_shank": 0}}, "bone 'l_shank' must be in (0, 1.5] m, got 0"),
    ({"layout": "paper10", "bones": BONES | {"neck": -0.2}}, "bone 'neck' must be in (0, 1.5] m, got -0.2"),
    ({"layout": "paper10", "height_m": 175, "bones": BONES}, "height must be within [0.5, 2.5] m, got 175"),
    ({"layout": "paper10", "height_m": 0.3, "bones": BONES}, "height must be within [0.5, 2.5] m, got 0.3"),
    ({"layout": "paper10", "bones": {k: v for k, v in BONES.items() if k != "neck"}}, "missing bone 'neck'"),
    ({"layout": "paper10", "bones": BONES | {"tail": 0.3}}, "layout paper10 has no bone 'tail'"),
    ({"layout": "paper10", "bones": BONES | {"l_shoulder": [0.2, "x", 0]}}, "bone 'l_shoulder' must be a length"),
    ({"layout": "nobody", "bones": BONES}, "layout must be one of paper10, full"),
    ({"bones": [0.4, 0.5]}, "body bones must be an object"),
    ("tall", "body must be an object"),
    ({"layout": "paper10", "bones": BONES, "weight_kg": 70}, "body must be an object of layout, height_m and bones"),
])
def test_a_malformed_body_is_refused_with_the_bound_and_the_rest_of_the_status_reads(body, said):
    status = decoded(body)
    assert status.body is None and said in status.body_error and "\n" not in status.body_error
    assert status.config == STATUS.config and status.points == 12 and status.rest_pose == "standing"


SUIT = load_layout(ROOT / "examples" / "layouts" / "suit17.toml")


def suit_body(**change) -> dict:
    """suit17's default body as a status carries it, its layout table changed by ``change``
    (segment name -> {key: value}; a key's value None: the key left out)."""
    data = json.loads(json.dumps(wire.encode_body(Body.default(SUIT))))
    for name, keys in change.items():
        row = next(r for r in data["layout"]["segments"] if r["name"] == name)
        for key, value in keys.items():
            row.pop(key) if value is None else row.__setitem__(key, value)
    return data


@pytest.mark.parametrize("layout", [SUIT, load_layout(ROOT / "examples" / "layouts" / "back16.json")],
                         ids=["suit17", "back16"])
def test_a_layout_files_body_carries_its_layout_whole_and_reads_back_equal(layout):
    body = Body.from_height(layout, 1.62)
    said = wire.encode_body(body)
    assert said["layout"] == layout.to_dict()  # the table a layout file holds
    status = wire.decode_status(wire.encode_status(STATUS.__class__(**{**STATUS.__dict__, "body": body})))
    assert status.body_error is None and status.body.layout == layout and status.body.height_m == 1.62
    assert wire.body_layout(layout.to_dict()) == layout and same_bones(status.body, body)
    assert len(wire.encode_status(status)) < 4096  # (suit17's whole status: about 3.6 kB)
    assert wire.encode_body(Body.default(FULL))["layout"] == "full"  # a built-in's travels as its name only


@pytest.mark.parametrize("body, said", [
    (suit_body(hip={"parent": "l_shank"}), "cycle of parents hip -> l_shank -> l_thigh -> hip"),
    (suit_body(l_hand={"parent": "l_wrist"}), "segment 'l_hand' has a missing parent 'l_wrist'"),
    (suit_body(r_hand={"name": "l_hand"}), "duplicate segment 'l_hand'"),
    (suit_body(l_foot={"direction": [0, 0, 0]}), "direction must be finite and non-zero"),
    (suit_body(l_foot={"wings": 2}), "unknown key 'wings'"),
    (suit_body(l_foot={"joint": None}), "'joint' must be a name"),
    (suit_body() | {"layout": {**suit_body()["layout"], "name": "full"}}, "a table named 'full', a built-in layout's"),
    (suit_body() | {"layout": {**suit_body()["layout"], "pad": "x" * wire.MAX_LAYOUT_BYTES}},
     f"at most {wire.MAX_LAYOUT_BYTES}"),
    (suit_body() | {"layout": [1, 2]}, "body layout must be a built-in's name or a layout table"),
    (suit_body() | {"bones": BONES}, "layout suit17 has no bone"),
], ids=["cycle", "missing_parent", "duplicate", "zero_direction", "unknown_key", "no_joint", "builtin_name", "too_big",
        "not_a_table", "other_bones"])
def test_a_malformed_layout_table_is_refused_naming_it_and_the_rest_of_the_status_reads(body, said):
    test_a_malformed_body_is_refused_with_the_bound_and_the_rest_of_the_status_reads(body, said)


def limbstream(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "limbstream.cli", *argv], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)


@pytest.mark.parametrize("command", ["up", "emulate"])
@pytest.mark.parametrize("flags, said", [
    (["--height-m", "175"], "--height-m: height must be within [0.5, 2.5] m, got 175.0"),
    (["--height-m", "0"], "--height-m: height must be within [0.5, 2.5] m, got 0.0"),
    (["--height-m", "1.5,-1"], "--height-m: height must be within [0.5, 2.5] m, got -1.0"),
    (["--height-m", "tall"], "--height-m: a height in m, or several: H,H,..., got 'tall'"),
    (["--height-m", "1.7", "--body", "me.toml"], "--height-m and --body both give the subjects' dimensions"),
    (["--body", "{dir}/long.toml"], "long.toml: bone 'l_thigh' must be in (0, 1.5] m, got 1.6"),
    (["--body", "{dir}/zero.json"], "zero.json: bone 'l_shank' must be in (0, 1.5] m, got 0"),
    (["--body", "{dir}/broken.toml"], "broken.toml: not valid TOML"),
    (["--body", "{dir}/short.toml"], "short.toml: missing bone 'neck' of layout paper10"),
    (["--body", "{dir}/none.toml"], "none.toml: cannot read"),
], ids=["height_175", "height_0", "second_height_negative", "height_text", "both", "thigh_1.6_m", "shank_0",
        "not_toml", "bone_missing", "no_file"])
def test_bad_dimensions_on_the_command_line_are_refused_up_front_in_one_line(tmp_path, command, flags, said):
    lines = [f"{k} = {v}" for k, v in BONES.items() if not isinstance(v, list)]
    lines += [f"{k} = {v}" for k, v in BONES.items() if isinstance(v, list)]
    (tmp_path / "long.toml").write_text("\n".join(lines).replace("l_thigh = 0.45", "l_thigh = 1.6"))
    (tmp_path / "short.toml").write_text("\n".join(line for line in lines if not line.startswith("neck")))
    (tmp_path / "broken.toml").write_text("hip = = 0.5")
    (tmp_path / "zero.json").write_text(json.dumps(BONES | {"l_shank": 0}))
    out = limbstream(command, "--layout", "paper10", *(f.format(dir=tmp_path) for f in flags))  # (BONES: paper10's)
    assert out.returncode == 2, (out.stdout, out.stderr)
    assert out.stderr.count("\n") == 1 and out.stderr.startswith(f"limbstream {command}: error: "), out.stderr
    assert said in out.stderr, out.stderr
    assert "starting" not in out.stdout  # refused before anything started


def test_a_good_body_file_sizes_the_subject_as_it_says(tmp_path):
    path = tmp_path / "me.toml"
    path.write_text("\n".join(f"{k} = {v}" if not isinstance(v, str) else f'{k} = "{v}"'
                              for k, v in (Body.from_height(PAPER10, 1.62).to_dict()).items()))
    from limbstream.cli import flags
    args = type("Args", (), {"height_m": None, "body": f"{path},{path}"})()
    given = flags.bodies(args)
    assert len(given) == 2 and same_bones(given[0], Body.from_height(PAPER10, 1.62))
    assert flags.body_argv(args) == ["--body", f"{path.resolve()},{path.resolve()}"]


def decoded_message(message):
    """A foxglove-sdk message decoded with the protobuf schema it carries (as the app reads it)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    schema = message.get_schema()
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name)).FromString(message.encode())


@pytest.mark.parametrize("height_m", [1.5, 1.9])
def test_foxglove_stands_each_subject_on_the_grid_on_its_own_legs(height_m):
    from limbstream.services.outputs import foxglove as fox
    body = Body.from_height(PAPER10, height_m)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(wire.SEGMENTS), 1)).astype(np.float32)
    frame = wire.PoseFrame(0, 1_000_000, wire.KIND_LIVE, 0, q, body.positions(q))
    got = decoded_message(fox.frame_transforms("s01", frame))
    root = next(t for t in got.transforms if t.child_frame_id == "s01")
    leg = body.lengths["l_thigh"] + body.lengths["l_shank"]
    assert root.translation.z == pytest.approx(leg, rel=1e-6)  # standing: the ankles on the grid (z = 0)
    assert decoded_message(fox.placement(0, fox.leg_m(frame))).position.z == pytest.approx(leg, rel=1e-6)


def bone_positions(bundle: bytes) -> dict[str, np.ndarray]:
    """Bone name -> its /VMC/Ext/Bone/Pos position (3,) of a VMC bundle."""
    from pythonosc.osc_bundle import OscBundle
    return {m.params[0]: np.array(m.params[1:4]) for m in OscBundle(bundle) if m.address == "/VMC/Ext/Bone/Pos"}


def test_vmc_sends_the_bone_offsets_of_each_subjects_body():
    from limbstream.services.outputs import vmc
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(wire.SEGMENTS), 1)).astype(np.float32)
    encoder = vmc.VmcEncoder()
    default = bone_positions(encoder.encode(wire.PoseFrame(0, 0, wire.KIND_LIVE, 0, q, Body.default(PAPER10).positions(q))))
    assert all(np.array_equal(default[b.name], p) for b, p in zip(vmc.VMC_BONES, vmc.rest_positions().astype(np.float32)))
    for k, height_m in enumerate((1.5, 1.9, 1.5), start=1):  # each change of body is sent (read once a second)
        body = Body.from_height(PAPER10, height_m)
        got = bone_positions(encoder.encode(wire.PoseFrame(k, k * vmc.SIZE_EVERY_US, wire.KIND_LIVE, 0, q,
                                                           body.positions(q))))
        bones = body.lengths
        assert got["Hips"][1] == pytest.approx(bones["l_thigh"] + bones["l_shank"], rel=1e-6)
        assert got["LeftLowerLeg"][1] == pytest.approx(-bones["l_thigh"], rel=1e-6)
        assert got["LeftFoot"][1] == pytest.approx(-bones["l_shank"], rel=1e-6)
        assert got["RightLowerArm"][0] == pytest.approx(bones["r_upperarm"], rel=1e-6)  # (Unity's x: to the right)
        assert got["RightHand"][0] == pytest.approx(bones["r_lowerarm"], rel=1e-6)
        assert got["Head"][1] == pytest.approx(bones["neck"], rel=1e-6)


@pytest.mark.parametrize("argv, said", [
    (["slimevr", "--height-m", "2.6"], "--height-m: height must be within [0.5, 2.5] m, got 2.6"),
    (["slimevr", "--height-m", "1.5,1.6"], "--height-m: one wearer's dimensions for the gateway's devices, got 2"),
    (["serial", "--port", "tcp:127.0.0.1:1", "--subject", "s01", "--segment", "hip", "--height-m", "0.4"],
     "--height-m: height must be within [0.5, 2.5] m, got 0.4"),
    (["serial", "--port", "tcp:127.0.0.1:1", "--subject", "s01", "--segment", "hip", "--body", "none.toml"],
     "--body none.toml: cannot read"),
], ids=["slimevr_height", "slimevr_two", "serial_height", "serial_no_file"])
def test_a_gateways_bad_dimensions_are_refused_in_one_line(argv, said):
    out = limbstream("gateway", *argv)
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and said in out.stderr, out.stderr


def test_a_slimevr_gateway_of_a_layout_file_announces_its_body_whole():
    """``gateway slimevr --layout FILE``: its trackers announce the file's default body (its
    layout whole on the wire), or the one ``--height-m`` gives; without ``--layout``, full's."""
    import argparse

    from limbstream.cli import gateway_slimevr
    parser = argparse.ArgumentParser()
    gateway_slimevr.add_arguments(parser)
    suit = str(ROOT / "examples" / "layouts" / "suit17.toml")
    body = gateway_slimevr._body(parser.parse_args(["--layout", suit]))
    assert body.layout == SUIT and wire.decode_body(wire.encode_body(body)).layout == SUIT
    body = gateway_slimevr._body(parser.parse_args(["--layout", suit, "--height-m", "1.6"]))
    assert body.layout == SUIT and body.height_m == 1.6
    assert gateway_slimevr._body(parser.parse_args([])).layout.name == "full"  # (the default layout's)
