"""Points Zenoh reports missed, although the device's cache still holds them, are asked of that
cache again by the aggregator (``HistoryQueries.refill``, services/aggregator/history.py): they
reach its store and stats, and ``missed`` counts only what the cache could not give.

Zenoh's recovery query for a miss can end with no reply (the device's link cut by the lease on a
saturated machine: docs/reliability.md), and Zenoh does not ask again. Here a real device
publisher's point 12 reaches the router before its points 10 and 11 (the sample as the publisher
sends it: its own id and sequence number): Zenoh's recovery query for 10 and 11 reaches the
device's cache before they are in it, ends with no reply, and Zenoh reports them missed. The
device then publishes from point 10 on (Zenoh drops 10, 11 and 12 as duplicates), or nothing."""
from __future__ import annotations

import time

import pytest
import zenoh
from support.stack import wait_until

from limbstream import wire, zconfig
from limbstream.device import io
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings, snapshot
from support.points import PointLog

POINTS = [wire.SegmentPoint(1, seq, 3 * seq, 60_000 * seq, (1.0, 0.0, 0.0, 0.0), 0) for seq in range(20)]


@pytest.mark.parametrize("cached", [True, False], ids=["cache-holds-them", "cache-lacks-them"])
def test_points_zenoh_reports_missed_are_asked_of_the_devices_cache_again(stack, cached):
    stack.router()
    device = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    agg = Aggregator(session, AggregatorSettings(subjects=("s01",)))
    log = PointLog(stack.endpoint)  # the tests' reader of every point fills them the same way
    try:
        pub = io.point_publisher(device, "s01", "l_thigh", 512, 2.0)
        agg.open()
        misses = agg._seg_subs[0].sample_miss_listener(zenoh.handlers.FifoChannel(16))

        def drained(until):
            return lambda: agg.drain(time.perf_counter()) >= 0 and until()

        for p in POINTS[:10]:
            pub.put(wire.encode_point(p))
        wait_until(drained(lambda: (t := agg.known("s01", "l_thigh")) is not None and t.points == 10
                           and len(log.poll().get("s01/l_thigh", ())) == 10), 10, "the first 10 points")
        track = agg.known("s01", "l_thigh")
        device.put(wire.seg_key("s01", "l_thigh"), wire.encode_point(POINTS[12]), source_info=zenoh.SourceInfo(pub.id, 12))
        miss = wait_until(misses.try_recv, 10, "Zenoh's miss report")
        assert (str(miss.source), miss.nb) == (str(pub.id), 2)
        if cached:
            for p in POINTS[10:]:
                pub.put(wire.encode_point(p))
        wait_until(drained(lambda: track.next_seq == (20 if cached else 13) and not agg.history.refilling), 15,
                   "the gap's refill to end", on_fail=lambda: print(track.points, track.gaps, agg.loop.missed))
        kept = POINTS if cached else POINTS[:10] + POINTS[12:13]
        assert agg.fusion.store.t[track.slot, :agg.fusion.store.n[track.slot]].tolist() == [p.t_us for p in kept]
        stats = snapshot(agg)["s01/l_thigh"]
        assert (stats["points"], stats["gaps"], stats["dropped"], agg.loop.missed) == (
            (20, 0, 0, 0) if cached else (11, 2, 0, 2))
        assert list(track.gap_spans) == ([] if cached else [(POINTS[9].t_us, POINTS[12].t_us)])
        wait_until(lambda: len(log.poll()["s01/l_thigh"]) == len(kept) - 2 * cached, 10, "the reader's points")
        assert log.misses == [(str(pub.id), 2)]
        assert (log.fill_starts()["s01/l_thigh"], log.filled.get("s01/l_thigh")) == (kept, 2 if cached else 0)
    finally:
        log.close()
        agg.close()
        session.close()
        device.close()
