"""The aggregator's input: device messages checked and taken into the fusion.

Every message's key names its device; a key never seen is checked (its grammar and kind) and its
device made, at most ``max_devices`` of them. Segment points and truth batches of a drain are
decoded together (``wire.decode_points``, ``wire.decode_raws``) and taken in as one batch each
(a subject's truth-tap message is split into its devices' batches first, ``wire.truth_batches``);
an undecodable message is counted against its device (or, for a device never seen, in
``bad_keys``) and dropped (the reasons: ``wire.POINT_DROPS``, ``wire.RAW_DROPS``, ``wire.UNCHARGED``).
"""
from __future__ import annotations

import collections
from collections.abc import Callable

import zenoh

from limbstream import wire
from limbstream.services.aggregator.fusion import Fusion
from limbstream.services.aggregator.history import HistoryQueries
from limbstream.services.aggregator.track import DeviceTrack


class Intake:
    """Device messages into ``fusion``.

    Parameters
    ----------
    fusion : where the devices' data goes.
    counters : the aggregator's loop counters (``points`` and ``raw_batches`` taken in).
    max_devices : most devices tracked; messages of further devices are counted and dropped.
    ask_status : asks a device (subject, segment) for its status when it is first seen.
    history : the history queries of late-joined streams (None: none are made).
    declare : called with each key a device's (or a subject's truth) messages come on, once: the
        aggregator declares it to Zenoh, so that Zenoh routes the messages on it from a cache
        (docs/benchmarks.md, "Keys declared").
    """

    def __init__(self, fusion: Fusion, counters, max_devices: int, ask_status: Callable[[str, str], None],
                 history: HistoryQueries | None, declare: Callable[[str], None] = lambda key: None):
        self.fusion, self.counters, self.max_devices = fusion, counters, max_devices
        self.ask_status, self.history, self.declare = ask_status, history, declare
        self._truth_keys: set[str] = set()  # subject truth keys seen (declared)
        self.bad_keys: collections.Counter = collections.Counter()  # messages no device could be charged with
        self._seg_tracks: dict[str, DeviceTrack] = {}  # by segment point key, once a point came
        self._raw_tracks: dict[str, DeviceTrack] = {}  # by truth-tap key, once a batch came

    def _parse_key(self, key: str, kind: str) -> tuple[str, str] | None:
        """(subject, segment) of a device key of ``kind``, or None (counted in ``bad_keys``)."""
        try:
            subject, segment, got = wire.parse_device_key(key)
        except wire.WireError:
            self.bad_keys["key"] += 1
            return None
        if got != kind:
            self.bad_keys["key"] += 1
            return None
        return subject, segment

    def known(self, subject: str, segment: str) -> DeviceTrack | None:
        """The track of a device seen, or None."""
        sub = self.fusion.subjects.get(subject)
        return sub.tracks.get(segment) if sub is not None else None

    def _device(self, ids: tuple[str, str], kind: str, reason: str | None) -> DeviceTrack | None:
        """The track a message of ``kind`` counts against, or None (counted in ``bad_keys``).

        Undecodable messages (``reason``) of devices never seen create no track, and at most
        ``max_devices`` tracks exist: keys invented by a faulty or hostile client cannot grow
        the aggregator's memory without bound (tests/test_live_fuzz.py)."""
        track = self.known(*ids)
        if track is None:
            if reason is not None:
                self.bad_keys[wire.undecodable(kind)] += 1
                return None
            if len(self.fusion.tracks) >= self.max_devices:
                self.bad_keys["too_many_devices"] += 1
                return None
            track = self.fusion.track(*ids)
            self.ask_status(*ids)  # its settings and rest pose, before the next poll
        if reason is not None:
            track.dropped[wire.device_reason(kind, reason)] += 1
        return track

    def take_points(self, keys: list[str], payloads: list[bytes], now: float,
                    samples: list[zenoh.Sample | None] | None = None) -> None:
        """The segment point messages of one drain, in arrival order (keys, payloads and the Zenoh
        samples that carried them: their source sequence numbers bound history queries): decoded
        together, counted and dropped per device where invalid, the rest taken in as one batch."""
        points = wire.decode_points(payloads)
        items = self._items(keys, points.reason, "seg", self._seg_tracks)
        history = self.history
        taken = gapped = None
        if history is not None:
            if samples:  # (only devices tracked: a key invented by a faulty client is not kept)
                history.newest.update((keys[i], samples[i]) for _, i in items)

            def taken(track, i):
                history.taken(track, samples[i] if samples else None)

            def gapped(track, i, missing):
                history.gap(track, samples[i] if samples else None, missing, now)
        self.counters.points += self.fusion.add_points(items, points, now, taken, gapped)

    def take_raw(self, keys: list[str], payloads: list[bytes], now: float) -> None:
        """The truth-tap messages of one drain, in arrival order: decoded together, counted and
        dropped per device where invalid, the rest taken in as one batch."""
        batches = wire.decode_raws(payloads)
        items = self._items(keys, batches.reason, "raw", self._raw_tracks)
        self.counters.raw_batches += self.fusion.add_raws(items, batches, now)

    def take_truth(self, keys: list[str], payloads: list[bytes], now: float,
                   raw_keys: list[str] | None = None, raw_payloads: list[bytes] | None = None) -> None:
        """The subject truth-tap messages of one drain (and its device truth-tap messages, taken
        in first): each split into the device batches it holds, then all taken in as
        :meth:`take_raw` takes a device's. A message that does not split is counted in
        ``bad_keys`` (``truth_<reason>``, ``key``) and dropped."""
        keys_in, payloads_in = list(raw_keys or ()), list(raw_payloads or ())
        for key, payload in zip(keys, payloads):
            try:
                batches = wire.truth_batches(key, payload)
            except wire.WireError as exc:
                self.bad_keys["key" if exc.reason == "key" else wire.truth_reason(exc.reason)] += 1
                continue
            if key not in self._truth_keys and len(self._truth_keys) < self.max_devices:
                self._truth_keys.add(key)
                self.declare(key)
            for device_key, batch in batches:
                keys_in.append(device_key)
                payloads_in.append(batch)
        if keys_in:
            self.take_raw(keys_in, payloads_in, now)

    def _items(self, keys: list[str], reasons: list, kind: str, known: dict[str, DeviceTrack]) -> list:
        """(track, row) of each message of ``kind`` (``seg``, ``raw``) that decoded (``reasons[row]``
        None), in order; an undecodable one is counted against its device, a key never seen is
        checked and its device found or made (``known``: tracks by key, kept)."""
        tracks = list(map(known.get, keys))
        if reasons.count(None) == len(reasons) and tracks.count(None) == 0:  # (a drain's usual: all known and valid)
            return list(zip(tracks, range(len(keys))))
        items = []
        for i, key in enumerate(keys):
            track = known.get(key)
            reason = reasons[i]
            if track is None:
                ids = self._parse_key(key, kind)
                track = None if ids is None else self._device(ids, kind, reason)
                if track is None or reason is not None:
                    continue
                known[key] = track
                self.declare(key)
            elif reason is not None:
                track.dropped[wire.device_reason(kind, reason)] += 1
                continue
            items.append((track, i))
        return items

    def on_alive(self, key: str, online: bool) -> None:
        ids = self._parse_key(key, "alive")
        if ids is not None and (track := self._device(ids, "alive", None)) is not None:
            self.fusion.set_online(track, online)
            if online and self.history is not None:
                self.history.resume(track)

    def on_config(self, key: str, payload: bytes) -> None:
        """A device's config reply (its status): the settings it runs."""
        ids = self._parse_key(key, "config")
        if ids is None:
            return
        try:
            status = wire.decode_status(payload)
        except wire.WireError:
            self.bad_keys["config_reply"] += 1
            return
        track = self.known(*ids)
        if track is not None:
            self.fusion.set_config(track, status.config)
            self.fusion.set_rest_pose(track.subject, status.rest_pose)
            self.fusion.set_body(track, status.body, status.body_error)
            track.clock = status.clock
            track.link = status.link
            track.fusion = status.fusion
            track.orientations = status.orientations
