"""Each subject's body layout comes from its data (docs/protocol.md, "Body layouts in the
aggregator"): the layout its devices' status body names, else the smallest built-in one holding
its devices' segments. A subject of ``full`` gets 512-byte frames of 15 segments drawn with its
body beside a ``paper10`` subject streaming as before; a device whose segment the layout lacks,
or whose status names another layout, is counted on it while the rest streams. Truth scoring,
heading correction and calibration take the subject's segments and joints. An aggregator fed by
hand here; tests/test_aggregator_layouts_live.py runs the same over a real Zenoh router."""
from __future__ import annotations

import json

import numpy as np
import pytest

from support.devices import pose_of

from limbstream import quat, wire
from limbstream.body import FULL, PAPER10, Body
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
from limbstream.services.aggregator.layouts import joint_table, joints_of
from limbstream.skeleton import Skeleton

T0 = 1_700_000_000_000_000
STEP_US = 100_000  # one segment point every 100 ms
F32 = 2e-6


def aggregator() -> tuple[Aggregator, list[tuple[str, bytes]]]:
    """An aggregator without a session whose published frames are kept as (subject, payload)."""
    agg = Aggregator(None, AggregatorSettings())
    sent: list[tuple[str, bytes]] = []
    agg._publish = lambda subject, payload: sent.append((subject, payload))
    return agg, sent


def status(subject: str, segment: str, body: Body | None) -> bytes:
    entry = wire.DeviceStatus(f"{subject}/{segment}", wire.DeviceConfig(), 1, 0, 0).as_dict()
    return json.dumps(entry | ({} if body is None else {"body": wire.encode_body(body)})).encode()


def device(agg: Aggregator, subject: str, segment: str, body: Body | None = None) -> None:
    """A device online, its status (with ``body``) answered."""
    agg.on_alive(wire.alive_key(subject, segment), True)
    agg.on_config(wire.config_key(subject, segment), status(subject, segment, body))


TRUTH_TURNS_DEG = {"chest": 9.0}
"""Segments whose truth is turned from what their points say (about X), degrees."""


def send(agg: Aggregator, subject: str, segment: str, seqs, now: float, truth: bool = False) -> None:
    """Points of sequence numbers ``seqs`` (point k at T0 + k * 100 ms) holding the segment's
    constant orientation, arriving at ``now``; with ``truth``, truth samples of it with reference
    times (turned by TRUTH_TURNS_DEG)."""
    q = pose_of(segment)
    turn = np.radians(TRUTH_TURNS_DEG.get(segment, 0.0)) / 2
    true = quat.multiply(np.array([np.cos(turn), np.sin(turn), 0.0, 0.0]), q)
    for k in seqs:
        point = wire.SegmentPoint(1, k, 5 * k, T0 + k * STEP_US, tuple(q), omega=(0.0, 0.0, 0.0))
        agg.on_point(wire.seg_key(subject, segment), wire.encode_point(point), now)
        if truth:
            t = np.array([T0 + k * STEP_US])
            batch = wire.RawBatch(1, 5 * k, t, true[None].astype(np.float32), t.copy())
            agg.on_raw(wire.raw_key(subject, segment), wire.encode_raw(batch), now)


def frames_of(sent: list[tuple[str, bytes]], subject: str, kind: int = wire.KIND_EXACT) -> list[tuple[bytes, wire.PoseFrame]]:
    return [(p, f) for s, p in sent if s == subject and (f := wire.decode_pose(p)).kind == kind]


def subject_stats(agg: Aggregator, subject: str) -> tuple[dict, dict]:
    """(subject fields, {segment: device entry})."""
    stats = agg.subject_stats(subject, 0.0)
    return stats, {d["device"].split("/")[1]: d for d in stats["devices"]}


def stream(agg: Aggregator, subjects: dict[str, tuple[str, ...]], steps: int = 11, truth: bool = False) -> None:
    for subject, segments in subjects.items():
        for segment in segments:
            send(agg, subject, segment, range(steps), now=0.0, truth=truth)
    agg.advance(live=True, now=0.0)


