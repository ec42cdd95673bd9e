"""The aggregator: subscribes to every device of its subjects, rebuilds each limb by SLERP
between segment points, fuses the limbs into full-body pose frames, publishes them and the
per-device statistics.

Zenoh delivers into bounded FIFO channels (its callbacks never run our code); one loop
drains them, advances the frames of every subject, and publishes. Segment points come
through an advanced subscriber (history for late joining, recovery of missed points).
"""
from __future__ import annotations

import collections
import logging
import os
import socket
import threading
import time
from dataclasses import dataclass, field

import zenoh
import zenoh.ext as zext

from limbstream import heap, wire, zconfig
from limbstream.pacing import LoopStats as PacingStats
from limbstream.pacing import PacedLoop
from limbstream.skeleton import Skeleton
from limbstream.services.aggregator.fusion import Fusion, Subject
from limbstream.services.aggregator.track import HISTORY_WAIT_S, DeviceTrack

log = logging.getLogger("limbstream.aggregator")
STATUSES_PER_TICK = 100
"""Device status replies a tick takes in at most: a poll of 2,000 devices answers within a few
milliseconds, and decoding all of them in one tick would make it late; the rest wait a tick."""
UNSYNCED_POLL_S = 1.0
"""For RESYNC_WATCH_S after the time service (re)appears, a subject with a device that last
reported itself not synced is asked for its statuses this often instead of every config_poll_s:
the stats show the devices' resync within about a second."""
RESYNC_WATCH_S = 10.0

_POSE_KIND_BYTE = wire.POSE_DTYPE.fields["kind"][1]  # offset of a pose frame's kind in its payload


@dataclass(frozen=True)
class AggregatorSettings:
    """Tuning of one aggregator.

    Attributes
    ----------
    subjects : key-chunk patterns of the subjects this instance serves (``*`` = all), e.g. ("s0*",).
    rate : exact frame rate, Hz.
    live_rate : live frame rate, Hz (0 = none); the devices' sample rate by default.
    tick_s : loop period, seconds.
    stats_period_s : stats message period, seconds.
    history : segment points per device to ask for when joining late.
    error_window_s : angular-error window, seconds (of samples and frames at ``rate``).
    config_poll_s : how often device configs (threshold) are queried, seconds.
    trim_s : how often freed heap memory is given back to the OS, seconds (limbstream.heap).
    max_devices : most devices tracked; messages of further devices are counted and dropped.
    calibrate_on_start : calibrate each new stream from its calibration script
        (services/aggregator/calibrating.py; devices with a sensor model).
    calibration_file : where calibrations are kept, so that they outlive this process ("": not kept).
    frame_batch_s : build exact frames at most this often, seconds (0 = every tick). Every build
        covers all subjects in a few vectorised calls, so batching only trades latency for CPU.
    """

    subjects: tuple[str, ...] = ("*",)
    rate: float = 50.0
    live_rate: float = 50.0
    tick_s: float = 0.02
    stats_period_s: float = 1.0
    history: int = 512
    error_window_s: float = 60.0
    config_poll_s: float = 5.0
    trim_s: float = 5.0
    frame_batch_s: float = 0.0
    max_devices: int = 10_000
    skeleton: Skeleton = Skeleton()
    calibrate_on_start: bool = False
    calibration_file: str = ""


@dataclass
class LoopStats:
    """Counters of the aggregator itself; its loop's pacing figures in ``pacing``."""

    points: int = 0
    raw_batches: int = 0
    frames: int = 0
    missed: int = 0          # reported by Zenoh's miss detection (not recoverable)
    max_backlog: int = 0     # most messages drained in one tick
    recent_backlog: int = 0  # most messages drained in one tick since the last stats message
    pacing: PacingStats = field(default_factory=PacingStats)

    def end_round(self, now: float) -> None:
        """A stats round is out: the pacing's ``load`` over it, and the ``recent_*`` figures start over."""
        self.pacing.end_round(now)
        self.recent_backlog = 0

    def as_dict(self) -> dict:
        """The counters as published in every stats message (``"aggregator"`` entry)."""
        return self.pacing.as_dict() | {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "pacing"}


