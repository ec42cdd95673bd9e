"""Property fuzz of every decoder and of the aggregator's per-device checks.

The contract (docs/protocol.md): a decoder returns a valid object or raises ``WireError`` with
a reason; nothing else escapes, whatever the bytes. Bulk cases come from seeded NumPy loops
(random bytes, valid messages with bytes flipped, fields set to extremes); Hypothesis draws
the structured ones, many payloads per example. The seeded bulk cases alone are over 100,000
(:data:`BULK`; each test checks it ran its share); ``make test-fast`` runs a tenth of every count
(support.profiles).
"""
from __future__ import annotations

import collections
import json
import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from limbstream import quat, wire
from limbstream.sources import SEGMENTS
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings, snapshot
from support.profiles import scaled

SEED = 20240607
BULK = {"point": 45_000, "raw": 15_000, "truth": 5_000, "pose": 15_000, "angles": 10_000, "key": 20_000, "aggregator_input": 8_000}
"""Seeded bulk cases of each test under the thorough profile (messages or keys decoded)."""
EXAMPLES = 100
"""Hypothesis examples of each property test under the thorough profile."""


def decodes_or_wire_error(decoder, payload, *args):
    """Run a decoder; return the object or the WireError reason. Any other exception fails."""
    try:
        return decoder(payload, *args)
    except wire.WireError as exc:
        assert exc.reason and isinstance(exc.reason, str)
        return exc.reason
    except Exception as exc:  # noqa: BLE001 - the point of the test
        pytest.fail(f"{decoder.__name__} raised {type(exc).__name__}: {exc} on {bytes(payload)[:80]!r}")


def check_point(result) -> None:
    """A decoded point is in range: finite unit quaternion, fields within their widths."""
    if isinstance(result, str):
        assert result in {"size", "version", "non_finite", "non_unit"} and result in wire.POINT_DROPS, result
        return
    norm = math.sqrt(sum(v * v for v in result.q))
    assert abs(norm - 1) <= wire.UNIT_TOLERANCE and all(map(math.isfinite, result.q)), result
    assert 0 <= result.stream <= 0xFFFF and 0 <= result.seq <= 0xFFFFFFFF and 0 <= result.index <= 0xFFFFFFFF


# ----------------------------------------------------------------------------- bulk, seeded


def valid_points(rng: np.random.Generator, n: int) -> list[bytes]:
    q = quat.normalize(rng.normal(size=(n, 4)))
    return [wire.encode_point(wire.SegmentPoint(int(rng.integers(0, 1 << 16)), int(rng.integers(0, 1 << 32)),
                                                int(rng.integers(0, 1 << 32)), int(rng.integers(-(1 << 62), 1 << 62)),
                                                tuple(float(v) for v in q[k]), int(rng.integers(0, 256))))
            for k in range(n)]


def mutate(rng: np.random.Generator, payload: bytes) -> bytes:
    """One random corruption: flip bytes, truncate, extend, or overwrite a float with NaN/Inf/huge."""
    b = bytearray(payload)
    op = rng.integers(0, 5)
    if op == 0 and b:
        for i in rng.integers(0, len(b), size=rng.integers(1, 4)):
            b[i] = int(rng.integers(0, 256))
    elif op == 1:
        b = b[: rng.integers(0, len(b) + 1)]
    elif op == 2:
        b += rng.bytes(int(rng.integers(1, 40)))
    elif op == 3 and len(b) >= 4:
        at = int(rng.integers(0, len(b) - 3))
        b[at: at + 4] = struct.pack("<f", rng.choice([np.nan, np.inf, -np.inf, 1e38, -0.0, 1e-45]))
    elif b:
        b[0] = int(rng.integers(0, 256))  # version byte
    return bytes(b)