def test_a_full_subject_gets_15_segment_frames_drawn_with_its_body_beside_a_paper10_subject_as_before():
    agg, sent = aggregator()
    tall = Body.from_height(FULL, 1.8)
    for segment in FULL.segment_names:
        device(agg, "f01", segment, tall)
    for segment in wire.SEGMENTS:
        device(agg, "s01", segment)
    stream(agg, {"f01": FULL.segment_names, "s01": wire.SEGMENTS})
    for kind in (wire.KIND_EXACT, wire.KIND_LIVE):
        full = frames_of(sent, "f01", kind)
        assert full and all(len(p) == 512 for p, _ in full)
        for _, f in full:
            assert f.layout == FULL and f.flags == 0 and f.q.shape == (15, 4) and f.joints.shape == (20, 3)
            want = np.array([pose_of(s) for s in FULL.segment_names])
            assert np.abs(np.abs((f.q * want).sum(axis=1)) - 1).max() < 1e-6
            assert np.abs(f.joints - tall.positions(f.q.astype(np.float64))).max() < 1e-5
        paper = frames_of(sent, "s01", kind)
        assert paper and all(len(p) == 372 for p, _ in paper)
        for _, f in paper:
            assert f.layout == PAPER10 and f.flags == wire.FRAME_NO_ROOT and not f.has_root  # no feet: no root
            assert np.abs(f.joints - Skeleton().positions(f.q.astype(np.float64))).max() < 1e-6
    assert len(frames_of(sent, "f01")) == len(frames_of(sent, "s01")) == 51
    assert subject_stats(agg, "f01")[0]["layout"] == "full" and subject_stats(agg, "s01")[0]["layout"] == "paper10"
    assert subject_stats(agg, "f01")[0]["bones_m"] == pytest.approx(tall.lengths)


def test_a_subject_without_a_body_takes_the_smallest_layout_of_its_segments_drawn_with_its_default_body():
    agg, sent = aggregator()
    legs = ("hip", "l_thigh", "l_shank", "l_foot")  # a foot: only full has one
    for segment in legs:
        device(agg, "f02", segment)
    stream(agg, {"f02": legs})
    (_, f), *_ = frames_of(sent, "f02")
    assert f.layout == FULL and f.flags & wire.FRAME_MISSING  # (its other segments have no device)
    assert np.abs(f.joints - Body.default(FULL).positions(f.q.astype(np.float64))).max() < 1e-5
    fields, _ = subject_stats(agg, "f02")
    assert fields["layout"] == "full" and "bones_m" not in fields


def test_a_device_whose_segment_its_subjects_layout_lacks_is_counted_and_the_rest_streams():
    agg, sent = aggregator()
    for segment in FULL.segment_names:
        device(agg, "f01", segment, Body.default(FULL))
    device(agg, "f01", "neck", Body.default(FULL))  # paper10's, not full's
    device(agg, "f01", "tail")                      # no built-in layout's
    stream(agg, {"f01": (*FULL.segment_names, "neck", "tail")})
    frames = frames_of(sent, "f01")
    assert len(frames) == 51 and all(f.layout == FULL and f.flags == 0 for _, f in frames)
    _, devices = subject_stats(agg, "f01")
    for segment in ("neck", "tail"):
        assert devices[segment]["dropped_by_reason"] == {"segment_not_in_layout": 11}
    assert not any(devices[s]["dropped_by_reason"] for s in FULL.segment_names)


def test_a_device_whose_status_names_another_layout_is_counted_and_the_subject_keeps_its_own():
    agg, sent = aggregator()
    device(agg, "f01", "hip", Body.default(FULL))
    device(agg, "f01", "l_shank", Body.default(PAPER10))  # the subject's layout is full already
    for segment in FULL.segment_names[1:]:
        device(agg, "f01", segment)
    agg.on_config(wire.config_key("f01", "l_shank"), status("f01", "l_shank", Body.default(PAPER10)))
    stream(agg, {"f01": FULL.segment_names})
    fields, devices = subject_stats(agg, "f01")
    assert fields["layout"] == "full" and devices["l_shank"]["dropped_by_reason"] == {"status_layout": 2}
    assert all(f.layout == FULL for _, f in frames_of(sent, "f01")) and len(frames_of(sent, "f01")) == 51
    assert not devices["l_shank"]["dropped_by_reason"].get("segment_not_in_layout")


def test_truth_scoring_compares_every_segment_and_joint_of_a_full_subject():
    """The chest's truth is 9 degrees off what its points say: 9/15 degrees per frame of the full
    subject, 9 degrees on each of the 4 of its 14 joints that join the chest (the lumbar spine,
    the shoulders, the neck)."""
    agg, _ = aggregator()
    for segment in FULL.segment_names:
        device(agg, "f01", segment, Body.default(FULL))
    for segment in wire.SEGMENTS:
        device(agg, "s01", segment)
    stream(agg, {"f01": FULL.segment_names, "s01": wire.SEGMENTS}, steps=21, truth=True)
    agg.advance(live=False, now=1.0)
    for subject, frame_deg, joint_deg in (("f01", 9.0 / 15, 4 * 9.0 / 14), ("s01", 0.0, 0.0)):
        fields, devices = subject_stats(agg, subject)
        assert fields["frame_error_frames"] > 0 and fields["frame_aad_deg"] == pytest.approx(frame_deg, abs=1e-3)
        assert fields["joint_aad_deg"] == pytest.approx(joint_deg, abs=1e-3)
        assert all(d["error_samples"] > 0 and d["aad_deg"] == pytest.approx(TRUTH_TURNS_DEG.get(s, 0.0), abs=1e-3)
                   for s, d in devices.items())


