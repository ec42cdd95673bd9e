"""The wire contract: codecs round-trip, reject bad payloads by reason, and the C encoder agrees."""
from __future__ import annotations

import ctypes
import json
from pathlib import Path
import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.profiles import scaled

from limbstream import kernel, quat, wire
from limbstream.body import FULL, PAPER10
from limbstream.sources import SEGMENTS

u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
i64 = st.integers(-(2**63), 2**63 - 1)


def unit_quaternions():
    return st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
        lambda v: sum(x * x for x in v) > 0.1).map(lambda v: tuple(np.float32(np.array(v) / np.linalg.norm(v))))


_lib = kernel._lib
_lib.lsw_encode_point.argtypes = [ctypes.c_char_p, ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32,
                                  ctypes.POINTER(kernel.Point), ctypes.c_int64]
_lib.lsw_encode_point.restype = ctypes.c_uint32


def c_encode(p: wire.SegmentPoint) -> bytes:
    point = kernel.Point()
    point.index, point.t = p.index, 0
    for d in range(4):
        point.y[d] = p.q[d]
    out = ctypes.create_string_buffer(wire.POINT_SIZE)
    assert _lib.lsw_encode_point(out, p.flags, p.stream, p.seq, ctypes.byref(point), p.t_us) == wire.POINT_SIZE
    return out.raw


@settings(max_examples=scaled(2000), deadline=None)
@given(u16, u32, u32, i64, unit_quaternions(), st.integers(0, 255))
def test_c_encoder_and_python_codec_agree_byte_for_byte(stream, seq, index, t_us, q, flags):
    p = wire.SegmentPoint(stream, seq, index, t_us, tuple(float(v) for v in q), flags)
    encoded = wire.encode_point(p)
    assert c_encode(p) == encoded
    assert wire.decode_point(encoded) == p



_lib.lsw_encode_point_rate.argtypes = [ctypes.c_char_p, ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32,
                                       ctypes.POINTER(kernel.Point), ctypes.POINTER(ctypes.c_float * 3), ctypes.c_int64]
_lib.lsw_encode_point_rate.restype = ctypes.c_uint32


@settings(max_examples=scaled(2000), deadline=None)
@given(u16, u32, u32, i64, unit_quaternions(), st.integers(0, 255),
       st.lists(st.floats(width=32, allow_nan=False, allow_infinity=False), min_size=3, max_size=3))
def test_c_encoder_and_python_codec_agree_on_points_with_a_rate(stream, seq, index, t_us, q, flags, omega):
    """Segment point v2 (docs/protocol.md): the C and Python encoders write the same 48 bytes."""
    p = wire.SegmentPoint(stream, seq, index, t_us, tuple(float(v) for v in q), flags, tuple(omega))
    point = kernel.Point()
    point.index = p.index
    for d in range(4):
        point.y[d] = p.q[d]
    out = ctypes.create_string_buffer(wire.point.POINT_SIZE_RATE)
    rate = (ctypes.c_float * 3)(*omega)
    assert _lib.lsw_encode_point_rate(out, p.flags, p.stream, p.seq, ctypes.byref(point), ctypes.byref(rate),
                                      p.t_us) == wire.point.POINT_SIZE_RATE == 48
    encoded = wire.encode_point(p)
    assert out.raw == encoded
    assert encoded[0] == wire.point.VERSION_RATE and encoded[36:] == struct.pack("<3f", *omega)
    assert wire.decode_point(encoded) == p


def test_points_with_and_without_a_rate():
    """A point without a rate is version 1 (36 bytes) and decodes with omega None; bad rates and
    sizes that do not match the version are refused with a reason."""
    v1 = wire.encode_point(wire.SegmentPoint(1, 2, 3, 4, (0.0, 1.0, 0.0, 0.0)))
    assert len(v1) == 36 and v1[0] == 1 and wire.decode_point(v1).omega is None
    v2 = wire.encode_point(wire.SegmentPoint(1, 2, 3, 4, (0.0, 1.0, 0.0, 0.0), omega=(0.5, -1.0, 2.0)))
    assert len(v2) == 48 and v2[:36] == bytes([2]) + v1[1:]
    assert wire.decode_point(v2).omega == (0.5, -1.0, 2.0)
    for bad, reason in ((v2[:36], "size"), (v1 + bytes(12), "size"), (bytes([3]) + v2[1:], "version"),
                        (b"", "size"), (v2[:36] + struct.pack("<3f", 0.0, math.nan, 0.0), "non_finite"),
                        (v2[:36] + struct.pack("<3f", math.inf, 0.0, 0.0), "non_finite")):
        with pytest.raises(wire.WireError) as err:
            wire.decode_point(bad)
        assert err.value.reason == reason, bad


