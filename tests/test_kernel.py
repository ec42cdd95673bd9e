"""fastSW and SW (C) against the brute-force NumPy Sliding Window, and the kernel's edge cases;
fastSW's live rule: tests/test_kernel_live.py."""
from __future__ import annotations

import ctypes

import numpy as np
import pytest
from support.streams import cmu_streams, random_walk_quaternions, rates_match, synthetic_streams, xio_streams
from support.sw_oracle import live_sliding_window, sliding_window

from limbstream import kernel
from limbstream.kernel import Segmenter, SegmenterBank, segment

THRESHOLDS = np.logspace(-6, 3, 21)  # >= 20 thresholds from 1e-6 to 1e3


def compare_with_oracle(streams, algorithm: str) -> tuple[int, int, list[str]]:
    """(identical points, points in either result, worst offenders) over all streams x thresholds."""
    same = total = 0
    offenders = []
    for name, t, q in streams:
        for threshold in THRESHOLDS:
            got = segment(t, q, threshold, algorithm=algorithm).index
            want = sliding_window(t, q, threshold)
            common = len(np.intersect1d(got, want))
            union = len(np.union1d(got, want))
            same += common
            total += union
            if common != union:
                offenders.append(f"{name}@{threshold:.3g}: {union - common}")
    return same, total, offenders


@pytest.fixture(scope="module")
def all_streams(cmu_npz, xio_dir):
    return cmu_streams(cmu_npz) + xio_streams(xio_dir) + synthetic_streams()


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["fastsw", "sw"])
def test_equals_brute_force_sliding_window(all_streams, algorithm):
    same, total, offenders = compare_with_oracle(all_streams, algorithm)
    quasi = total - same
    print(f"\n{algorithm}: {same}/{total} identical segment points, {quasi} quasi-equal "
          f"({len(offenders)} stream x threshold runs differ) over {len(all_streams)} streams "
          f"x {len(THRESHOLDS)} thresholds")
    assert same / total >= 0.999, f"only {same}/{total} identical; e.g. {offenders[:10]}"


def test_fastsw_equals_c_sw(all_streams):
    same = total = 0
    for _, t, q in all_streams[::3]:
        for threshold in THRESHOLDS:
            a = segment(t, q, threshold).index
            b = segment(t, q, threshold, algorithm="sw").index
            same += len(np.intersect1d(a, b))
            total += len(np.union1d(a, b))
    print(f"\nfastSW vs C SW: {same}/{total} identical")
    assert same / total >= 0.999


def test_points_are_original_samples_bit_for_bit(cmu_npz):
    t, q = cmu_streams(cmu_npz)[7][1:]
    result = segment(t, q, 1e-3)
    assert np.array_equal(result.q, q[result.index])
    assert result.q.dtype == q.dtype
    streamed = Segmenter(threshold=1e-3)
    points = [p for p in (streamed.update(ti, qi) for ti, qi in zip(t, q)) if p is not None]
    points.append(streamed.flush())
    assert [p[0] for p in points if p] == result.index.tolist()
    for index, _, y in (p for p in points if p):
        assert y.tobytes() == q[index].astype(np.float32).tobytes()


def test_first_and_last_sample_are_points():
    t = np.arange(50) * 0.02
    q = random_walk_quaternions(50, 3)
    for threshold in (0.0, 1e-4, 1e3):
        index = segment(t, q, threshold).index
        assert index[0] == 0 and index[-1] == 49, index


def test_straight_line_keeps_only_its_ends():
    t = np.arange(100) * 0.01
    q = np.stack([np.ones(100), t * 0.1, np.zeros(100), np.zeros(100)], axis=1)  # linear in t
    # float32 resolves the SSR to ~1e-7 of sum |y|^2: 1e-6 is far above that noise here
    assert segment(t, q, 1e-6).index.tolist() == [0, 99]


def test_max_len_caps_segment_length():
    t = np.arange(200) * 0.02
    q = np.tile([1.0, 0, 0, 0], (200, 1))  # still limb: only the cap splits
    index = segment(t, q, 1.0, max_len=25).index
    assert np.all(np.diff(index) <= 25), np.diff(index)
    assert index.tolist() == list(range(0, 200, 25)) + [199]
    assert index.tolist() == sliding_window(t, q, 1.0, max_len=25).tolist()


def test_non_finite_samples_are_rejected_and_counted():
    t = np.arange(100) * 0.02
    q = random_walk_quaternions(100, 5)
    bad = q.copy()
    bad[10, 1] = np.nan
    bad[20, 0] = np.inf
    bad[30, 2] = -np.inf
    result = segment(t, bad, 1e-3)
    assert result.rejected == 3
    assert not set(result.index) & {10, 20, 30}
    clean = np.delete(np.arange(100), [10, 20, 30])
    expected = clean[sliding_window(t[clean], q[clean], 1e-3)]
    assert result.index.tolist() == expected.tolist()


