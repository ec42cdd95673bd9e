"""The aggregator's own queries of devices' caches, for streams it joined late.

Zenoh's history for a joining subscriber brings each device's newest ``depth`` points before its
live ones, but not always (a publisher it found late, or answers late under load), and a
subject's frames begin where its devices' streams begin. So for every stream whose first point
received, in a drain, is not its start, the aggregator asks the device's cache for what is
missing of the ``depth`` points before the newest one received (Zenoh's sequence numbers: nothing
when Zenoh's history came), and the query's end, an event, settles the stream
(tests/test_history.py; docs/protocol.md).
"""
from __future__ import annotations

import zenoh

from limbstream import wire
from limbstream.services.aggregator.fusion import Fusion
from limbstream.services.aggregator.track import HISTORY_WAIT_S, DeviceTrack


class HistoryQueries:
    """History queries under way, and the streams that need one.

    Parameters
    ----------
    session : the aggregator's Zenoh session.
    fusion : where the points answered go.
    depth : points per device to ask for (the aggregator's ``history``).
    """

    def __init__(self, session: zenoh.Session, fusion: Fusion, depth: int):
        self.session, self.fusion, self.depth = session, fusion, depth
        self._due: dict[DeviceTrack, tuple[int | None, int | None]] = {}  # Zenoh sequence numbers (first, newest)
        self._replies: list = []  # (track, its stream's generation, reply channel)

    def taken(self, track: DeviceTrack, sample: zenoh.Sample | None) -> None:
        """A point of ``track`` was taken in (``sample``: the Zenoh sample that carried it, whose
        source sequence number bounds the query); a stream that wants its start is due a query."""
        if track.wants_history():
            info = sample.source_info if sample is not None else None
            first, _ = self._due.get(track, (None, None))
            sn = None if info is None else info.source_sn
            self._due[track] = (sn if first is None else first, sn)

    def ask(self) -> None:
        """Ask the caches of the streams due (after each drain)."""
        for track, (first, newest) in self._due.items():
            track.history = "asked"
            if first == 0:  # its publisher's first sample: nothing before it
                self.fusion.history_done(track)
                continue
            span = None if first is None else (newest - self.depth + 1, first - 1)
            if span is not None and span[0] > span[1]:  # Zenoh's history brought them all
                self.fusion.history_done(track)
                continue
            selector = wire.history_selector(track.subject, track.segment, self.depth, span)
            replies = self.session.get(selector, zenoh.handlers.FifoChannel(max(1024, self.depth)),
                                       accept_replies=zenoh.ReplyKeyExpr.ANY, target=zenoh.QueryTarget.ALL,
                                       consolidation=zenoh.ConsolidationMode.NONE, timeout=HISTORY_WAIT_S)
            self._replies.append((track, track.generation, replies))
        self._due.clear()

    def drain(self, now: float) -> int:
        """Take in the earlier points of late-joined streams as their queries answer; a query that
        has completed settles its stream. Returns the points taken in."""
        still_open, taken = [], 0
        for track, generation, replies in self._replies:
            try:
                while (reply := replies.try_recv()) is not None:
                    if reply.ok is not None and track.generation == generation:
                        taken += self._point(track, reply.ok.payload.to_bytes(), now)
                still_open.append((track, generation, replies))
            except zenoh.ZError:  # complete and empty
                if track.generation == generation:
                    self.fusion.history_done(track)
        self._replies = still_open
        return taken

    def _point(self, track: DeviceTrack, payload: bytes, now: float) -> bool:
        """A point from a device's cache: taken in if it is of the current stream and before
        its first point received; the rest of the cache is already here (not a drop)."""
        try:
            point = wire.decode_point(payload)
        except wire.WireError as exc:
            track.dropped[exc.reason] += 1
            return False
        return (point.stream == track.stream and track.first_seq is not None and point.seq < track.first_seq
                and self.fusion.add_point(track, point, len(payload), now))
