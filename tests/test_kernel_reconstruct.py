"""The aggregator's reconstruction and forward kinematics in C (lsw_fuse.c) against NumPy: the
point store as it was in NumPy (tests/reference_aggregator/store.py, on limbstream.quat) and the
NumPy forward kinematics (tests/reference_aggregator/skeleton.py), on random rows and bodies."""
from __future__ import annotations

import numpy as np
import pytest
from support.reference_aggregator.skeleton import Skeleton as NumpySkeleton
from support.reference_aggregator.store import PointStore as NumpyStore

from limbstream import quat
from limbstream.kernel import reconstruct
from limbstream.services.aggregator.store import PointStore
from limbstream.skeleton import Skeleton


def random_stores(seed: int, rows: int = 60) -> tuple[PointStore, NumpyStore]:
    """The same random rows in both stores: empty, one point, many; rates and held points."""
    rng = np.random.default_rng(seed)
    c, ref = PointStore(64), NumpyStore(64)
    for r in range(rows):
        c.add_slot()
        ref.add_slot()
        n = [0, 1, 2][r] if r < 3 else int(rng.integers(1, 40))
        t = 1_790_000_000_000_000 + np.cumsum(rng.integers(1, 200_000, n))
        q = rng.normal(size=(n, 4)) * rng.uniform(0.9, 1.1, (n, 1))  # stored norms are not exactly 1
        w = rng.normal(0, 3, (n, 3)) * (rng.random((n, 1)) < 0.7)
        for store in (c, ref):
            for k in range(n):
                store.append(r, int(t[k]), q[k], w[k])
    return c, ref


