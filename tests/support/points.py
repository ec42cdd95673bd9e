"""Every segment point on a router, by device, read as the aggregator reads them
(:class:`PointLog`): Zenoh's advanced subscriber with history and recovery, and the device's
cache asked for a stream's start that Zenoh did not deliver and for points it reported missed
(``HistoryQueries`` in services/aggregator/history.py does the same for the aggregator).

Zenoh 1.10's advanced subscriber holds a new publisher's live samples back only while its first
history query is under way; while the publisher's own query (on detecting it, or for samples
held back) is under way, the next live sample is delivered at once and the older ones that
query brings are dropped as duplicates, without a miss. A stream whose first points did not come
live before (held back by a slow first query, or lost with a cut link) loses its start so
(``tests/test_point_log.py``; docs/reliability.md).
"""
from __future__ import annotations

import zenoh
import zenoh.ext as zext

from limbstream import wire, zconfig

CACHE = 512
"""Points a device's cache holds (``limbstream.device.host.HostSettings.cache``)."""


class PointLog:
    """The points of every device on the router at ``endpoint``, by device, publisher and Zenoh
    sequence number. :meth:`fill_starts` then asks each device's cache for the start of a stream that
    Zenoh dropped and for points it reported missed (the query's end, an event, ends it);
    :meth:`points` lists them in order."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.sub = zext.declare_advanced_subscriber(
            self.session, wire.device_selector("seg"), zenoh.handlers.FifoChannel(100_000),
            history=zext.HistoryConfig(detect_late_publishers=True, max_samples=1024),
            recovery=zext.RecoveryConfig(heartbeat=True), subscriber_detection=True)
        self.misses: list[tuple[str, int]] = []  # (publisher, points) Zenoh reported missed
        self._miss_listener = self.sub.sample_miss_listener(lambda m: self.misses.append((str(m.source), m.nb)))
        # device -> its publishers (in the order first heard) -> Zenoh sequence number -> point
        self._by_source: dict[str, dict[str, dict[int, wire.SegmentPoint]]] = {}
        self.filled: dict[str, int] = {}  # device -> points taken from its cache (its start, misses)

    def _take(self, sample: zenoh.Sample, source: str | None = None) -> None:
        """Keep one point (``source``: only if its publisher is this one)."""
        subject, segment, _ = wire.parse_device_key(str(sample.key_expr))
        info = sample.source_info
        if info is None or (source is not None and str(info.source_id) != source):
            return
        sources = self._by_source.setdefault(wire.device_id(subject, segment), {})
        sources.setdefault(str(info.source_id), {}).setdefault(info.source_sn, wire.decode_point(sample.payload.to_bytes()))

    def poll(self) -> dict[str, list[wire.SegmentPoint]]:
        """Every device's points received so far, in their publishers' order."""
        while (sample := self.sub.try_recv()) is not None:
            self._take(sample)
        return self.points()

    def points(self) -> dict[str, list[wire.SegmentPoint]]:
        return {d: [by_sn[sn] for by_sn in sources.values() for sn in sorted(by_sn)]
                for d, sources in self._by_source.items()}

    def ended(self, devices: int) -> bool:
        """``devices`` devices sent points and the newest of each is its stream's last."""
        points = self.poll()
        return len(points) == devices and all(p[-1].flags & wire.FLAG_FINAL for p in points.values())

    def fill_starts(self) -> dict[str, list[wire.SegmentPoint]]:
        """Ask the cache of each publisher for the points it sent that did not arrive: those before
        its first point received (a start Zenoh dropped) and those between (points Zenoh reported
        missed after a recovery query that got no reply), by Zenoh's sequence numbers, and wait for
        each query's end (``HistoryQueries`` and its refill do the same for the aggregator)."""
        self.poll()
        for device, sources in self._by_source.items():
            for source, by_sn in sources.items():
                newest = max(by_sn)
                if len(by_sn) == newest + 1:  # 0..newest all in
                    continue
                had = len(by_sn)
                subject, segment = device.split("/")
                replies = self.session.get(wire.history_selector(subject, segment, CACHE, (0, newest - 1)),
                                           zenoh.handlers.FifoChannel(CACHE), accept_replies=zenoh.ReplyKeyExpr.ANY,
                                           target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE)
                for reply in replies:  # until the query's end
                    if reply.ok is not None:
                        self._take(reply.ok, source)
                self.filled[device] = self.filled.get(device, 0) + len(by_sn) - had
        return self.points()

    def describe(self) -> str:
        """One line per publisher heard (points, sequence numbers, newest point), and Zenoh's misses."""
        lines = [f"{device} {source}: {len(by_sn)} points, sn {min(by_sn)}..{max(by_sn)}, newest {by_sn[max(by_sn)]}"
                 for device, sources in self._by_source.items() for source, by_sn in sources.items()]
        return "\n".join([*lines, f"Zenoh reported missed: {self.misses or 'none'}"])

    def close(self):
        self.session.close()
