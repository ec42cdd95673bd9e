"""The tests' reader of segment points (support.points.PointLog) gets every point a device put,
its stream's start included, when Zenoh's advanced subscriber drops that start: its first
history query ends while the device's own query is still under way, and a live point comes
first (two answerers that hold their queries until released stand for devices answering late
under load; the points are a real device publisher's, through a real router)."""
from __future__ import annotations

import threading

import zenoh

from limbstream import wire, zconfig
from limbstream.device import io
from support.points import PointLog
from support.stack import wait_until


class HeldQueries:
    """A queryable of ``session`` on ``key`` that answers nothing until :meth:`release` ends its
    queries; made once the router routes there the queries of ``other`` (another session)."""

    def __init__(self, session: zenoh.Session, key: str, other: zenoh.Session):
        self.queries: list[zenoh.Query] = []
        self.arrived, self.routed = threading.Event(), threading.Event()
        self._lock = threading.Lock()
        self.queryable = session.declare_queryable(key, self._hold)
        wait_until(lambda: self.routed.is_set() or other.get(f"{key}?probe", timeout=1.0) is None, 10,
                   f"queries on {key} routed")

    def _hold(self, query: zenoh.Query) -> None:
        if "probe" in str(query.parameters):
            with query:  # answered at once
                self.routed.set()
            return
        with self._lock:
            self.queries.append(query)
        self.arrived.set()

    def release(self) -> None:
        """Answer no more queries (undeclared) and end every query held, with no reply."""
        self.queryable.undeclare()
        with self._lock:
            queries, self.queries = self.queries, []
        for query in queries:
            with query:  # its end
                pass


def test_a_streams_start_dropped_by_zenoh_is_taken_from_the_devices_cache(stack):
    stack.router()
    slow = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    device = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    log = None
    try:
        # answers every reader's first history query (limbstream/*/*/seg/@adv/**) late
        initial = HeldQueries(slow, wire.seg_key("s00", "late") + "/@adv/pub/00/1/_", device)
        log = PointLog(stack.endpoint)
        seen = log.session.declare_subscriber(wire.device_selector("seg"), zenoh.handlers.FifoChannel(100))
        wait_until(initial.arrived.is_set, 10, "the reader's first history query")
        # answers the device's own history query late (the query a reader makes on detecting it)
        own = HeldQueries(slow, wire.seg_key("s01", "l_thigh") + f"/@adv/pub/{device.zid()}/**", device)
        pub = io.point_publisher(device, "s01", "l_thigh", 512, 2.0)
        wait_until(own.arrived.is_set, 10, "the reader's query of the device's cache")
        points = [wire.SegmentPoint(1, seq, 3 * seq, 60_000 * seq, (1.0, 0.0, 0.0, 0.0),
                                    wire.FLAG_FINAL if seq == 24 else 0) for seq in range(25)]
        for p in points[:10]:
            pub.put(wire.encode_point(p))
        received = []
        wait_until(lambda: received.extend(iter(seen.try_recv, None)) or len(received) == 10, 10,
                   "the reader's session to receive the first 10 points")
        initial.release()  # the first history query ends; the device's own is still under way
        for p in points[10:]:
            pub.put(wire.encode_point(p))
        wait_until(lambda: log.ended(1), 10, "the stream's last point", on_fail=log.poll)
        own.release()
        # Zenoh delivers a tail of the stream: usually from point 10 on (the start dropped without a
        # miss); how much of the start it drops depends on its threads' timing
        delivered = [p.seq for p in log.poll()["s01/l_thigh"]]
        assert delivered == list(range(delivered[0], 25)), delivered
        assert log.misses == []  # dropped without a miss
        assert log.fill_starts()["s01/l_thigh"] == points
        assert log.filled.get("s01/l_thigh", 0) == delivered[0]
    finally:
        if log is not None:
            log.close()
        slow.close()
        device.close()