def queries(store: PointStore, seed: int, count: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """Times before, between, at and after each row's points."""
    rng = np.random.default_rng(seed + 100)
    slots = rng.integers(0, store.size, count)
    n = store.n[slots]
    k = rng.integers(0, np.maximum(n, 1))
    base = np.where(n > 0, store.t[slots, k], 1_790_000_000_000_000)
    return slots, base + rng.choice([-300_000, -1, 0, 1, 7_000, 50_000, 400_000], count)


def test_reconstruction_in_c_is_numpys():
    for seed in range(3):
        c, ref = random_stores(seed)
        slots, t = queries(c, seed)
        exact, predicted = c.interpolate(slots, t), c.predicted(slots, t)
        assert np.abs(exact - ref.interpolate(slots, t)).max() < 1e-12
        assert np.abs(predicted - ref.predicted(slots, t)).max() < 1e-12
        live = np.random.default_rng(seed).random(len(slots)) < 0.5
        both = np.where(live[:, None], ref.live(slots, t), ref.interpolate(slots, t))
        assert np.abs(c.reconstruct(slots, t, live) - both).max() < 1e-12
        truth = quat.normalize(np.random.default_rng(seed).normal(size=(len(slots), 4))).astype(np.float32)
        e, p = c.errors(slots, t, truth)
        assert np.abs(e - quat.angle_deg(ref.interpolate(slots, t), truth)).max() < 1e-9
        assert np.abs(p - quat.angle_deg(ref.predicted(slots, t), truth)).max() < 1e-9


def test_errors_of_a_devices_run_of_samples_are_those_of_each_alone():
    """Truth samples come in runs of one device's consecutive times, whose spans the errors'
    call prepares once: the same bits as each sample's alone."""
    for seed in range(3):
        c, _ = random_stores(seed)
        slots, t = queries(c, seed)
        order = np.lexsort((t, slots))
        slots, t = slots[order], t[order]
        truth = quat.normalize(np.random.default_rng(seed).normal(size=(len(slots), 4))).astype(np.float32)
        e, p = c.errors(slots, t, truth)
        alone = np.array([c.errors(slots[i:i + 1], t[i:i + 1], truth[i:i + 1]) for i in range(len(slots))])
        assert np.array_equal(e, alone[:, 0, 0]) and np.array_equal(p, alone[:, 1, 0])


def assert_same_as_a_fresh_view(store: PointStore, slots: np.ndarray, t: np.ndarray, truth: np.ndarray) -> None:
    """The store's C view answers as a view made now (that remembers nothing) does, bit for bit."""
    fresh = reconstruct.PointRows(store.t, store.q, store.w, store.n)
    for mode in (reconstruct.EXACT, reconstruct.LIVE, reconstruct.PREDICTED):
        assert np.array_equal(store._c.reconstruct(slots, t, mode), fresh.reconstruct(slots, t, mode))
    assert np.array_equal(np.array(store.errors(slots, t, truth)), np.array(fresh.errors(slots, t, truth)))


def test_remembered_spans_give_a_fresh_views_bits_whatever_changed_in_the_rows():
    """A store's C view remembers each row's last SLERP spans between calls: its answers are those of
    a view that remembers nothing, also after points were rewritten in place (as a calibration
    does), forgotten, or a row began again with the same times and other orientations."""
    for seed in range(3):
        c, _ = random_stores(seed)
        rng = np.random.default_rng(seed)
        slots, t = queries(c, seed)
        truth = quat.normalize(rng.normal(size=(len(slots), 4))).astype(np.float32)
        assert_same_as_a_fresh_view(c, slots, t, truth)
        assert_same_as_a_fresh_view(c, slots, t, truth)  # every span remembered now
        rows = np.flatnonzero(c.n[:c.size] >= 2)
        for r in rows[::3]:  # points rewritten in place, times kept
            n = c.n[r]
            c.q[r, :n] = quat.multiply(quat.normalize(rng.normal(size=4)), c.q[r, :n].astype(np.float64)).astype(np.float32)
        c.q[rows[1], 0, 0] = -c.q[rows[1], 0, 0]  # one component's sign
        c.shift(int(rows[2]), 1)
        again = int(rows[4])
        times, n = c.t[again, :c.n[again]].copy(), int(c.n[again])
        c.reset(again)
        for k in range(n):
            c.append(again, int(times[k]), rng.normal(size=4))
        assert_same_as_a_fresh_view(c, slots, t, truth)


def test_ring_ranks_are_the_sorted_values_at_those_ranks():
    """Rows full, partly full and short, of positive, signed and whole values, with NaN, -0 and rows of
    one value throughout, asked for ranks across the row or only among its largest: each rank's
    value is the row's sorted values' (numpy's order)."""
    rng = np.random.default_rng(1)
    window = 3000
    for trial in range(60):
        ring = [rng.gamma(2, 1, (20, window)), rng.normal(0, 5, (20, window)),
                np.round(rng.normal(0, 2, (20, window)))][trial % 3].astype(np.float32)
        if trial % 5 == 0:
            ring[rng.random(ring.shape) < 0.01] = np.nan
        if trial % 7 == 0:
            ring[rng.random(ring.shape) < 0.05] = -0.0
        if trial % 11 == 0:
            ring[:] = 1.5
        rows = rng.integers(0, 20, 15)
        n = rng.integers(1, window + 1, 15)
        n[::3] = window
        n[1::5] = rng.integers(1, 10 * reconstruct.RING_TOP, len(n[1::5]))  # short rows
        for quantiles in ((0.0, 0.5, 0.99), (0.99,), (0.999, 0.995)):  # the last two: ranks among the top (a heap)
            ranks = np.stack([np.floor(p * (n - 1)).astype(np.int64) for p in quantiles] + [n - 1], axis=1)
            got = reconstruct.ring_ranks(ring, rows, n, ranks)
            for i in range(len(rows)):
                assert np.array_equal(got[i], np.sort(ring[rows[i], :n[i]])[ranks[i]], equal_nan=True), (trial, i)
    with pytest.raises(ValueError):
        reconstruct.ring_ranks(ring, rows[:1], np.array([window]), np.array([[window]]))


def two_points(q0, q1, w=(0.0, 0.0, 0.0)) -> PointStore:
    store = PointStore(8)
    store.add_slot()
    store.append(0, 0, q0, w)
    store.append(0, 1000, q1, w)
    return store


def test_slerp_ends_sign_closed_form_and_near_identical_points():
    u = np.linspace(0.0, 1.0, 11)
    t = np.round(u * 1000).astype(np.int64)
    zero = np.zeros(len(t), np.int64)
    half_turn = two_points((1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0))
    closed = np.stack([np.cos(np.pi * u / 2), np.sin(np.pi * u / 2), 0 * u, 0 * u], axis=1)
    assert np.abs(half_turn.interpolate(zero, t) - closed).max() < 1e-7, "cos(pi u / 2) + sin(pi u / 2) i"
    q1 = quat.normalize(np.array([0.9, 0.1, -0.3, 0.2]))
    plus, minus = two_points((1.0, 0.0, 0.0, 0.0), q1), two_points((1.0, 0.0, 0.0, 0.0), -q1)
    assert quat.angle_deg(plus.interpolate(zero, t), minus.interpolate(zero, t)).max() < 1e-6, "q and -q"
    assert np.abs(plus.interpolate(zero[:1], t[:1]) - [1.0, 0.0, 0.0, 0.0]).max() < 1e-12, "u = 0"
    assert quat.angle_deg(plus.interpolate(zero[-1:], t[-1:]), q1).max() < 1e-6, "u = 1"
    near = quat.normalize(np.array([1.0, 1e-9, 0.0, 0.0]))
    tiny = two_points((1.0, 0.0, 0.0, 0.0), near).interpolate(zero, t)
    assert np.all(np.isfinite(tiny)) and quat.angle_deg(tiny, [1.0, 0.0, 0.0, 0.0]).max() < 1e-6


def test_the_live_view_extrapolates_the_newest_point_with_its_rate():
    spin = two_points((1.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 2.0))
    t = np.array([1000 + 100_000, 500, -5])
    live = spin.reconstruct(np.zeros(3, np.int64), t, np.ones(3, bool))
    assert quat.angle_deg(live[0], quat.predict(np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, 2.0]), 0.1)) < 1e-9
    assert np.abs(live[1:] - [1.0, 0.0, 0.0, 0.0]).max() < 1e-12, "within the points: exact; before: held"
    assert np.abs(spin.predicted(np.zeros(1, np.int64), np.array([-5])) - [1.0, 0.0, 0.0, 0.0]).max() == 0, "none yet"


