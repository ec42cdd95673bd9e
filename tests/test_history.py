"""A joining aggregator gets the start of each device's stream: when Zenoh's history does not
bring it first, the aggregator asks the device's cache itself and settles the stream when that
query completes (services/aggregator/aggregator.py, ``_ask_history``)."""
from __future__ import annotations

import time

import zenoh
from stack import wait_until

from limbstream import wire, zconfig
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
from limbstream.services.aggregator.track import HISTORY_WAIT_S
from limbstream.sources import SEGMENTS


def test_a_stream_joined_late_gets_its_start_from_the_devices_cache(watch, stack):
    """The aggregator is fed live points only (a plain subscriber: as when Zenoh's history
    misses a publisher or arrives late), so every stream's first point received is not its
    start. It takes in every earlier point from the device's cache, and the stream settles when
    that query completes, not after the upper bound of HISTORY_WAIT_S."""
    stack.emulator(subjects=1)
    wait_until(lambda: all(watch.device_status(f"s01/{s}")["points"] >= 5 for s in SEGMENTS), 60,
               "every device past its first points", interval=0.2, on_fail=stack.logs)
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    live = session.declare_subscriber(wire.device_selector("seg", "s01"), zenoh.handlers.FifoChannel(4096))
    agg = Aggregator(session, AggregatorSettings(subjects=("s01",)))  # fed by hand, from `live`
    began = time.perf_counter()
    try:
        def settled():
            now = time.perf_counter()
            while (sample := live.try_recv()) is not None:
                agg.on_point(str(sample.key_expr), sample.payload.to_bytes(), now, sample)
            agg.drain(now)
            agg.advance(live=False, now=now)
            tracks = [agg.known("s01", s) for s in SEGMENTS]
            return all(t is not None and t.first_seq is not None and t.settled(now) for t in tracks) and tracks

        tracks = wait_until(settled, 30, "every stream settled", on_fail=stack.logs)
        took = time.perf_counter() - began
        for t in tracks:
            assert t.first_seq > 0, f"{t.id}: its first point received is its start"
            assert len(t.early) == t.first_seq, f"{t.id}: {len(t.early)} of {t.first_seq} earlier points"
            assert t.history == "done" and not t.dropped, (t.id, t.history, dict(t.dropped))
        assert took < HISTORY_WAIT_S, f"settled after {took:.2f} s: by the bound, not by the query's end"
    finally:
        live.undeclare()
        session.close()