class Aggregator:
    """Aggregator state and loop. ``open()`` declares the Zenoh entities, ``run()`` loops."""

    def __init__(self, session: zenoh.Session, settings: AggregatorSettings):
        self.session, self.settings = session, settings
        self.fusion = Fusion(settings.rate, settings.skeleton, capacity=max(1024, 2 * settings.history),
                             error_window=int(settings.error_window_s * settings.rate),
                             calibrate_on_start=settings.calibrate_on_start,
                             calibration_file=settings.calibration_file)
        self.subjects: dict[str, Subject] = self.fusion.subjects
        self.bad_keys: collections.Counter = collections.Counter()
        self.stats_seq: collections.Counter = collections.Counter()  # stats messages sent, per subject
        self.loop = LoopStats()
        self._calibrating: list = []  # (query, CalibrationRequest) under way
        self._calibrate_qs: list = []
        self._pubs: dict[tuple[str, str], zenoh.Publisher] = {}  # by (key expression, zconfig.QOS kind)
        self._config_replies: list = []
        self._history_replies: list = []  # (track, its stream's generation, reply channel)
        self._history_due: dict = {}      # {track: Zenoh sequence numbers (first, newest) received}
        self._seg_subs, self._raw_subs, self._alive_subs, self._misses = [], [], [], []  # declared by open()
        self._time_service = None     # the time service's presence (a querier's matching listener)
        self.lock = threading.Lock()  # guards snapshots read by other threads (tests, tools)
        self.id = f"{socket.gethostname()}:{os.getpid()}"  # names this instance in its stats
        self._missed_unlogged, self._next_miss_log = 0, 0.0

    # ------------------------------------------------------------------ zenoh

    def open(self) -> None:
        s = self.settings
        for pattern in s.subjects:
            sub = zext.declare_advanced_subscriber(
                self.session, wire.device_selector("seg", pattern), zenoh.handlers.FifoChannel(1 << 16),
                history=zext.HistoryConfig(detect_late_publishers=True, max_samples=s.history),
                recovery=zext.RecoveryConfig(heartbeat=True),
                subscriber_detection=True,
            )
            self._seg_subs.append(sub)
            self._misses.append(sub.sample_miss_listener(zenoh.handlers.FifoChannel(1024)))
            self._raw_subs.append(zext.declare_advanced_subscriber(  # truth tap: recovered like points
                self.session, wire.device_selector("raw", pattern), zenoh.handlers.FifoChannel(1 << 14),
                history=zext.HistoryConfig(detect_late_publishers=True, max_samples=64),
                recovery=zext.RecoveryConfig(heartbeat=True), subscriber_detection=True))
            self._alive_subs.append(self.session.liveliness().declare_subscriber(
                wire.device_selector("alive", pattern), zenoh.handlers.FifoChannel(1 << 14), history=True))
            self._calibrate_qs.append(self.session.declare_queryable(
                wire.subject_selector("calibrate", pattern), zenoh.handlers.FifoChannel(256)))
        # the time service's return: devices resync at once; their stats should follow
        self._time_querier = self.session.declare_querier(wire.time_key(), allowed_destination=zenoh.Locality.REMOTE)
        self._time_service = self._time_querier.declare_matching_listener(zenoh.handlers.FifoChannel(16))

    def close(self) -> None:
        for query, _ in self._calibrating:
            with query:
                query.reply_err("the aggregator is stopping")
        self._calibrating = []
        for group in (self._misses, self._seg_subs, self._raw_subs, self._alive_subs, self._calibrate_qs):
            for entity in group:
                entity.undeclare()
        if self._time_service is not None:
            self._time_service.undeclare()
            self._time_querier.undeclare()
        for pub in self._pubs.values():
            pub.undeclare()

    # ------------------------------------------------------------------ input

    def track(self, subject: str, segment: str) -> DeviceTrack:
        return self.fusion.track(subject, segment)

    def _parse_key(self, key: str, kind: str) -> tuple[str, str] | None:
        try:
            subject, segment, got = wire.parse_device_key(key)
        except wire.WireError:
            self.bad_keys["key"] += 1
            return None
        if got != kind:
            self.bad_keys["key"] += 1
            return None
        return subject, segment

    def _known(self, subject: str, segment: str) -> DeviceTrack | None:
        sub = self.subjects.get(subject)
        return sub.tracks.get(segment) if sub is not None else None

    def _device(self, ids: tuple[str, str], kind: str, reason: str | None) -> DeviceTrack | None:
        """The track a message of ``kind`` counts against, or None (counted in ``bad_keys``).

        Undecodable messages (``reason``) of devices never seen create no track, and at most
        ``max_devices`` tracks exist: keys invented by a faulty or hostile client cannot grow
        the aggregator's memory without bound (tests/test_live_fuzz.py)."""
        track = self._known(*ids)
        if track is None:
            if reason is not None:
                self.bad_keys[f"{kind}_{reason}"] += 1
                return None
            if len(self.fusion.tracks) >= self.settings.max_devices:
                self.bad_keys["too_many_devices"] += 1
                return None
            track = self.track(*ids)
            self._ask_status(*ids)  # its settings and rest pose, before the next poll
        if reason is not None:
            track.dropped[reason if kind == "seg" else f"{kind}_{reason}"] += 1
        return track

    def on_point(self, key: str, payload: bytes, now: float, sample: zenoh.Sample | None = None) -> None:
        """A segment point message (decoded, validated, counted); ``sample``: the Zenoh sample
        that carried it (its source sequence number bounds a history query)."""
        ids = self._parse_key(key, "seg")
        if ids is None:
            return
        try:
            point = wire.decode_point(payload)
        except wire.WireError as exc:
            self._device(ids, "seg", exc.reason)
            return
        track = self._device(ids, "seg", None)
        if track is not None and self.fusion.add_point(track, point, len(payload), now):
            self.loop.points += 1
            if self.session is not None and track.wants_history():
                info = sample.source_info if sample is not None else None
                first, _ = self._history_due.get(track, (None, None))
                sn = None if info is None else info.source_sn
                self._history_due[track] = (sn if first is None else first, sn)

    def _ask_history(self) -> None:
        """Ask the caches of the devices whose streams began, as received in this drain, after
        their start, for the points before. Zenoh's history for a joining subscriber brings each
        device's newest ``history`` points before its live ones, but not always (a publisher it
        found late, or answers late under load), and a subject's frames begin where its devices'
        streams begin. So the query asks for what is missing of the ``history`` points before
        the newest one received (Zenoh's sequence numbers: nothing when Zenoh's history came),
        and its end, an event, settles the stream (tests/test_history.py)."""
        for track, (first, newest) in self._history_due.items():
            track.history = "asked"
            if first == 0:  # its publisher's first sample: nothing before it
                self.fusion.history_done(track)
                continue
            span = None if first is None else (newest - self.settings.history + 1, first - 1)
            if span is not None and span[0] > span[1]:  # Zenoh's history brought them all
                self.fusion.history_done(track)
                continue
            selector = wire.history_selector(track.subject, track.segment, self.settings.history, span)
            replies = self.session.get(selector, zenoh.handlers.FifoChannel(max(1024, self.settings.history)),
                                       accept_replies=zenoh.ReplyKeyExpr.ANY, target=zenoh.QueryTarget.ALL,
                                       consolidation=zenoh.ConsolidationMode.NONE, timeout=HISTORY_WAIT_S)
            self._history_replies.append((track, track.generation, replies))
        self._history_due.clear()

    def _drain_history(self, now: float) -> None:
        """Take in the earlier points of late-joined streams as their history queries answer;
        a query that has completed settles its stream."""
        still_open = []
        for track, generation, replies in self._history_replies:
            try:
                while (reply := replies.try_recv()) is not None:
                    if reply.ok is not None and track.generation == generation:
                        self._history_point(track, reply.ok.payload.to_bytes(), now)
                still_open.append((track, generation, replies))
            except zenoh.ZError:  # complete and empty
                if track.generation == generation:
                    self.fusion.history_done(track)
        self._history_replies = still_open

    def _history_point(self, track: DeviceTrack, payload: bytes, now: float) -> None:
        """A point from a device's cache: taken in if it is of the current stream and before
        its first point received; the rest of the cache is already here (not a drop)."""
        try:
            point = wire.decode_point(payload)
        except wire.WireError as exc:
            track.dropped[exc.reason] += 1
            return
        if (point.stream == track.stream and track.first_seq is not None and point.seq < track.first_seq
                and self.fusion.add_point(track, point, len(payload), now)):
            self.loop.points += 1

    def on_raw(self, key: str, payload: bytes, now: float) -> None:
        """A truth-tap batch."""
        ids = self._parse_key(key, "raw")
        if ids is None:
            return
        try:
            batch = wire.decode_raw(payload)
        except wire.WireError as exc:
            self._device(ids, "raw", exc.reason)
            return
        track = self._device(ids, "raw", None)
        if track is not None and self.fusion.add_raw(track, batch, now):
            self.loop.raw_batches += 1

    def on_alive(self, key: str, online: bool) -> None:
        ids = self._parse_key(key, "alive")
        if ids is not None and (track := self._device(ids, "alive", None)) is not None:
            self.fusion.set_online(track, online)

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
        track = self._known(*ids)
        if track is not None:
            self.fusion.set_config(track, status.config)
            self.fusion.set_rest_pose(track.subject, status.rest_pose)
            track.clock = status.clock
            track.link = status.link

    def drain(self, now: float, budget: int = 100_000) -> int:
        """Move everything waiting in the channels into the tracks. Returns messages handled."""
        handled = 0
        for sub in self._alive_subs:
            while (sample := sub.try_recv()) is not None:
                self.on_alive(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
                handled += 1
        for sub in self._seg_subs:
            while handled < budget and (sample := sub.try_recv()) is not None:
                self.on_point(str(sample.key_expr), sample.payload.to_bytes(), now, sample)
                handled += 1
        for sub in self._raw_subs:
            while handled < budget and (sample := sub.try_recv()) is not None:
                self.on_raw(str(sample.key_expr), sample.payload.to_bytes(), now)
                handled += 1
        self._ask_history()
        self._drain_history(now)
        for listener in self._misses:
            while (miss := listener.try_recv()) is not None:
                self.loop.missed += miss.nb
                self._missed_unlogged += miss.nb
        if self._missed_unlogged and now >= self._next_miss_log:  # at most one line per 5 s
            log.warning("zenoh reports %d segment points missed for good (%d in all)",
                        self._missed_unlogged, self.loop.missed)
            self._missed_unlogged, self._next_miss_log = 0, now + 5.0
        open_replies, statuses = [], STATUSES_PER_TICK
        for replies in self._config_replies:
            try:
                while statuses > 0 and (reply := replies.try_recv()) is not None:
                    statuses -= 1
                    if reply.ok is not None:
                        self.on_config(str(reply.ok.key_expr), reply.ok.payload.to_bytes())
                open_replies.append(replies)
            except zenoh.ZError:  # the query is complete and its channel empty
                pass
        self._config_replies = open_replies
        self.loop.max_backlog = max(self.loop.max_backlog, handled)
        self.loop.recent_backlog = max(self.loop.recent_backlog, handled)
        return handled

    def _ask_status(self, subject: str, segment: str) -> None:
        """Ask one device for its status (the answer arrives in a channel, read by drain; no
        session: an aggregator fed by hand, nothing to ask)."""
        if self.session is not None:
            self._config_replies.append(
                self.session.get(wire.config_key(subject, segment), zenoh.handlers.FifoChannel(4), timeout=2.0))

    def time_service_returned(self) -> bool:
        """Whether the time service appeared since the last call (its matching status changed)."""
        returned = False
        while self._time_service is not None and (status := self._time_service.try_recv()) is not None:
            returned |= status.matching
        return returned

    def poll_unsynced(self) -> int:
        """Ask the subjects with an online device that last said it is not synced for their
        statuses again; returns how many subjects were asked."""
        subjects = {t.subject for t in self.fusion.tracks
                    if t.online and t.clock is not None and not t.clock.synced}
        for subject in subjects:
            self._config_replies.append(self.session.get(
                wire.device_selector("config", subject), zenoh.handlers.FifoChannel(64), timeout=2.0))
        return len(subjects)

    def poll_configs(self) -> None:
        """Ask every device for its config (answers arrive in a channel, read by drain)."""
        self._config_replies += [
            self.session.get(wire.device_selector("config", pattern), zenoh.handlers.FifoChannel(4096), timeout=2.0)
            for pattern in self.settings.subjects
        ]

    # ------------------------------------------------------------------ output

    def _publish(self, subject: str, payload: bytes) -> None:
        """An encoded pose frame of ``subject``: exact and live frames share the key, not the QoS."""
        kind = "pose_live" if payload[_POSE_KIND_BYTE] == wire.KIND_LIVE else "pose_exact"
        self._publisher(wire.pose_key(subject), kind).put(payload)

    def _publisher(self, key: str, kind: str) -> zenoh.Publisher:
        """The publisher of ``key`` for messages of ``kind`` (zconfig.QOS), declared on first use."""
        pub = self._pubs.get((key, kind))
        if pub is None:
            pub = self._pubs[key, kind] = self.session.declare_publisher(key, **zconfig.publisher_options(kind))
        return pub

    def advance(self, live: bool, prune: bool = True, now: float | None = None) -> int:
        """Truth evaluation, exact frames (and live frames) of every subject; returns frames published.
        ``now``: the arrival clock of the messages (perf_counter), if time went on without any."""
        if now is not None:
            self.fusion.advance_clock(now)
        self.fusion.calibrate_ready()
        self.fusion.evaluate_truth()
        owners, frames = self.fusion.exact_frames()
        self.fusion.evaluate_frames()
        for sub, payload in zip(owners, frames.encode()):
            self._publish(sub.name, payload)
        if live:
            owners, live_frames = self.fusion.live_frames(self.fusion.clock if now is None else now, time.time())
            for sub, payload in zip(owners, live_frames.encode()):
                self._publish(sub.name, payload)
        if prune:
            self.fusion.prune()
        self.loop.frames += len(frames)
        return len(frames)

    def serve_calibrations(self) -> None:
        """Take calibration requests in; answer those whose pose hold is complete (each tick)."""
        wall = time.time()
        for queryable in self._calibrate_qs:
            while (query := queryable.try_recv()) is not None:
                payload = query.payload.to_bytes() if query.payload is not None else b""
                try:
                    subject, _ = wire.parse_subject_key(str(query.key_expr))
                    req = self.fusion.start_request(subject, wire.decode_calibrate_request(payload), wall)
                except (wire.WireError, ValueError) as exc:
                    with query:
                        query.reply_err(str(exc))
                    continue
                if isinstance(req, str):
                    self._answer(query, wire.CalibrateAnswer(False, req))
                else:
                    self._calibrating.append((query, req))
        still = []
        for query, req in self._calibrating:
            answer = self.fusion.finish_request(req, wall)
            if answer is None:
                still.append((query, req))
            else:
                self._answer(query, answer)
        self._calibrating = still

    @staticmethod
    def _answer(query, answer: wire.CalibrateAnswer) -> None:
        with query:
            query.reply(query.key_expr, wire.encode_calibrate_answer(answer))

    def subject_stats(self, subject: str, now: float) -> dict:
        sub = self.subjects[subject]
        frame_aad, frames_compared = self.fusion.frame_error(sub)
        return {
            "devices": self.fusion.device_stats(sub, now),
            "frames": sub.frames,
            "skipped_frames": sub.skipped,
            "watermark_us": self.fusion.watermark(sub),
            "frame_aad_deg": frame_aad,
            "frame_error_frames": frames_compared,
            "facing_deg": self.fusion.facing_deg(sub),
        }

    def publish_stats(self, now: float, part: int = 0, parts: int = 1) -> None:
        """Stats of the subjects whose index % ``parts`` == ``part`` (all by default); the loop
        spreads one round over the ticks of a stats period so that no tick carries them all."""
        wall = time.time()
        for sub in list(self.subjects.values()):
            if sub.index % parts != part:
                continue
            snapshot = self.subject_stats(sub.name, now)
            devices = snapshot.pop("devices")
            # load / soak figures (bench/soak.py) and messages no device could be charged with
            snapshot["aggregator"] = {"id": self.id, "subjects": len(self.subjects)} | self.loop.as_dict() | {
                "bad_keys": dict(self.bad_keys)}
            payload = wire.encode_stats(sub.name, wall, devices, snapshot, seq=self.stats_seq[sub.name])
            self._publisher(wire.stats_key(sub.name), "stats").put(payload)
            self.stats_seq[sub.name] += 1
        if part == parts - 1:
            self.loop.end_round(now)

    # ------------------------------------------------------------------ loop

    def run(self, stop: threading.Event) -> LoopStats:
        """Loop until ``stop``: drain, advance frames every tick, stats about once a second."""
        s = self.settings
        start = time.perf_counter()
        next_live = next_config = next_frames = next_prune = next_trim = start
        next_unsynced = start + UNSYNCED_POLL_S
        watch_until = start  # the stats follow devices resyncing until then
        stats_parts = max(1, round(s.stats_period_s / s.tick_s))  # one stats round per period

        def tick(k: int, now: float) -> None:
            nonlocal next_live, next_config, next_frames, next_prune, next_trim, next_unsynced, watch_until
            with self.lock:
                self.drain(now)
                live = s.live_rate > 0 and now >= next_live
                if live:  # on a fixed schedule (no drift); after a stall, from now on
                    next_live += 1.0 / s.live_rate
                    if next_live <= now:
                        next_live = now + 1.0 / s.live_rate
                if live or now >= next_frames:
                    prune = now >= next_prune
                    self.advance(live, prune, now)
                    next_frames = now + s.frame_batch_s
                    next_prune = now + 0.5 if prune else next_prune
                self.publish_stats(now, k % stats_parts, stats_parts)
                self.serve_calibrations()
            if now >= next_config:
                self.poll_configs()
                next_config = now + s.config_poll_s
                next_unsynced = now + UNSYNCED_POLL_S
            elif now >= next_unsynced:
                if self.time_service_returned():
                    watch_until = now + RESYNC_WATCH_S
                if now < watch_until:
                    self.poll_unsynced()
                next_unsynced = now + UNSYNCED_POLL_S
            elif now >= next_trim:
                heap.release_free_heap()
                next_trim = now + s.trim_s

        PacedLoop(s.tick_s, stats=self.loop.pacing).run(stop, tick)
        return self.loop


def snapshot(aggregator: Aggregator) -> dict:
    """{device id: stats} of every device, taken under the aggregator's lock (tests and tools)."""
    now = time.perf_counter()
    with aggregator.lock:
        return {d["device"]: d for sub in aggregator.subjects.values()
                for d in aggregator.fusion.device_stats(sub, now)}