def test_forward_kinematics_in_c_is_numpys_bit_for_bit():
    rng = np.random.default_rng(5)
    q = quat.normalize(rng.normal(size=(200, 10, 4)))
    tpose = rng.random(200) < 0.5
    for body in ({}, {"thigh": 0.5, "upperarm": 0.33, "rest_pose": "tpose"}):
        c, ref = Skeleton(**body), NumpySkeleton(**body)
        for args in ((q, tpose), (q,), (q[0],), (q, True), (q.reshape(4, 50, 10, 4), tpose.reshape(4, 50))):
            assert np.array_equal(c.positions(*args), ref.positions(*args))
    assert reconstruct.MAX_JOINTS >= len(Skeleton().positions(q[0]))


def test_error_windows_filled_in_c_are_numpys():
    from support.reference_aggregator.store import ErrorRings as NumpyRings

    from limbstream.services.aggregator.rings import ErrorRings
    rng = np.random.default_rng(6)
    c, ref = ErrorRings(50, rows=8), NumpyRings(50, slots=8)
    for _ in range(40):
        rows = rng.integers(0, 8, int(rng.integers(1, 120)))
        values = rng.gamma(2.0, 3.0, len(rows))
        c.add(rows, values)
        ref.add(rows, values)
        assert np.array_equal(c.values, ref.values) and np.array_equal(c.count, ref.count)
        assert np.array_equal(c.total, ref.total)