def test_point_is_36_bytes_little_endian():
    p = wire.SegmentPoint(0x0102, 0x03040506, 7, 0x1122334455667788, (1.0, 0.0, 0.0, 0.0), wire.FLAG_FINAL)
    raw = wire.encode_point(p)
    assert len(raw) == 36 <= 40
    assert raw[:4] == bytes([wire.VERSION, 1, 0x02, 0x01])
    assert raw[4:8] == bytes([6, 5, 4, 3])
    assert raw[12:20] == bytes.fromhex("8877665544332211")
    assert raw[20:24] == struct.pack("<f", 1.0)


@pytest.mark.parametrize("mutate, reason", [
    (lambda b: b[:-1], "size"),
    (lambda b: b + b"\0", "size"),
    (lambda b: bytes([9]) + b[1:], "version"),
    (lambda b: b[:20] + struct.pack("<4f", math.nan, 0, 0, 0), "non_finite"),
    (lambda b: b[:20] + struct.pack("<4f", math.inf, 0, 0, 0), "non_finite"),
    (lambda b: b[:20] + struct.pack("<4f", 0.5, 0, 0, 0), "non_unit"),
    (lambda b: b[:20] + struct.pack("<4f", 0, 0, 0, 0), "non_unit"),
])
def test_bad_points_are_rejected_with_a_reason(mutate, reason):
    good = wire.encode_point(wire.SegmentPoint(1, 2, 3, 4, (0.0, 1.0, 0.0, 0.0)))
    with pytest.raises(wire.WireError) as err:
        wire.decode_point(mutate(good))
    assert err.value.reason == reason


def test_raw_batch_round_trip_and_errors():
    rng = np.random.default_rng(0)
    t = 1_700_000_000_000_000 + np.arange(25) * 20_000
    q = rng.normal(size=(25, 4)).astype(np.float32)
    batch = wire.RawBatch(7, 1000, t, q)
    back = wire.decode_raw(wire.encode_raw(batch))
    assert back.stream == 7 and back.first_index == 1000
    assert np.array_equal(back.t_us, t) and np.array_equal(back.q, q)
    raw = wire.encode_raw(batch)
    for bad, reason in ((raw[:-3], "size"), (raw[:10], "size"), (bytes([4]) + raw[1:], "version")):
        with pytest.raises(wire.WireError) as err:
            wire.decode_raw(bad)
        assert err.value.reason == reason


def test_truth_batches_encoded_together_are_the_batches_encoded_one_by_one():
    rng = np.random.default_rng(3)
    for with_ref, equal in ((True, False), (False, False), (True, True), (False, True)):
        count = np.full(300, 25) if equal else rng.integers(1, 40, 300)
        t = 1_800_000_000_000_000 + np.cumsum(rng.integers(0, 30_000, count.sum()))
        q = rng.normal(size=(count.sum(), 4)).astype(np.float32)
        ref = t - rng.integers(0, 5_000, count.sum()) if with_ref else None
        stream, first_index = rng.integers(0, 1 << 16, 300), rng.integers(0, 1 << 32, 300)
        payload, ends = wire.encode_raws(stream, first_index, count, t, q, ref)
        starts, first = np.concatenate([[0], ends[:-1]]), np.cumsum(count) - count
        for i in range(300):
            rows = slice(first[i], first[i] + count[i])
            one = wire.encode_raw(wire.RawBatch(int(stream[i]), int(first_index[i]), t[rows], q[rows],
                                                None if ref is None else ref[rows]))
            assert payload[starts[i]:ends[i]] == one, (with_ref, equal, i)
    payload, ends = wire.encode_raws(np.zeros(0), np.zeros(0), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 4)))
    assert payload == b"" and len(ends) == 0
    with pytest.raises(ValueError, match="1..4096"):
        wire.encode_raws([1], [0], [0], np.zeros(0), np.zeros((0, 4)))


