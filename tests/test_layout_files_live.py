"""A subject of a layout file's layout end to end over a real Zenoh router (e2e, docs/protocol.md
"Layout files on the wire"): its devices announce the layout whole in their status, the
aggregator publishes its frames and joint angles with layout byte 255, and the dashboard,
``limbstream watch``, a recording, its BVH export and its replay read them with the layout the devices announce; a status whose
layout table is malformed is counted on its device while everything streams on."""
from __future__ import annotations

import json
import signal

import numpy as np
import pytest
from support.bvh import read_bvh_positions
from support.command import Command
from support.export import cli
from support.devices import RawBodies
from support.stack import StatsWatch, http_json, stack, wait_for_subscribers, wait_until  # noqa: F401  (fixture)

from limbstream import wire
from limbstream.body import FULL, Body, load_layout
from limbstream.services.outputs.bvh_writer import bvh_joints
from limbstream.services.outputs.recording import Recording, RecordingError

pytestmark = pytest.mark.e2e

LEGS = ("hip", "l_thigh", "l_shank", "l_foot", "r_thigh", "r_shank", "r_foot")


def legs_file(tmp_path):
    """A layout file of the lower body (7 segments the generator moves; no built-in layout is it)."""
    path = tmp_path / "legs7.json"
    path.write_text(json.dumps(FULL.part("legs7", LEGS).to_dict()))
    return path


def test_a_layout_files_subject_is_served_by_the_dashboard_and_its_recording_exports_to_bvh(stack, tmp_path):  # noqa: F811
    legs = load_layout(legs_file(tmp_path))
    body = Body.default(legs)
    rec, out = tmp_path / "take.mcap", tmp_path / "s01.bvh"
    stack.router()
    stack.aggregator()
    url = stack.dashboard()
    recorder = stack.start("record", "record", str(rec), "--connect", stack.endpoint, "--no-skeleton")
    wait_for_subscribers(stack.endpoint, [wire.seg_key("s01", "hip"), wire.pose_key("s01")],
                         "the aggregator and the recorder", on_fail=stack.logs)
    stack.emulator(1, 1.0, "--layout", str(legs_file(tmp_path)))

    def served():
        status, pose = http_json(url + "/api/subjects/s01/pose?kind=exact")
        return pose if status == 200 and pose["layout"] == "legs7" and not pose["missing"] else None
    pose = wait_until(served, 40, "s01's legs7 frames on the dashboard", on_fail=stack.logs)
    assert list(pose["segments"]) == list(legs.segment_names) and list(pose["joints"]) == list(legs.joints)
    q = np.array([pose["segments"][s] for s in legs.segment_names])
    drawn = body.positions(q / np.linalg.norm(q, axis=1, keepdims=True))
    assert np.abs(np.array([pose["joints"][j] for j in legs.joints]) - drawn).max() < 1e-3  # (rounded to 0.1 mm)
    def refused() -> float:  # pose frames the dashboard could not read: only those before the devices' answer
        lines = [line for line in http_json(url + "/metrics")[1].splitlines()
                 if line.startswith('limbstream_dashboard_errors_total{reason="pose_layout"}')]
        return float(lines[0].split()[-1]) if lines else 0.0
    before = refused()
    seq = pose["seq"]
    wait_until(lambda: http_json(url + "/api/subjects/s01/pose?kind=exact")[1]["seq"] >= seq + 50, 20,
               "50 more exact frames", on_fail=stack.logs)
    assert refused() == before < 50, before
    status, view = http_json(url + "/api/subjects/s01")
    assert status == 200 and view["layout"] == "legs7" and view["pose_refused"] is None
    assert view["segments"] == list(legs.segment_names) and view["joints"] == list(legs.joints)
    assert view["bones"] == [[b.origin, b.joint] for b in legs.bones] and view["missing_segments"] == []
    assert view["bones_m"] == pytest.approx(body.lengths, abs=1e-5)  # (its stats round to 10 um)
    joints = wait_until(lambda: (r := http_json(url + "/api/subjects/s01/joints"))[0] == 200 and r[1], 20,
                        "s01's joint angles on the dashboard", on_fail=stack.logs)
    assert joints["names"] == list(wire.joint_angles(legs)) and "knee_angle_l" in joints["names"]
    assert "ankle_angle_r" in joints["names"] and "arm_flex_l" not in joints["names"]

    watch = Command(["watch", "s01", "--connect", stack.endpoint, "--count", "3", "--joints"])
    assert watch.exit_code(60.0)[0] == 0, watch.rest()
    shown = "\n".join(watch.rest())
    assert "live #" in shown and "legs7" in shown and "l_foot" in shown and "knee_angle_l" in shown, shown

    def recorded(kind):
        try:
            return list(Recording(rec).entries([kind]))
        except RecordingError:
            return []
    wait_until(lambda: len([e for e in recorded("pose") if e.payload[16] == wire.OTHER_LAYOUT]) >= 100
               and {e.key for e in recorded("config")} >= {wire.config_key("s01", s) for s in LEGS}, 40,
               "the recorder to hold s01's legs7 frames and its devices' statuses", on_fail=stack.logs)
    recorder.signal(signal.SIGTERM)
    assert recorder.popen.wait(20) == 0, stack.logs()
    summary = json.loads("{" + recorder.log.read_text().split("record: {", 1)[1].splitlines()[0])
    assert summary["messages"]["pose"] >= 100 and summary["messages"]["angles"] > 0, summary

    result = cli(str(rec), "--subject", "s01", "--format", "bvh", "-o", str(out))
    assert result.returncode == 0, result.stderr
    text = out.read_text()
    names = [line.split()[1] for line in text.splitlines() if line.strip().split()[:1] in (["ROOT"], ["JOINT"])]
    assert names == [j.name for j in bvh_joints(legs)] and len(names) == 7
    positions = read_bvh_positions(out)
    frames = int(text.split("Frames:")[1].split()[0])
    assert frames >= 100 and all(p.shape == (frames, 3) for p in positions.values())
    knee, ankle = (positions[j.name] for j in bvh_joints(legs) if j.segment in ("l_shank", "l_foot"))
    assert np.abs(np.linalg.norm(ankle - knee, axis=1) - body.lengths["l_shank"]).max() < 1e-3  # its bones, read back

    # replayed, its devices announce the recorded layout again: the aggregator's frames are legs7's
    stack.start("replay", "replay", str(rec), "--connect", stack.endpoint, "--subject-prefix", "r-", "--hold", "30")
    wait_until(lambda: (r := http_json(url + "/api/subjects/r-s01/pose"))[0] == 200 and r[1]["layout"] == "legs7",
               40, "the replayed subject's legs7 frames on the dashboard", on_fail=stack.logs)


