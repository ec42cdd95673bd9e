"""The windows of the aggregator's figures: one window per subject for the values all its devices
get at once (the live latency) has the order statistics of one window per device."""
from __future__ import annotations

import numpy as np

from limbstream.services.aggregator.rings import ErrorRings, SubjectRings


def test_subject_windows_give_each_device_the_figures_of_its_own_window():
    rng = np.random.default_rng(4)
    window, subjects, per_subject = 50, 3, 4
    owner = np.repeat(np.arange(subjects), per_subject)
    shared, own = SubjectRings(window), ErrorRings(window, rows=1)
    own.ensure(len(owner))
    shared.add_subject(subjects)
    for _ in owner:
        shared.add_device()
    started = np.zeros(len(owner), bool)
    for step in range(200):
        started |= rng.random(len(owner)) < 0.05          # a device's first point: values from now on
        for slot in np.flatnonzero(rng.random(len(owner)) < 0.005):  # a new stream: its window starts over
            started[slot] = False
            shared.reset(slot)
            own.reset(slot)
        framed = np.flatnonzero(rng.random(subjects) < 0.8)  # subjects with a live frame this tick
        values = rng.gamma(2.0, 10.0, len(framed))
        getting = np.flatnonzero(started & np.isin(owner, framed))
        shared.add(framed, values, getting, owner[getting])
        own.add(getting, values[np.searchsorted(framed, owner[getting])])
        if step % 7 == 0:
            slots = np.arange(len(owner))
            expected = own.summary(slots, (0.5, 0.99))[2:]
            got = shared.quantiles(slots, owner, (0.5, 0.99))
            for e, g in zip(expected, got):
                assert np.array_equal(np.isnan(e), np.isnan(g)) and np.array_equal(e[~np.isnan(e)], g[~np.isnan(g)]), (
                    step, e, g)
            assert np.array_equal(shared.count(slots, owner), own.count), step


def test_window_summaries_are_the_order_statistics_and_mean_of_each_rows_newest_values():
    rng = np.random.default_rng(7)
    window = 40
    rings = ErrorRings(window, rows=2)
    kept: list[list[float]] = [[] for _ in range(6)]
    for step in range(120):
        rows = np.flatnonzero(rng.random(6) < np.linspace(0.1, 0.9, 6))  # rows fill at different paces
        values = rng.gamma(2.0, 3.0, len(rows)).astype(np.float32)
        rings.ensure(6)
        rings.add(rows, values)
        for row, value in zip(rows, values):
            kept[row].append(float(value))
        if step % 9:
            continue
        ask = np.array([5, 0, 3, 1, 4, 2])  # not in row order
        mean, mx, p50, p99 = rings.summary(ask, (0.5, 0.99))
        for i, row in enumerate(ask):
            held = np.sort(np.array(kept[row][-window:], np.float64))
            if len(held) == 0:
                assert np.isnan([mean[i], mx[i], p50[i], p99[i]]).all()
                continue
            k = len(held)
            assert (mx[i], p50[i], p99[i]) == (held[-1], held[int(0.5 * (k - 1))], held[int(0.99 * (k - 1))]), (step, row)
            assert abs(mean[i] - held.mean()) <= 1e-12 * held.mean(), (step, row)