def payloads_of_points(count: int, seed: int) -> list[bytes]:
    """Valid v1 and v2 points and every kind of bad one, mixed."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        omega = None if i % 3 else tuple(rng.normal(0, 3, 3))
        good = wire.encode_point(wire.SegmentPoint(i % 65536, i, 3 * i, 1_800_000_000_000_000 + i, tuple(q), i % 2, omega))
        bad = [good[:-1], good + b"\0", bytes([7]) + good[1:], b"", good[:20] + struct.pack("<4f", math.nan, 0, 0, 0),
               good[:20] + struct.pack("<4f", 1.5, 0, 0, 0), good[:36] + struct.pack("<3f", 0, math.inf, 0)]
        out.append(good if rng.random() < 0.7 else bad[int(rng.integers(len(bad)))])
    return out


def test_points_decoded_together_are_the_points_decoded_one_by_one():
    payloads = payloads_of_points(3000, 1)
    cols = wire.decode_points(payloads)
    for i, payload in enumerate(payloads):
        try:
            p = wire.decode_point(payload)
        except wire.WireError as exc:
            assert cols.reason[i] == exc.reason, (i, payload)
            continue
        assert cols.reason[i] is None
        got = (cols.stream[i], cols.seq[i], cols.index[i], cols.t_us[i], cols.flags[i], tuple(cols.q[i].tolist()))
        assert got == (p.stream, p.seq, p.index, p.t_us, p.flags, p.q), i
        assert tuple(cols.omega[i].tolist()) == (p.omega or (0.0, 0.0, 0.0)) and cols.nbytes[i] == len(payload)
    assert len(wire.decode_points([]).reason) == 0


def test_truth_batches_decoded_together_are_the_batches_decoded_one_by_one():
    rng = np.random.default_rng(2)
    payloads = []
    for i in range(600):
        n = int(rng.integers(1, 40))
        t = 1_800_000_000_000_000 + np.cumsum(rng.integers(0, 30_000, n))
        good = bytearray(wire.encode_raw(wire.RawBatch(i % 9, 10 * i, t, rng.normal(size=(n, 4)).astype(np.float32),
                                                       t + 3_000 if i % 2 else None)))
        kind = rng.integers(8)
        if kind == 1:
            good = good[:-3]
        elif kind == 2:
            good[0] = 9
        elif kind == 3:
            good[-4:] = struct.pack("<f", math.nan)
        elif kind == 4 and n > 1:  # the first two samples' times swapped
            header, size = (28, 24) if i % 2 else (20, 20)
            good[header:header + 4], good[header + size:header + size + 4] = (good[header + size:header + size + 4],
                                                                              good[header:header + 4])
        payloads.append(bytes(good))
    cols = wire.decode_raws(payloads + [b""])
    assert cols.reason[-1] == "size"
    for i, payload in enumerate(payloads):
        try:
            b = wire.decode_raw(payload)
        except wire.WireError as exc:
            assert cols.reason[i] == exc.reason, (i, cols.reason[i], exc.reason)
            continue
        got = cols.batch(i)
        assert cols.reason[i] is None and (got.stream, got.first_index) == (b.stream, b.first_index)
        assert np.array_equal(got.t_us, b.t_us) and np.array_equal(got.q, b.q)
        assert (got.ref_us is None and b.ref_us is None) or np.array_equal(got.ref_us, b.ref_us)


def test_pose_frame_round_trip():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(len(SEGMENTS), 4)).astype(np.float32)
    joints = rng.normal(size=(len(wire.JOINTS), 3)).astype(np.float32)
    frame = wire.PoseFrame(5, 123456789, wire.KIND_LIVE, wire.FRAME_GAP, q, joints)
    back = wire.decode_pose(wire.encode_pose(frame))
    assert (back.seq, back.t_us, back.kind, back.flags) == (5, 123456789, wire.KIND_LIVE, wire.FRAME_GAP)
    assert np.array_equal(back.q, q) and np.array_equal(back.joints, joints)
    as_json = back.to_json("s01")
    assert as_json["kind"] == "live" and as_json["gap"] and set(as_json["segments"]) == set(SEGMENTS)
    with pytest.raises(wire.WireError):
        wire.decode_pose(wire.encode_pose(frame)[:-1])


def test_pose_frames_encode_as_the_documented_layout():
    """A batch encodes frame by frame to the bytes docs/protocol.md gives: header <BBBBIqBBBB3f
    (version 2, kind, flags, n_segments, seq, t_us, layout, n_joints, contacts, 0, root), then
    S x 4 and J x 3 float32: 372 bytes for paper10, 512 for full."""
    rng = np.random.default_rng(2)
    n = 7
    header = struct.Struct("<BBBBIqBBBB3f")
    assert header.size == wire.pose.HEADER_SIZE
    for layout, code, size in ((PAPER10, 0, 372), (FULL, 1, 512)):
        frames = wire.PoseFrames(rng.integers(0, 2**32, n), rng.integers(0, 2**53, n), wire.KIND_EXACT,
                                 rng.integers(0, 4, n), rng.normal(size=(n, len(layout.segments), 4)),
                                 rng.normal(size=(n, len(layout.joints), 3)), layout,
                                 rng.normal(size=(n, 3)), rng.integers(0, 16, n))
        payloads = frames.encode()
        assert len(payloads) == n and all(len(p) == size for p in payloads)
        for i, payload in enumerate(payloads):
            expected = (header.pack(2, wire.KIND_EXACT, int(frames.flags[i]), len(layout.segments), int(frames.seq[i]),
                                    int(frames.t_us[i]), code, len(layout.joints), int(frames.contacts[i]), 0,
                                    *frames.root[i].astype("<f4"))
                        + frames.q[i].astype("<f4").tobytes() + frames.joints[i].astype("<f4").tobytes())
            assert payload == expected == wire.encode_pose(frames[i])
            back = wire.decode_pose(payload)
            assert (back.seq, back.t_us, back.flags, back.contacts) == (
                frames.seq[i], frames.t_us[i], frames.flags[i], frames.contacts[i])
            assert back.layout == layout and np.array_equal(back.root, frames.root[i].astype(np.float32))
        assert wire.PoseFrames.empty(wire.KIND_LIVE, layout).encode() == []


def test_version_1_pose_frames_are_still_read_as_paper10():
    """Recordings hold 356-byte version-1 frames: read as paper10 frames at the origin, no contacts."""
    rng = np.random.default_rng(3)
    q, joints = rng.normal(size=(10, 4)).astype("<f4"), rng.normal(size=(15, 3)).astype("<f4")
    payload = struct.pack("<BBBBIq", 1, wire.KIND_LIVE, wire.FRAME_MISSING, 10, 9, 1234) + q.tobytes() + joints.tobytes()
    assert len(payload) == 356
    frame = wire.decode_pose(payload)
    assert frame.layout is PAPER10 and (frame.seq, frame.t_us, frame.flags, frame.contacts) == (9, 1234, wire.FRAME_MISSING, 0)
    assert np.array_equal(frame.q, q) and np.array_equal(frame.joints, joints) and not frame.root.any()


def test_full_layout_frames_name_their_segments_joints_root_and_contacts_in_json():
    rng = np.random.default_rng(4)
    frame = wire.PoseFrame(1, 2_000_000, wire.KIND_EXACT, 0, rng.normal(size=(15, 4)).astype(np.float32),
                           rng.normal(size=(20, 3)).astype(np.float32), FULL, np.array([1.0, 0.9, -2.0], np.float32), 0b0101)
    as_json = wire.decode_pose(wire.encode_pose(frame)).to_json("s01")
    assert as_json["layout"] == "full" and list(as_json["segments"]) == list(FULL.segment_names)
    assert list(as_json["joints"]) == list(FULL.joints) and as_json["root"] == [1.0, 0.9, -2.0]
    assert as_json["contacts"] == ["l_heel", "r_heel"]


def test_pose_frames_that_break_the_contract_are_refused_by_reason():
    frame = wire.PoseFrame(1, 2, wire.KIND_EXACT, 0, np.zeros((15, 4), np.float32), np.zeros((20, 3), np.float32), FULL)
    payload = bytearray(wire.encode_pose(frame))
    cases = {"size": [b"", bytes(payload[:20]), bytes(payload[:-1])], "version": [bytes([3]) + bytes(payload[1:])]}
    other = bytearray(payload)
    other[16] = wire.OTHER_LAYOUT  # a layout file's frame, read without its layout
    wrong = bytearray(payload)
    wrong[16] = 0  # says paper10 with full's counts
    unknown = bytearray(payload)
    unknown[16] = 7
    cases["layout"] = [bytes(other), bytes(wrong), bytes(unknown)]
    for reason, payloads in cases.items():
        for bad in payloads:
            with pytest.raises(wire.WireError) as err:
                wire.decode_pose(bad)
            assert err.value.reason == reason, (reason, err.value)
    assert wire.decode_pose(bytes(other), FULL).layout is FULL  # the subject's layout, passed in


SAMPLE_VALUES = {float: 0.5, int: 3, bool: True, str: "s01/hip", dict: {"size": 1}}


def test_stats_round_trip_in_both_forms_and_null_for_non_finite():
    device = {f.name: SAMPLE_VALUES[f.type] for f in wire.DEVICE_FIELDS} | {"aad_deg": math.nan, "gaps": 2**40}
    loop = {f.name: SAMPLE_VALUES[f.type] for f in wire.AGGREGATOR_FIELDS}
    other = device | {"online": False, "tracker": None, "sync_bad": None, "max_len": None, "icr": math.inf}
    args = ("s01", 1.5, [device, other], {"frames": 3, "aggregator": loop})
    compact, text = wire.encode_stats(*args, seq=7), wire.encode_stats_json(*args, seq=7)
    assert compact[0] == wire.STATS_VERSION and text[:1] == b"{" and len(compact) < len(text)
    data = wire.decode_stats(compact)
    assert data == wire.decode_stats(text) == json.loads(wire.stats_json(compact)), "one message, two forms"
    assert wire.stats_json(text) == text
    assert data["subject"] == "s01" and data["frames"] == 3 and data["seq"] == 7
    assert data["devices"][0] == device | {"aad_deg": None}
    assert data["devices"][1] == other | {"aad_deg": None, "icr": None}
    assert data["aggregator"] == loop
    assert list(data) == ["subject", "t", "seq", "frames", "devices", "aggregator"]
    assert list(data["devices"][0]) == list(wire.STATS_FIELDS), "device fields in table order"
    assert [type(v) for v in data["devices"][0].values()] == [type(v) for v in (device | {"aad_deg": None}).values()]
    empty = wire.decode_stats(wire.encode_stats("s02", 2.0, []))
    assert empty == {"subject": "s02", "t": 2.0, "seq": 0, "devices": []}


def test_stats_fields_are_declared_and_typed():
    """The encoders refuse a field the table lacks; the decoder a value of the wrong type, and a
    compact message whose parts do not fit."""
    for encode in (wire.encode_stats, wire.encode_stats_json):
        with pytest.raises(ValueError, match="not declared"):
            encode("s01", 1.0, [{"device": "s01/hip", "speed": 3}])
        with pytest.raises(ValueError, match="not declared"):
            encode("s01", 1.0, [], {"aggregator": {"colour": 1}})
    sparse = json.loads(wire.encode_stats_json("s01", 1.0, [{"device": "s01/hip"}]))
    assert set(sparse["devices"][0]) == set(wire.STATS_FIELDS), "missing device fields are sent as null"
    assert wire.decode_stats(wire.encode_stats("s01", 1.0, [{"device": "s01/hip"}])) == sparse
    for field in wire.DEVICE_FIELDS:
        wrong = "text" if field.type is not str else 5
        bad = dict(sparse, devices=[sparse["devices"][0] | {field.name: wrong}])
        with pytest.raises(wire.WireError, match=field.name):
            wire.decode_stats(json.dumps(bad).encode())
    for bad_seq in ("1", 1.5, True):
        with pytest.raises(wire.WireError):
            wire.decode_stats(json.dumps(sparse | {"seq": bad_seq}).encode())
    good = wire.encode_stats("s01", 1.0, [{"device": "s01/hip", "points": 3}])
    column = 12 + int.from_bytes(good[8:12], "little") + 8 * wire.STATS_NUMBERS.index("points")
    half = good[:column] + struct.pack("<d", 2.5) + good[column + 8:]
    for bad in (good[:-1], good + b"\0" * 8, good[:11], good[:12] + b"[" + good[13:], half):
        with pytest.raises(wire.WireError):
            wire.decode_stats(bad)


def test_field_table_is_consistent():
    names = [(f.scope, f.name) for f in wire.FIELDS]
    assert len(names) == len(set(names)), "a field is declared twice"
    metrics = [f.metric for f in wire.FIELDS if f.metric]
    assert len(metrics) == len(set(metrics)) and all(m.startswith("limbstream_") for m in metrics)
    assert all(f.type in (float, int) for f in wire.FIELDS if f.chart), "charts need numbers"
    assert set(wire.HISTORY_FIELDS) <= set(wire.STATS_FIELDS)
    assert set(wire.TUNABLES) <= set(wire.STATS_FIELDS), "every tunable is reported per device"
    with pytest.raises(wire.WireError):
        wire.decode_stats(b"{not json")
    with pytest.raises(wire.WireError):
        wire.decode_stats(json.dumps({"subject": "s01", "devices": [{"device": "x"}]}).encode())


def test_keys_and_bad_chunks():
    assert wire.seg_key("s01", "l_shank") == "limbstream/s01/l_shank/seg"
    assert wire.parse_device_key("limbstream/s01/l_shank/raw") == ("s01", "l_shank", "raw")
    for bad in ("limbstream/s01/seg", "other/s01/x/seg", "limbstream/s 1/x/seg"):
        with pytest.raises(wire.WireError):
            wire.parse_device_key(bad)
    for bad in ("", "a/b", "*", "x y"):
        with pytest.raises(ValueError):
            wire.device_id(bad, "hip")


def test_config_validation():
    assert (wire.decode_config(b'{"threshold": 0.01, "max_len": 25, "live_bound_deg": 5}')
            == wire.DeviceConfig(0.01, 25, 5.0))
    current = wire.DeviceConfig(0.01, 25)
    assert wire.decode_config(b'{"threshold": 0.5}', current) == wire.DeviceConfig(0.5, 25)
    assert wire.decode_config(b'{"max_len": 7}', current) == wire.DeviceConfig(0.01, 7)
    assert wire.decode_config(b'{"live_bound_deg": 2.5}', current) == wire.DeviceConfig(0.01, 25, 2.5)
    for bad, words in ((b'{"threshold": -1, "max_len": 25}', "threshold"), (b'{"threshold": 0.1, "max_len": 0}', "max_len"),
                       (b'{"threshold": "x", "max_len": 5}', "threshold"), (b'{"max_len": 5}', "needs"),
                       (b"[]", "object"), (b"\xff", "JSON"), (b'{"max_len": 5.5}', "max_len"),
                       (b'{"threshold": true}', "threshold"),
                       (b'{"live_bound_deg": -1}', "live_bound_deg"), (b'{"live_bound_deg": 181}', "live_bound_deg"),
                       (b'{"live_bound_deg": "5"}', "live_bound_deg"), (b'{"speed": 1}', "unknown"), (b"{}", "some of")):
        with pytest.raises(wire.WireError, match=words):
            wire.decode_config(bad, current if b"speed" in bad or b"live" in bad or bad == b"{}" else None)


def test_subject_patterns_become_key_chunks():
    assert wire.subject_pattern("*") == "*"
    assert wire.subject_pattern(" s01 ") == "s01"
    assert wire.subject_pattern("s0*") == "s0$*"
    for bad in ("s/1", "", "s 1"):
        with pytest.raises(ValueError):
            wire.subject_pattern(bad)


def test_protocol_doc_holds_the_generated_tables():
    """docs/protocol.md lists every stats field and tunable exactly as the contract declares them."""
    from limbstream.wire.__main__ import tables

    doc = (Path(__file__).resolve().parent.parent / "docs" / "protocol.md").read_text()
    for heading, table in tables().items():
        assert table in doc, f"docs/protocol.md: the '{heading}' table is out of date: run python -m limbstream.wire"


def test_protocol_doc_quotes_the_stats_sizes_bench_stats_size_prints():
    """The compact stats form's size against the JSON form's in docs/protocol.md is what
    ``python bench/stats_size.py`` measures: the same ratio, the same bytes within 1 % (the
    aggregator's loop figures in the message vary from run to run by a few digits)."""
    import re
    import sys
    root = Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root / "bench"))
    try:
        import stats_size
    finally:
        sys.path.remove(str(root / "bench"))
    doc = (root / "docs" / "protocol.md").read_text()
    assert stats_size.HEADER in doc, "docs/protocol.md: the stats size table is gone"
    row = re.search(r"^\| 1 \| (\d+) \| ([\d,]+) \| ([\d,]+) \| ([\d.]+) \|$", doc, re.M)
    assert row, "docs/protocol.md: no stats size row for 1 subject"
    devices, compact, text = stats_size.stats_sizes(1)
    assert int(row[1]) == devices and row[4] == f"{compact / text:.2f}", (row[0], devices, compact, text)
    for quoted, measured in ((row[2], compact), (row[3], text)):
        assert abs(int(quoted.replace(",", "")) - measured) <= 0.01 * measured, (row[0], compact, text)


