"""SegmenterBank.update_wire (C: lsw_bank.h): the segment point messages it returns are, byte for
byte, those limbstream.wire.encode_point makes from the bank's points as the emulator built them
(wire fields from the ring, body rate from points_omega, version 2 where the live rule is on)."""
from __future__ import annotations

import numpy as np
import pytest

from limbstream import kernel, wire

RING = 5
BOUNDS = (0.0, 2.0, 5.0, 10.0, 180.0)


def cmu_devices(path) -> np.ndarray:
    """(m, S, 4) float32: the first clip of the CMU set, every segment a device."""
    data = np.load(path)
    clip = data[sorted(k for k in data.files if k.startswith("clip_"))[0]]
    return np.ascontiguousarray(clip, np.float32)


def python_messages(bank: kernel.SegmenterBank, status, index, yp, stream, seq, base, sample, t_us, live):
    """{slot: message} the way the emulator encoded points before the bank did."""
    emitted = np.flatnonzero(status == kernel.POINT)
    omega = bank.points_omega() if len(emitted) else None
    out = {}
    for k in emitted:
        row = int(index[k]) % RING
        rate = tuple(float(v) for v in omega[k]) if live[k] else None
        point = wire.SegmentPoint(int(stream[k]), int(seq[k]), int(sample[row, k] - base[k]), int(t_us[row, k]),
                                  tuple(float(v) for v in yp[k]), 0, rate)
        out[int(k)] = wire.encode_point(point)
        seq[k] = (int(seq[k]) + 1) & 0xFFFFFFFF
    return out


def test_bank_messages_equal_python_encoder(cmu_npz):
    y = cmu_devices(cmu_npz)
    m, count = y.shape[0], y.shape[1]
    rng = np.random.default_rng(11)
    bounds = np.array([BOUNDS[k % len(BOUNDS)] for k in range(count)])
    thresholds = np.where(np.arange(count) % 2 == 0, 1e-2, 1e-3)
    fast = kernel.SegmenterBank(count, thresholds, 25, live_bound_deg=bounds, ring=RING)
    ref = kernel.SegmenterBank(count, thresholds, 25, live_bound_deg=bounds)
    fast.stream[:] = rng.integers(0, 1 << 16, count)
    fast.seq[:] = 0xFFFFFFFF - rng.integers(0, 40, count)  # wraps around during the run
    fast.base[:] = rng.integers(0, 1000, count)
    seq = fast.seq.copy()
    live = [0.0 < b < 180.0 for b in bounds]
    taken = fast.base + rng.integers(0, 50, count)  # sample number of each device's next sample
    t = np.zeros(count, np.int64) + 1_700_000_000_000_000 + rng.integers(0, 10**6, count)
    ticks = np.zeros(count, np.int64)
    messages = v2 = 0
    for call in range(m):
        if call == m // 2:  # live rule switched on and off mid-stream: the version follows
            for k, b in ((0, 5.0), (2, 0.0)):
                fast.retune(k, thresholds[k], 25, b)
                ref.retune(k, thresholds[k], 25, b)
                live[k] = b > 0
        skip = rng.random(count) < 0.1  # a device with no sample due this call (the emulator's NaN row)
        rows = np.where(skip[:, None], np.nan, y[call]).astype(np.float32)
        row = call % RING
        fast.sample[row] = np.where(skip, -1, taken)
        fast.t_us[row] = t
        ticks += 20_000
        want = python_messages(ref, *ref.update(ticks.astype(np.uint32), rows), fast.stream, seq, fast.base,
                               fast.sample, fast.t_us, live)
        slots, payload, ends = fast.update_wire(ticks.astype(np.uint32), rows)
        starts = np.concatenate([[0], ends[:-1]]).astype(int)
        got = {int(k): payload[a:b] for k, a, b in zip(slots, starts, ends)}
        assert got == want, f"call {call}"
        assert len(payload) == (int(ends[-1]) if len(ends) else 0)
        taken += ~skip
        t += np.where(skip, 0, 20_000 + rng.integers(-300, 300, count))
        messages += len(got)
        v2 += sum(msg[0] == wire.VERSION_RATE for msg in got.values())
    assert np.array_equal(fast.seq, seq)
    assert messages > 500 and 0 < v2 < messages, (messages, v2)
    assert (fast.seq < 100).any(), "some sequence numbers wrapped"


def test_bank_messages_decode_to_the_kernel_points(cmu_npz):
    """The bank's messages decode to its points: index, time, quaternion and rate."""
    y = cmu_devices(cmu_npz)[:300]
    count = y.shape[1]
    bank = kernel.SegmenterBank(count, 1e-2, 25, live_bound_deg=5.0, ring=RING)
    bank.stream[:] = np.arange(count) + 100
    for call in range(len(y)):
        bank.sample[call % RING] = call
        bank.t_us[call % RING] = 10**15 + call * 20_000
        slots, payload, ends = bank.update_wire(np.full(count, call * 20_000, np.uint32), y[call])
        omega = bank.points_omega()
        start = 0
        for k, end in zip(slots.tolist(), ends.tolist()):
            point = wire.decode_point(payload[start:end])
            start = end
            assert (point.stream, point.flags) == (k + 100, 0)
            assert point.t_us == 10**15 + point.index * 20_000
            assert np.array_equal(np.float32(point.q), y[point.index, k])
            assert np.allclose(point.omega, omega[k], rtol=1e-6, atol=1e-6)
    assert (bank.seq > 10).all()


def test_update_wire_needs_a_ring():
    with pytest.raises(ValueError, match="ring"):
        kernel.SegmenterBank(2).update_wire(np.zeros(2, np.uint32), np.zeros((2, 4), np.float32))
