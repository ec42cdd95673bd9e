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