def test_gateway_key_is_verbatim_and_its_codec_round_trips():
    import zenoh
    key = wire.gateway_key("lab1")
    assert key == "limbstream/@gateway/lab1" and wire.parse_gateway_key(key) == "lab1"
    assert zenoh.KeyExpr(wire.gateway_selector()).intersects(zenoh.KeyExpr(key))
    for selector in (wire.subject_selector("pose"), wire.subject_selector("stats"), "limbstream/*/*", "limbstream/*/*/*"):
        assert not zenoh.KeyExpr(selector).intersects(zenoh.KeyExpr(key)), selector
    with pytest.raises(ValueError):
        wire.gateway_key("a/b")
    with pytest.raises(wire.WireError):
        wire.parse_gateway_key("limbstream/s01/pose")
    a = wire.Assignment("AA:BB:CC:DD:EE:01", 2, None, "hip")
    assert wire.decode_assignment(wire.encode_assignment(a)) == a
    assert wire.decode_assignment(b'{"tracker": "t", "sensor": 0, "segment": null}').segment is None
    listing = {"gateway": "g", "subject": "s01", "sensors": [
        {"tracker": "t", "sensor": 0, "online": True, "position": None, "device": None, "why": "no segment"}]}
    assert wire.decode_sensors(wire.encode_sensors("g", "s01", listing["sensors"])) == listing
    for bad in (b"{}", b'{"gateway": "g", "subject": "s", "sensors": [{"tracker": 1}]}', b"nope"):
        with pytest.raises(wire.WireError):
            wire.decode_sensors(bad)