def test_segment_point_decoder_bulk():
    rng = np.random.default_rng(SEED)
    n = scaled(BULK["point"])
    good = valid_points(rng, n // 9)
    reasons: dict = {}
    for payload in good:
        p = decodes_or_wire_error(wire.decode_point, payload)
        assert isinstance(p, wire.SegmentPoint) and wire.encode_point(p) == payload
    for k in range(n - len(good)):
        payload = mutate(rng, good[k % len(good)]) if k % 4 else rng.bytes(int(rng.integers(0, 80)))
        result = decodes_or_wire_error(wire.decode_point, payload)
        check_point(result)
        key = result if isinstance(result, str) else "ok"
        reasons[key] = reasons.get(key, 0) + 1
    assert sum(reasons.values()) + len(good) == n
    assert {"size", "version", "non_finite", "non_unit", "ok"} <= set(reasons), reasons


def test_raw_batch_decoder_bulk():
    rng = np.random.default_rng(SEED + 1)
    reasons: dict = {}
    for k in range(scaled(BULK["raw"])):
        n = int(rng.integers(1, 60))
        t = np.cumsum(rng.integers(1, 40_000, n)) + int(rng.integers(0, 1 << 50))
        payload = wire.encode_raw(wire.RawBatch(int(rng.integers(0, 1 << 16)), int(rng.integers(0, 1 << 32)),
                                                t.astype(np.int64), quat.normalize(rng.normal(size=(n, 4)))
                                                .astype(np.float32)))
        if k % 3:
            payload = mutate(rng, payload)
        result = decodes_or_wire_error(wire.decode_raw, payload)
        if isinstance(result, str):
            assert result in {"size", "version", "non_finite", "time_backwards"}, result
            assert wire.device_reason("raw", result) in wire.RAW_DROPS, result
        else:
            assert len(result.t_us) == len(result.q) > 0 and np.all(np.isfinite(result.q))
            assert np.all(np.diff(result.t_us) >= 0), "dt_us is unsigned: time cannot go back inside a batch"
        key = result if isinstance(result, str) else "ok"
        reasons[key] = reasons.get(key, 0) + 1
    assert sum(reasons.values()) == scaled(BULK["raw"])
    assert {"size", "version", "non_finite", "time_backwards", "ok"} <= set(reasons), reasons


def test_truth_message_decoder_bulk():
    """Subject truth-tap messages (a few devices' batches), valid and mutated: each splits into
    named batches that are exactly bytes of the message, or is refused with a reason of its own."""
    rng = np.random.default_rng(SEED + 7)
    batch = wire.encode_raw(wire.RawBatch(1, 0, np.arange(5, dtype=np.int64) * 20_000, np.tile(
        np.float32([1, 0, 0, 0]), (5, 1))))
    reasons: dict = {}
    for k in range(scaled(BULK["truth"])):
        segments = list(rng.choice(SEGMENTS, int(rng.integers(1, 5)), replace=False))
        payload = wire.encode_truth(segments, [batch[:int(rng.integers(0, len(batch) + 1))] for _ in segments])
        if k % 4:
            payload = mutate(rng, payload)
        result = decodes_or_wire_error(wire.decode_truth, payload)
        if isinstance(result, str):
            assert wire.truth_reason(result) in wire.UNCHARGED, result
        else:
            assert result and len({s for s, _ in result}) == len(result)
            assert sum(len(b) for _, b in result) <= len(payload) and all(b in payload for _, b in result)
        key = result if isinstance(result, str) else "ok"
        reasons[key] = reasons.get(key, 0) + 1
    assert sum(reasons.values()) == scaled(BULK["truth"])
    assert {"size", "version", "segment", "ok"} <= set(reasons), reasons


def test_pose_frame_decoder_bulk():
    rng = np.random.default_rng(SEED + 2)
    frame = wire.PoseFrame(7, 1_700_000_000_000_000, wire.KIND_EXACT, 0,
                           quat.normalize(rng.normal(size=(10, 4))).astype(np.float32))
    good = wire.encode_pose(frame)
    reasons: collections.Counter = collections.Counter()
    for k in range(scaled(BULK["pose"])):
        payload = mutate(rng, good) if k % 5 else rng.bytes(int(rng.integers(0, 400)))
        result = decodes_or_wire_error(wire.decode_pose, payload)
        if not isinstance(result, str):
            layout = result.layout
            assert result.q.shape == (len(layout.segments), 4) and result.joints.shape == (len(layout.joints), 3)
        else:
            assert result in {"size", "version", "layout"}
        reasons[result if isinstance(result, str) else "ok"] += 1
    assert sum(reasons.values()) == scaled(BULK["pose"]) and {"size", "version", "ok"} <= set(reasons), reasons


def valid_angles(rng: np.random.Generator, n: int) -> list[bytes]:
    """Joint-angle messages as an aggregator makes them: each basis, some angles missing or near lock."""
    a = len(wire.JOINT_ANGLES)
    basis = rng.integers(0, len(wire.ANGLE_BASES), n)
    valid = np.array([wire.ANGLE_BASES[b].valid for b in basis])
    flags = np.where(rng.random((n, a)) < 0.1, wire.ANGLE_MISSING, 0) | np.where(rng.random((n, a)) < 0.1,
                                                                                  wire.ANGLE_GIMBAL, 0)
    flags |= np.where(valid, 0, wire.ANGLE_UNCALIBRATED)[:, None]
    angles = np.where(flags & (wire.ANGLE_MISSING | wire.ANGLE_UNCALIBRATED), np.nan, rng.uniform(-180, 180, (n, a)))
    facing = np.where(basis == wire.BASIS["functional"], rng.uniform(-180, 180, n), np.nan)
    return wire.AngleFrames(rng.integers(0, 1 << 32, n), rng.integers(0, 1 << 62, n), rng.integers(0, 2, n), basis,
                            facing, angles, flags.astype(np.uint8)).encode()


def test_joint_angle_decoder_bulk():
    """Good messages come back as sent; mutated ones and random bytes are refused with a reason,
    or decode to angles that keep the contract: a number exactly where the flags allow one, none
    at all where the basis gives no anatomical frames."""
    rng = np.random.default_rng(SEED + 5)
    n = scaled(BULK["angles"])
    good = valid_angles(rng, n // 5)
    frames, refused = wire.decode_angles_many(good)
    assert not any(refused) and frames.encode() == good
    reasons: collections.Counter = collections.Counter()
    payloads = [mutate(rng, good[k % len(good)]) if k % 4 else rng.bytes(int(rng.integers(0, 160)))
                for k in range(n - len(good))]
    batch, batch_reasons = wire.decode_angles_many(payloads)
    for payload, why in zip(payloads, batch_reasons):
        result = decodes_or_wire_error(wire.decode_angles, payload)
        assert (result if isinstance(result, str) else "") == why  # one at a time as in a batch
        if isinstance(result, str):
            assert result in {"size", "version", "layout", "value"}, result
        else:
            number = (result.flags & (wire.ANGLE_MISSING | wire.ANGLE_UNCALIBRATED)) == 0
            assert np.isfinite(result.angles[number]).all() and np.isnan(result.angles[~number]).all()
            assert number.any() <= result.calibration.valid and result.kind in (0, 1)
        reasons[result if isinstance(result, str) else "ok"] += 1
    assert len(batch) == reasons["ok"] and sum(reasons.values()) + len(good) == n
    assert {"size", "version", "value", "ok"} <= set(reasons), reasons


def test_keys_bulk():
    rng = np.random.default_rng(SEED + 3)
    alphabet = list("ab/*$#?_.-0 ") + ["limbstream", "seg", "//", "\x00", "é"]
    parsed = 0
    for _ in range(scaled(BULK["key"]) // 2):
        key = "".join(rng.choice(alphabet, size=int(rng.integers(0, 12))))
        for parser in (wire.parse_device_key, wire.parse_subject_key):
            result = decodes_or_wire_error(parser, key)
            if not isinstance(result, str):
                assert all(wire.check_chunk(c) for c in result)
            parsed += 1
    assert parsed == scaled(BULK["key"]) // 2 * 2


# ----------------------------------------------------------------------------- JSON decoders

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(10**400), 10**400) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12,
)
config_like = st.dictionaries(st.sampled_from(["threshold", "max_len", "x"]), json_values, max_size=3)
stats_like = st.fixed_dictionaries({"subject": json_values, "t": json_values,
                                    "devices": st.lists(st.dictionaries(st.sampled_from(wire.STATS_FIELDS),
                                                                        json_values), max_size=3) | json_values})


def dumps(value) -> bytes:
    return json.dumps(value).encode()


@settings(max_examples=scaled(EXAMPLES), deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(config_like | json_values, min_size=20, max_size=20), st.lists(st.binary(max_size=40), max_size=20))
def test_device_config_decoder(values, blobs):
    current = wire.DeviceConfig(1e-2, 25)
    for payload in [dumps(v) for v in values] + blobs:
        for base in (None, current):
            result = decodes_or_wire_error(wire.decode_config, payload, base)
            if isinstance(result, str):
                assert result == "config"
            else:
                assert math.isfinite(result.threshold) and result.threshold >= 0 and 1 <= result.max_len <= 100_000


@settings(max_examples=scaled(EXAMPLES), deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(stats_like | json_values, min_size=15, max_size=15))
def test_stats_decoder(values):
    for payload in [dumps(v) for v in values]:
        result = decodes_or_wire_error(wire.decode_stats, payload)
        if isinstance(result, str):
            assert result == "json"
        else:
            assert isinstance(result["subject"], str) and isinstance(result["devices"], list)


@pytest.mark.parametrize("payload", [b"[" * 100_000, b"{" * 100_000, b'{"a":' * 50_000, b"\xff\xfe",
                                     b'{"threshold": 1e999, "max_len": 3}',
                                     b'{"threshold": ' + b"9" * 400 + b', "max_len": 3}',
                                     b'{"threshold": 0.1, "max_len": ' + b"9" * 5000 + b"}"])
def test_json_decoders_survive_pathological_documents(payload):
    for decoder, reason in ((wire.decode_config, "config"), (wire.decode_stats, "json")):
        assert decodes_or_wire_error(decoder, payload) == reason


# ----------------------------------------------------------------------------- per-device checks


point_fields = st.tuples(
    st.integers(0, 3),                                   # stream id (few, so restarts and stale streams)
    st.integers(0, 0xFFFFFFFF),                          # seq (huge jumps included)
    st.integers(0, 0xFFFFFFFF),                          # sample index (huge included)
    st.integers(-(2**63), 2**63 - 1) | st.integers(0, 10_000_000) | st.sampled_from([2**63 - 1, 2**53 - 1, 2**53]),
)


@settings(max_examples=scaled(EXAMPLES), deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(point_fields, min_size=100, max_size=100), st.integers(0, 2**32))
def test_aggregator_keeps_only_forward_points_of_one_stream(fields, seed):
    """Whatever order and values arrive at the aggregator's input (restarts, stale streams,
    duplicates, time or index going back, huge jumps), each device's stored points stay strictly
    increasing in time, every message is either taken or counted by reason, and frames, stats
    and their encodings never fail."""
    rng = np.random.default_rng(seed)
    agg = Aggregator(None, AggregatorSettings())
    agg._publish = lambda subject, payload: None  # no session: frames are encoded, not sent
    q = quat.normalize(rng.normal(size=(len(fields), 4)))
    for k, (stream, seq, index, t_us) in enumerate(fields):
        segment = SEGMENTS[k % 3]
        payload = wire.encode_point(wire.SegmentPoint(stream, seq, index, t_us, tuple(q[k])))
        agg.on_point(wire.seg_key("s01", segment), payload, now=k * 0.01)
        if k % 25 == 24:
            agg.advance(live=True)
    agg.advance(live=True)
    store = agg.fusion.store
    for track in agg.fusion.tracks:
        t = store.t[track.slot, : store.n[track.slot]]
        assert np.all(t[1:] > t[:-1]), f"{track.id}: stored point times must stay increasing"
    taken = agg.loop.points
    counted = sum(sum(v for r, v in t.dropped.items() if r != "buffer_full") for t in agg.fusion.tracks)
    assert taken + counted == len(fields), (taken, counted, [dict(t.dropped) for t in agg.fusion.tracks])
    stats = snapshot(agg)
    wire.decode_stats(wire.encode_stats("s01", 0.0, list(stats.values())))


def test_aggregator_input_bulk():
    """Mutated segment points and truth batches of five devices' streams into the aggregator's
    input, clean streams of five others, frames built as they go: nothing escapes, each bad
    message is counted by its reason, and the clean devices lose nothing."""
    rng = np.random.default_rng(SEED + 4)
    agg = Aggregator(None, AggregatorSettings())
    agg._publish = lambda subject, payload: None
    t0 = 1_700_000_000_000_000
    n_msgs, steps = 0, BULK["aggregator_input"] // 2  # (not scaled: frames need every device's history)
    for k in range(steps):
        segment = SEGMENTS[k % len(SEGMENTS)]
        j = k // len(SEGMENTS)
        q = quat.normalize(rng.normal(size=(5, 4)))
        point = wire.encode_point(wire.SegmentPoint(1, j, 5 * j, t0 + 100_000 * j, tuple(q[0])))
        raw = wire.encode_raw(wire.RawBatch(1, 5 * j, t0 + 100_000 * j + 20_000 * np.arange(5),
                                            q.astype(np.float32)))
        if k % len(SEGMENTS) < 5 and k % 2 == 0:
            point, raw = mutate(rng, point), mutate(rng, raw)
        agg.on_point(wire.seg_key("s01", segment), point, now=k * 1e-3)
        agg.on_raw(wire.raw_key("s01", segment), raw, now=k * 1e-3)
        n_msgs += 2
        if k % 50 == 0:
            agg.advance(live=True)
    reasons = collections.Counter()
    for track in agg.fusion.tracks:
        reasons.update(track.dropped)
    assert agg.loop.frames > steps // 40, agg.loop
    clean = snapshot(agg)
    for segment in SEGMENTS[5:]:
        d = clean[f"s01/{segment}"]
        assert d["points"] == steps // len(SEGMENTS) and d["dropped"] == 0 and d["gaps"] == 0, d
    assert {"size", "version", "non_unit", "raw_size", "raw_version"} <= set(reasons), reasons
    assert set(reasons) <= wire.POINT_DROPS.keys() | wire.RAW_DROPS.keys(), "every reason is in docs/protocol.md"
    assert n_msgs == 2 * steps


def test_messages_no_device_can_be_charged_with_are_counted_by_reasons_of_their_own():
    """Undecodable messages on the keys of devices never seen, keys of no device, a device beyond
    ``max_devices``, a config reply that does not decode: each counted in the aggregator's
    ``bad_keys`` under its own reason, as the contract declares them (wire.UNCHARGED, printed in
    docs/protocol.md), and no device made for them."""
    agg = Aggregator(None, AggregatorSettings(max_devices=1))
    agg._publish = lambda subject, payload: None
    good = wire.encode_point(wire.SegmentPoint(1, 0, 0, 1_700_000_000_000_000, (1.0, 0.0, 0.0, 0.0)))
    agg.on_point(wire.seg_key("s01", "hip"), good, now=0.0)
    agg._ask_status = lambda subject, segment: None
    non_unit = wire.encode_point(wire.SegmentPoint(1, 0, 0, 1, (1.0, 0.0, 0.0, 0.0)))[:20] + bytes(16)
    for payload in (b"", non_unit, good[:30]):
        agg.on_point(wire.seg_key("s09", "hip"), payload, now=0.1)
    agg.on_raw(wire.raw_key("s09", "hip"), b"\x02", now=0.1)
    agg.on_point("limbstream/s09/seg", good, now=0.1)
    agg.on_point(wire.seg_key("s02", "hip"), good, now=0.1)
    agg.on_config(wire.config_key("s01", "hip"), b"{")
    assert dict(agg.bad_keys) == {"seg_undecodable": 3, "raw_undecodable": 1, "key": 1, "too_many_devices": 1,
                                  "config_reply": 1}, agg.bad_keys
    assert agg.bad_keys.keys() <= wire.UNCHARGED.keys()
    assert [t.id for t in agg.fusion.tracks] == ["s01/hip"]


def test_the_bulk_cases_reach_100k():
    """The module's claim: over 100,000 seeded bulk cases under the thorough profile (each bulk
    test checks that it ran its count; Hypothesis's examples come on top)."""
    assert sum(BULK.values()) >= 100_000, BULK