def test_zero_and_negative_time_steps_are_rejected():
    t = np.arange(100) * 0.02
    t[40] = t[39]          # zero step
    t[60] = t[59] - 0.01   # going back
    q = random_walk_quaternions(100, 6)
    result = segment(t, q, 1e-3)
    assert result.rejected == 2
    keep = np.delete(np.arange(100), [40, 60])
    assert result.index.tolist() == keep[sliding_window(t[keep], q[keep], 1e-3)].tolist()


def test_tick_counter_wraparound():
    """Timestamps that cross 2**32 microseconds segment as if they did not."""
    t = 4294.9 + np.arange(300) * 0.02  # crosses 2**32 us = 4294.967 s
    q = random_walk_quaternions(300, 7)
    ticks = (np.round(t * 1e6).astype(np.int64) & 0xFFFFFFFF).astype(np.uint32)
    assert ticks[-1] < ticks[0]
    for live in (0.0, 3.0):
        index, known, omega = raw_ticks_segment(ticks, q, 1e-3, 1000, live)
        want, want_known, want_omega = live_sliding_window(t - t[0], q, 1e-3, 1000, live)
        assert index.tolist() == want.tolist(), live
        assert known.tolist() == want_known.tolist(), live
        assert rates_match(omega, want_omega), live


def raw_ticks_segment(ticks: np.ndarray, q: np.ndarray, threshold: float, max_len: int,
                      live_bound_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """fastsw_segment on the caller's own uint32 ticks: (index, known_from, omega rad/s)."""
    settings = kernel.make_settings(threshold, max_len, 4, live_bound_deg)
    y = np.ascontiguousarray(q, np.float32)
    index, call = np.empty(len(ticks), np.uint32), np.empty(len(ticks), np.uint32)
    rates = np.empty((len(ticks), 4), np.float32)
    out = kernel.BatchOut(index.ctypes.data, None, call.ctypes.data, rates.ctypes.data)
    k = kernel._lib.fastsw_segment(settings, ticks, y, len(ticks), out, None)
    return index[:k].astype(np.int64), call[:k].astype(np.int64), kernel.body_rates(y[index[:k]], rates[:k])


def test_bad_arguments_raise_value_error():
    t = np.arange(10) * 0.02
    q = random_walk_quaternions(10, 1)
    with pytest.raises(ValueError, match="threshold"):
        segment(t, q, -1.0)
    with pytest.raises(ValueError, match="max_len"):
        segment(t, q, 1e-3, max_len=0)
    with pytest.raises(ValueError, match="algorithm"):
        segment(t, q, 1e-3, algorithm="nope")
    with pytest.raises(ValueError, match="dim"):
        segment(t, np.zeros((10, kernel.MAX_DIM + 1)), 1e-3)
    with pytest.raises(ValueError, match="shape|must be"):
        segment(t[:5], q, 1e-3)


def test_bank_equals_independent_streams():
    m, count = 400, 7
    t = np.arange(m) * 0.02
    streams = [random_walk_quaternions(m, 20 + k) for k in range(count)]
    thresholds = np.logspace(-4, -1, count)
    bank = SegmenterBank(count, threshold=thresholds, max_len=50)
    got = [[] for _ in range(count)]
    ticks = kernel.to_ticks(t)
    for i in range(m):
        status, index, _ = bank.update(np.full(count, ticks[i]), np.stack([s[i] for s in streams]))
        for k in np.flatnonzero(status == kernel.POINT):
            got[k].append(int(index[k]))
    for k in range(count):
        last = bank.flush(k)
        got[k].append(last[0]) if last else None
        want = segment(t, streams[k], thresholds[k], max_len=50).index.tolist()
        assert got[k] == want, f"stream {k}"


def test_retune_changes_segmentation_from_next_sample():
    t = np.arange(400) * 0.02
    q = random_walk_quaternions(400, 9)
    seg = Segmenter(threshold=1e3, max_len=1000)
    early = sum(seg.update(ti, qi) is not None for ti, qi in zip(t[:200], q[:200]))
    seg.retune(1e-6, 1000)
    late = sum(seg.update(ti, qi) is not None for ti, qi in zip(t[200:], q[200:]))
    assert early == 1 and late > 20, (early, late)


def test_the_bindings_struct_copies_have_the_c_sizes():
    """The load-time check compares what the C library reports (lsw_abi.h) with the ctypes copies."""
    structs = (kernel.Settings, kernel.Point, kernel.BatchOut, kernel.BankWire)
    assert [kernel._lib.lsw_abi_size(k) for k in range(len(structs))] == [ctypes.sizeof(s) for s in structs]
    assert kernel._lib.lsw_abi_size(99) == 0, "an unknown struct has no size"