def angle_frames(n: int, basis: str = "segments") -> wire.AngleFrames:
    rng = np.random.default_rng(3)
    a = len(wire.JOINT_ANGLES)
    flags = np.zeros((n, a), np.uint8)
    flags[:, 1] = wire.ANGLE_MISSING
    flags[:, 5] = wire.ANGLE_GIMBAL
    valid = wire.ANGLE_BASES[wire.BASIS[basis]].valid
    flags |= np.uint8(0 if valid else wire.ANGLE_UNCALIBRATED)
    angles = np.where(flags & (wire.ANGLE_MISSING | wire.ANGLE_UNCALIBRATED), np.nan, rng.uniform(-90, 90, (n, a)))
    return wire.AngleFrames(rng.integers(0, 2**32, n), rng.integers(0, 2**53, n), np.full(n, wire.KIND_LIVE),
                            np.full(n, wire.BASIS[basis]), np.full(n, 12.5 if basis == "functional" else np.nan),
                            angles, flags)


def test_joint_angles_encode_as_the_documented_layout_and_come_back():
    """Header <BBBBIqfB3x (version 2, kind, basis, n_angles, seq, t_us, facing_deg, layout code),
    then the angles (float32, JOINT_ANGLES order) and a flag byte each; decoded one by one or
    together, the same. Version 1 (no layout byte) is still read."""
    frames = angle_frames(5, "functional")
    payloads = frames.encode()
    header = struct.Struct("<BBBBIqfB3x")
    v1 = struct.Struct("<BBBBIqf")
    for i, payload in enumerate(payloads):
        expected = (header.pack(wire.ANGLES_VERSION, wire.KIND_LIVE, wire.BASIS["functional"], len(wire.JOINT_ANGLES),
                                int(frames.seq[i]), int(frames.t_us[i]), 12.5, 0)
                    + frames.angles[i].astype("<f4").tobytes() + frames.flags[i].tobytes())
        assert payload == expected == wire.encode_angles(frames[i]) and len(payload) == wire.ANGLES_SIZE == 119
        old = v1.pack(1, wire.KIND_LIVE, wire.BASIS["functional"], len(wire.JOINT_ANGLES), int(frames.seq[i]),
                      int(frames.t_us[i]), 12.5) + frames.angles[i].astype("<f4").tobytes() + frames.flags[i].tobytes()
        assert len(old) == 115
        for back in (wire.decode_angles(payload), wire.decode_angles(old)):
            assert (back.seq, back.t_us, back.kind, back.facing_deg) == (frames.seq[i], frames.t_us[i], 1, 12.5)
            assert np.array_equal(back.flags, frames.flags[i]) and back.layout is None
            assert np.allclose(back.angles, frames.angles[i], equal_nan=True, atol=1e-4)
            assert back.names == wire.JOINT_ANGLES
    together, refused = wire.decode_angles_many(payloads)
    assert refused == [""] * 5 and together.encode() == payloads
    js = wire.decode_angles(payloads[0]).to_json("s01")
    assert (js["calibration"], js["valid"], js["why"], js["facing_deg"], js["kind"]) == ("functional", True, None, 12.5,
                                                                                           "live")
    assert list(js["angles"]) == list(wire.JOINT_ANGLES) and js["angles"][wire.JOINT_ANGLES[1]] is None
    assert js["flags"] == {wire.JOINT_ANGLES[1]: ["missing"], wire.JOINT_ANGLES[5]: ["gimbal"]}
    js = wire.decode_angles(angle_frames(1, "uncalibrated").encode()[0]).to_json("s01")
    assert not js["valid"] and "calibrat" in js["why"] and set(js["angles"].values()) == {None}
    assert wire.angles_key("s01") == "limbstream/s01/angles" == wire.subject_key("s01", wire.ANGLES)
    assert wire.parse_subject_key(wire.angles_key("s01")) == ("s01", "angles")