def test_the_joints_of_a_layout_are_its_joint_tables_the_shoulders_and_neck_off_a_chest():
    assert joint_table(PAPER10) is wire.JOINT_TABLE and joint_table(FULL) == wire.joint_table("full")
    full = {j.name: (j.parent, j.child) for j in joint_table(FULL)}
    assert full["shoulder_r"] == ("chest", "r_upperarm") and full["shoulder_l"] == ("chest", "l_upperarm")
    assert full["neck"] == ("chest", "head") and full["lumbar"] == ("hip", "chest")
    lay = joints_of(FULL, rest_pose="tpose")
    before, after = lay.to_standing()
    assert lay.segments == FULL.segment_names and before.shape == after.shape == (len(full), 4)


def test_a_full_subject_calibrates_on_request_and_its_headings_are_corrected_by_its_joints():
    agg, sent = aggregator()
    legs_missing = tuple(s for s in FULL.segment_names if s != "l_foot")
    for segment in legs_missing:
        device(agg, "f01", segment, Body.default(FULL))
    stream(agg, {"f01": legs_missing}, steps=5)
    req = agg.fusion.start_request("f01", "rest", 0.0)
    assert not isinstance(req, str) and req.absent == ["l_foot"]
    stream(agg, {"f01": legs_missing}, steps=40)
    answer = agg.fusion.finish_request(req, 0.5)
    assert answer is not None and answer.ok, answer
    assert sorted(answer.devices) == sorted(f"f01/{s}" for s in legs_missing)
    count = len(frames_of(sent, "f01"))
    for s in legs_missing:
        send(agg, "f01", s, range(40, 80), now=2.0)
    agg.advance(live=False, now=2.0)
    after = frames_of(sent, "f01")[count:]
    assert after and all(np.abs(f.q[FULL.segment_index["chest"]] - [1, 0, 0, 0]).max() < 1e-5 for _, f in after)
    _, devices = subject_stats(agg, "f01")
    assert all(devices[s]["calibrated"] for s in legs_missing)
    held = {s for s in legs_missing if devices[s]["heading_confidence"] > 0.5}  # held by a joint (the chest: shoulders, ...)
    assert held == set(legs_missing)  # (every segment present has a joint with one present: full's table)


def test_frames_carry_the_root_translation_of_the_subjects_feet():
    """Each subject's frames carry its root, tracked from its frames' feet (docs/body.md, "Root
    translation"): a full subject walking (the generator's walk, every sample a point) moves over
    the floor with a foot planted in every exact frame, its root at a standing pelvis' height; the
    same body standing still stays where it stood; live frames carry a root near the exact ones'."""
    from limbstream.sources.generator import GeneratorSource

    agg, sent = aggregator()
    n = 400  # 8 s at 50 Hz
    for subject, activity in (("w01", "walking"), ("t01", "still")):
        q = GeneratorSource(5, activities=[activity], layout="full").orientations(np.arange(n) / 50.0)
        for segment in FULL.segment_names:
            device(agg, subject, segment, Body.default(FULL))
        for k in range(n):
            for s, segment in enumerate(FULL.segment_names):
                point = wire.SegmentPoint(1, k, k, T0 + k * 20_000, tuple(q[k, s]), omega=(0.0, 0.0, 0.0))
                agg.on_point(wire.seg_key(subject, segment), wire.encode_point(point), 0.0)
            if k % 10 == 9:
                agg.advance(live=True, now=0.0)
    walk = [f for _, f in frames_of(sent, "w01")]
    still = [f for _, f in frames_of(sent, "t01")]
    assert len(walk) > 300 and len(still) > 300
    root = np.array([f.root for f in walk])
    assert np.linalg.norm(root[-1, [0, 2]] - root[0, [0, 2]]) > 1.0  # it walked somewhere
    assert np.all((0.8 < root[:, 1]) & (root[:, 1] < 1.05))  # a standing adult's pelvis height, m
    assert all(f.contacts for f in walk)  # a foot on the floor in every frame of a walk
    held = np.array([f.root for f in still])
    assert np.linalg.norm(held[:, [0, 2]] - held[0, [0, 2]], axis=1).max() < 0.01
    live = [f for _, f in frames_of(sent, "w01", wire.KIND_LIVE)]
    assert live and np.linalg.norm(live[-1].root - root[-1]) < 0.2
