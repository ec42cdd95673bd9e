"""The aggregator's own queries of devices' caches, for streams it joined late.

Zenoh's history for a joining subscriber brings each device's newest ``depth`` points before its
live ones, but not always (a publisher it found late, or answers late under load), and a
subject's frames begin where its devices' streams begin. So for every stream whose first point
received, in a drain, is not its start, the aggregator asks the device's cache for what is
missing of the ``depth`` points before the newest one received (Zenoh's sequence numbers: nothing
when Zenoh's history came), and the query's end, an event, settles the stream
(tests/test_history.py; docs/protocol.md).

A device whose liveliness token comes back (its link or the router was down) is asked for the
points after the newest one received (:meth:`resume`): what it sent meanwhile and no later point
revealed, e.g. before a pause. Zenoh's own late-publisher detection would do the same, but costs
its receive threads work per sample that grows with the publishers present (docs/benchmarks.md,
"Late-publisher detection").

Points Zenoh reports missed are asked of the device's cache again the same way (:meth:`refill`):
Zenoh's own recovery query ends with no reply when the device's link is cut meanwhile, and it
never asks again, although the cache (512 points) still holds them. The aggregator asks for the
gap's sequence numbers up to REFILL_TRIES times, REFILL_RETRY_S apart, and counts as ``missed``
only what no answer brought (tests/test_refill.py).
"""
from __future__ import annotations

import collections
from dataclasses import dataclass, field

import zenoh

from limbstream import wire, zconfig
from limbstream.services.aggregator.fusion import Fusion
from limbstream.services.aggregator.track import HISTORY_WAIT_S, DeviceTrack

REFILL_TRIES = 3
"""Queries of a device's cache for the points of one gap, at most."""
REFILL_RETRY_S = 1.0
"""Time between the end of a gap's query that left points out and the next one, s (a device
whose link was cut is back within about a second: its lease)."""
MISS_WAIT_S = 1.0
"""How long a miss Zenoh reports waits, s, for the gap it belongs to before it is counted."""


@dataclass
class Refill:
    """The points of one gap of a device's stream, asked of its cache (Zenoh's sequence numbers
    ``first``..``last`` of publisher ``source``)."""

    track: DeviceTrack
    generation: int
    source: str
    first: int
    last: int
    tries: int = 0
    due: float = 0.0      # arrival clock of the next query, s
    replies: object = None  # the query under way, or None
    got: set = field(default_factory=set)  # sequence numbers answered and taken in
    resume: bool = False  # the points after the newest received, however many (none may be missing)

    def wanted(self) -> bool:
        """Whether the gap may still be filled: points are missing (a resume: nothing answered yet)."""
        return not self.got if self.resume else len(self.got) <= self.last - self.first


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
        self._refills: list[Refill] = []
        self._reported: dict[str, list[float | int]] = {}  # source -> [first report's clock, points missed]
        self._recovered: collections.Counter = collections.Counter()  # source -> points its refills brought
        self.newest: dict[str, zenoh.Sample] = {}  # point key -> the Zenoh sample of its newest point taken in

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
            replies = zconfig.ask_caches(self.session, selector, self.depth, HISTORY_WAIT_S)
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

    @property
    def refilling(self) -> bool:
        """Whether a gap's refill or a reported miss is still open (``missed`` may yet change)."""
        return bool(self._refills or self._reported)

    def gap(self, track: DeviceTrack, sample: zenoh.Sample | None, points: int, now: float) -> None:
        """A point of ``track`` (carried by ``sample``) came after a gap of ``points`` points: ask
        the device's cache for them (the Zenoh sequence numbers before the sample's)."""
        info = sample.source_info if sample is not None else None
        if info is not None and info.source_sn >= points > 0:
            self._refills.append(Refill(track, track.generation, str(info.source_id),
                                        info.source_sn - points, info.source_sn - 1, due=now))

    def resume(self, track: DeviceTrack) -> None:
        """The device of ``track`` is back online: ask its cache for the points after the newest
        one received (at most the aggregator's ``history``; the query is asked again, up to
        REFILL_TRIES times, until the device answers)."""
        sample = self.newest.get(wire.seg_key(track.subject, track.segment))
        info = sample.source_info if sample is not None else None
        if info is not None and info.source_id is not None and info.source_sn is not None:
            self._refills.append(Refill(track, track.generation, str(info.source_id), info.source_sn + 1,
                                        info.source_sn + self.depth, resume=True))

    def missed(self, source: str, points: int, now: float) -> None:
        """Zenoh reports ``points`` points of publisher ``source`` missed (counted by :meth:`settle`)."""
        reported = self._reported.setdefault(source, [now, 0])
        reported[1] += points

    def refill(self, now: float) -> int:
        """Ask the caches for the gaps due, take in what answered; returns the points taken in."""
        taken, still = 0, []
        for r in self._refills:
            if r.replies is None and now >= r.due and r.track.generation == r.generation:
                r.tries += 1
                r.replies = zconfig.ask_caches(
                    self.session, wire.history_selector(r.track.subject, r.track.segment, self.depth, (r.first, r.last)),
                    self.depth, HISTORY_WAIT_S)
            if r.replies is not None:
                taken += self._refill_replies(r, now)
            if r.track.generation == r.generation and r.wanted() and (
                    r.replies is not None or r.tries < REFILL_TRIES):
                still.append(r)
        self._refills = still
        return taken

    def _refill_replies(self, r: Refill, now: float) -> int:
        """Take in the answers of a gap's query; at its end, the next query is due REFILL_RETRY_S later."""
        taken = 0
        try:
            while (reply := r.replies.try_recv()) is not None:  # type: ignore[attr-defined]
                info = reply.ok.source_info if reply.ok is not None else None
                if (info is not None and str(info.source_id) == r.source and r.first <= info.source_sn <= r.last
                        and info.source_sn not in r.got and r.track.generation == r.generation):
                    payload = reply.ok.payload.to_bytes()
                    if self._take(r.track, payload, now, r.resume):
                        r.got.add(info.source_sn)
                        self._recovered[r.source] += 1
                        taken += 1
        except zenoh.ZError:  # complete and empty
            r.replies, r.due = None, now + REFILL_RETRY_S
        return taken

    def _take(self, track: DeviceTrack, payload: bytes, now: float, newer: bool = False) -> bool:
        """A point of a refill taken in; ``newer``: only if it is after the newest received (a
        resume's answer may repeat points that came live meanwhile: not counted as duplicates)."""
        try:
            point = wire.decode_point(payload)
        except wire.WireError as exc:
            track.dropped[exc.reason] += 1
            return False
        if newer and track.next_seq is not None and point.seq < track.next_seq:
            return False
        return point.stream == track.stream and self.fusion.add_point(track, point, len(payload), now)

    def settle(self, now: float) -> int:
        """Points Zenoh reported missed that no refill brought, once every refill of their publisher
        has ended (or none came within MISS_WAIT_S): returns them (to be counted ``missed``)."""
        busy = {r.source for r in self._refills}
        lost = 0
        for source, (since, points) in list(self._reported.items()):
            if source not in busy and (self._recovered[source] or now - since >= MISS_WAIT_S):
                lost += max(0, int(points) - self._recovered.pop(source, 0))
                del self._reported[source]
        return lost