def test_bad_joint_angle_messages_are_refused_with_a_reason():
    good = bytearray(angle_frames(1).encode()[0])
    uncal = bytearray(angle_frames(1, "no_facing").encode()[0])
    at = {name: wire.ANGLES_DTYPE.fields[name][1] for name in wire.ANGLES_DTYPE.names}

    def changed(base: bytearray, offset: int, data: bytes) -> bytes:
        b = bytearray(base)
        b[offset:offset + len(data)] = data
        return bytes(b)
    flag0, angle0 = at["flags"], at["angles"]
    cases = [(bytes(good[:-1]), "size"), (bytes(good) + b"\0", "size"), (changed(good, 0, b"\3"), "version"),
             (changed(good, at["n_angles"], b"\x14"), "size"), (changed(good, at["kind"], b"\2"), "value"),
             (changed(good, at["layout"], b"\1"), "layout"),                            # full's code, paper10's count
             (changed(good, at["layout"], b"\7"), "layout"), (changed(good, at["layout"], b"\xff"), "layout"),
             (changed(good, at["basis"], bytes([len(wire.ANGLE_BASES)])), "value"),
             (changed(good, flag0, b"\x08"), "value"),                                   # an unknown flag bit
             (changed(good, angle0, struct.pack("<f", math.nan)), "value"),              # a valid angle without a number
             (changed(good, angle0 + 4, struct.pack("<f", 3.0)), "value"),               # a MISSING angle with one
             (changed(good, flag0, bytes([wire.ANGLE_UNCALIBRATED])), "value"),          # UNCALIBRATED on a valid basis
             (changed(uncal, flag0, b"\0"), "value"),                                    # ... not on an invalid one
             (changed(good, at["facing_deg"], struct.pack("<f", math.inf)), "value")]
    for payload, reason in cases:
        with pytest.raises(wire.WireError) as err:
            wire.decode_angles(payload)
        assert err.value.reason == reason, (payload, reason)
    _, reasons = wire.decode_angles_many([p for p, _ in cases] + [bytes(good)])
    assert reasons == [r for _, r in cases] + [""]