def test_a_malformed_layout_table_in_a_status_is_counted_and_the_subject_streams_on(stack, tmp_path):  # noqa: F811
    stack.router()
    stack.aggregator()
    wait_for_subscribers(stack.endpoint, [wire.seg_key("b01", "hip")], "the aggregator", on_fail=stack.logs)
    good = wire.encode_body(Body.default(load_layout(legs_file(tmp_path))))
    cycle = json.loads(json.dumps(good))
    next(r for r in cycle["layout"]["segments"] if r["name"] == "hip")["parent"] = "l_shank"
    fakes = RawBodies(stack.endpoint)
    fakes.add("b01", {"hip": cycle, "l_thigh": cycle})
    fakes.add("g01", {s: good for s in LEGS})
    watch = StatsWatch(stack.endpoint)
    try:
        def counted():
            devices = watch.poll()
            return all((devices.get(f"b01/{s}", {}).get("dropped_by_reason") or {}).get("status_body")
                       for s in ("hip", "l_thigh")) and watch.subjects.get("g01", {}).get("layout") == "legs7"
        wait_until(counted, 30, "b01's malformed layouts counted, g01's layout taken", on_fail=stack.logs)
        status = wire.decode_status(json.dumps(wire.DeviceStatus("b01/hip", wire.DeviceConfig(), 7, 1, 1).as_dict()
                                               | {"body": cycle}).encode())
        assert status.body is None and "cycle of parents hip -> l_shank -> l_thigh -> hip" in status.body_error
        points = watch.poll()["b01/hip"]["points"]
        wait_until(lambda: watch.poll()["b01/hip"]["points"] > points + 25 and watch.subjects["b01"]["layout"] == "paper10",
                   20, "b01's points taken on in a built-in layout", on_fail=stack.logs)
        assert set(watch.poll()["b01/hip"]["dropped_by_reason"]) == {"status_body"}
    finally:
        watch.close()
        fakes.close()
