"""``emulate --once`` with clips of different lengths, end to end on loopback (real router,
emulator and aggregator processes): every device's stream ends at its own clip's end."""
from __future__ import annotations

import numpy as np
import pytest
import zenoh
from support.stack import stack, wait_for_subscribers, wait_until  # noqa: F401  (fixture)

from limbstream import evaluation, wire
from limbstream.sources import SEGMENTS, load_npz
from limbstream.sources.generator import GeneratorSource

LENGTHS = {"s01": 260, "s02": 610}  # samples at 50 Hz; s01 (the first subject) has the shorter clip


def two_clips(path):
    """An npz in the loader's format: clip_short (s01's) and clip_long (s02's), seeded generator motion."""
    short = GeneratorSource(seed=4).chunk(0, LENGTHS["s01"])[1]
    long = GeneratorSource(seed=5).chunk(0, LENGTHS["s02"])[1]
    np.savez(path, fs=50.0, segment_names=np.array(SEGMENTS), clip_short=short, clip_long=long)
    motions = load_npz(path)
    assert [len(m.t) for m in motions] == list(LENGTHS.values())
    return dict(zip(LENGTHS, motions))


def test_each_subject_ends_with_its_own_clip(stack, watch, tmp_path):  # noqa: F811
    path = tmp_path / "two_clips.npz"
    motions = two_clips(path)
    stack.aggregator()
    keys = [k for s in LENGTHS for seg in SEGMENTS for k in (wire.seg_key(s, seg), wire.raw_key(s, seg))]
    wait_for_subscribers(stack.endpoint, keys, "the aggregator's subscriptions", on_fail=stack.logs)
    # the short subject's own streams, as sent (the tail is what matters: its end)
    points = {seg: watch.session.declare_subscriber(wire.seg_key("s01", seg), zenoh.handlers.FifoChannel(1 << 14))
              for seg in SEGMENTS}
    truth = watch.session.declare_subscriber(wire.truth_key("s01"), zenoh.handlers.FifoChannel(1 << 12))  # one per batch
    stack.emulator(2, 10.0, "--source", str(path), "--once", "--max-len", "25")

    def finished():
        devices = watch.poll()
        return (len(devices) == 20 and all(d["final"] and d["error_samples"] == d["samples"] > 0
                                           for d in devices.values()) and devices)
    devices = wait_until(finished, 60, "every device final and evaluated to its last sample", on_fail=stack.logs)

    raws: dict[str, list] = {seg: [] for seg in SEGMENTS}
    for message in iter(truth.try_recv, None):
        for seg, payload in wire.decode_truth(message.payload.to_bytes()):
            raws[seg].append(wire.decode_raw(payload))
    for seg in SEGMENTS:
        got = [wire.decode_point(s.payload.to_bytes()) for s in iter(points[seg].try_recv, None)]
        assert got, f"s01/{seg}: no points received"
        finals = [p for p in got if p.flags & wire.FLAG_FINAL]
        assert len(finals) == 1 and got[-1] is finals[0], f"s01/{seg}: FINAL points {finals}, last {got[-1]}"
        assert got[-1].index == LENGTHS["s01"] - 1, f"s01/{seg}: last point at {got[-1].index}"
        assert max(p.index for p in got) == LENGTHS["s01"] - 1
        last = max(b.first_index + len(b.t_us) for b in raws[seg])
        assert last == LENGTHS["s01"], f"s01/{seg}: truth tap up to sample {last - 1}"

    for subject, m in LENGTHS.items():
        mine = [d for d in devices.values() if d["subject"] == subject]
        for d in mine:
            own = watch.device_status(d["device"])
            assert d["samples"] == own["samples"] == m, f"{d['device']}: aggregator {d['samples']}, " \
                f"device {own['samples']}, clip {m}"
            assert d["error_samples"] == m and d["final"] and d["gaps"] == 0, d
        expected = evaluation.evaluate([motions[subject]], ["fastsw"], [1e-2], max_len=25)[0]
        pooled = sum(d["aad_all_deg"] * d["error_samples"] for d in mine) / sum(d["error_samples"] for d in mine)
        print(f"\n{subject} ({m} samples): AAD {pooled:.9f} deg vs eval {expected['aad']:.9f} deg")
        assert abs(pooled - expected["aad"]) < 1e-6, (subject, pooled, expected)
        total_points = sum(d["points"] for d in mine)
        assert total_points / (len(SEGMENTS) * m) == pytest.approx(expected["icr"], abs=1e-12), subject