def test_a_device_status_says_what_its_orientations_are():
    status = wire.DeviceStatus("s01/hip", wire.DeviceConfig(), 3, 10, 2, orientations="rest")
    assert wire.decode_status(wire.encode_status(status)).orientations == "rest"
    silent = wire.decode_status(wire.encode_status(wire.DeviceStatus("s01/hip", wire.DeviceConfig(), 3, 10, 2)))
    assert silent.orientations is None and "orientations" not in silent.as_dict()
    data = status.as_dict() | {"orientations": "quaternions"}
    with pytest.raises(wire.WireError, match="orientations must be one of segments, rest, sensors"):
        wire.decode_status(json.dumps(data).encode())


def test_truth_tap_v3_carries_the_devices_own_orientation_and_v2_still_decodes():
    """Version 3 adds each sample's own orientation (what the device compressed); a version 2 or
    1 batch (a recording's) decodes as before, without one, alone and among others."""
    rng = np.random.default_rng(3)
    n = 5
    t = 1_790_000_000_000_000 + 20_000 * np.arange(n)
    q, own = (quat.normalize(rng.normal(size=(n, 4))).astype(np.float32) for _ in range(2))
    v3 = wire.encode_raw(wire.RawBatch(7, 100, t, q, t + 3, own))
    v2 = wire.encode_raw(wire.RawBatch(7, 100, t, q, t + 3))
    v1 = wire.encode_raw(wire.RawBatch(7, 100, t, q))
    assert (v3[0], v2[0], v1[0]) == (3, 2, 1) and len(v3) == 28 + 40 * n
    b = wire.decode_raw(v3)
    assert (b.own == own).all() and (b.q == q).all() and (b.ref_us == t + 3).all()
    assert wire.decode_raw(v2).own is None and wire.decode_raw(v1).own is None
    cols = wire.decode_raws([v2, v3, v1])
    assert cols.reason == [None] * 3 and cols.has_own.tolist() == [False, True, False]
    assert (cols.batch(1).own == own).all() and cols.batch(0).own is None and np.isnan(cols.own[:n]).all()
    payload, ends = wire.encode_raws(np.array([7, 8]), np.array([100, 0]), np.array([n, n]), np.concatenate([t, t]),
                                     np.concatenate([q, q]), np.concatenate([t, t]), np.concatenate([own, own]))
    assert payload[: int(ends[0])] == wire.encode_raw(wire.RawBatch(7, 100, t, q, t, own))
    bad = bytearray(v3)
    bad[-4:] = np.float32(np.nan).tobytes()
    with pytest.raises(wire.WireError) as err:
        wire.decode_raw(bytes(bad))
    assert err.value.reason == "non_finite" and wire.decode_raws([bytes(bad)]).reason == ["non_finite"]
