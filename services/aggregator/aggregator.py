"""The aggregator: subscribes to every device of its subjects, rebuilds each limb by SLERP
between segment points, fuses the limbs into full-body pose frames, publishes them and the
per-device statistics.

Zenoh delivers into bounded FIFO channels (its callbacks never run our code); one loop
drains them, advances the frames of every subject, and publishes. Segment points come
through an advanced subscriber (history for late joining, recovery of missed points; a device
back online is asked for what it sent meanwhile: ``HistoryQueries.resume``); a tick's
points are decoded together and taken in as one batch.
"""
from __future__ import annotations

import collections
import logging
import os
import socket
import threading
import time

import numpy as np
import zenoh
import zenoh.ext as zext

from limbstream import heap, wire, zconfig
from limbstream.pacing import Deadlines, PacedLoop
from limbstream.services.aggregator.angles import JointStage
from limbstream.services.aggregator.devices import NO_TIME
from limbstream.services.aggregator.frames import FrameBatch, FrameStage
from limbstream.services.aggregator.fusion import Fusion, Subject
from limbstream.services.aggregator.history import HistoryQueries
from limbstream.services.aggregator.intake import Intake
from limbstream.services.aggregator.settings import AggregatorCounters, AggregatorSettings
from limbstream.services.aggregator.track import DeviceTrack

log = logging.getLogger("limbstream.aggregator")
STATUSES_PER_TICK = 100
"""Device status replies a tick takes in at most: a poll of 2,000 devices answers within a few
milliseconds, and decoding all of them in one tick would make it late; the rest wait a tick."""
UNSYNCED_POLL_S = 1.0
"""For RESYNC_WATCH_S after the time service (re)appears, a subject with a device that last
reported itself not synced is asked for its statuses this often instead of every config_poll_s:
the stats show the devices' resync within about a second."""
RESYNC_WATCH_S = 10.0
STATS_BATCHES = 10
"""A stats period's messages (one per subject) go out in this many batches, a tick each: often
enough that no tick carries them all, few enough that each batch's figures are computed for many
devices at once."""
ALIVE_WAIT_S = 5.0
"""How long opening waits, at most, for the router's answer of the liveliness tokens present, s."""

MATCH_WAIT_S = 2.0
"""Frames on a key whose publisher was declared less than this ago are sent whether or not a
subscriber is known to match: the router tells a new publisher of its subscribers within
milliseconds, but a restarted aggregator's first frames (its devices' history) go out at once."""

_HEARD_KINDS = frozenset({"pose_exact", "pose_live", wire.ANGLES})
"""The kinds (zconfig.QOS) of messages sent only while a subscriber hears them (:meth:`Aggregator.heard`)."""
_POSE_KIND_BYTE = wire.POSE_DTYPE.fields["kind"][1]  # offset of a pose frame's kind in its payload


class Aggregator:
    """Aggregator state and loop. ``open()`` declares the Zenoh entities, ``run()`` loops."""

    def __init__(self, session: zenoh.Session, settings: AggregatorSettings):
        self.session, self.settings = session, settings
        self.fusion = Fusion(settings.rate, settings.skeleton, capacity=max(1024, 2 * settings.history),
                             error_window=int(settings.error_window_s * settings.rate),
                             calibrate_on_start=settings.calibrate_on_start,
                             calibration_file=settings.calibration_file,
                             heading_correction=settings.heading_correction)
        self.subjects: dict[str, Subject] = self.fusion.subjects
        self.stats_seq: collections.Counter = collections.Counter()  # stats messages sent, per subject
        self.loop = AggregatorCounters()
        self._calibrating: list = []  # (query, CalibrationRequest) under way
        self._calibrate_qs: list = []
        self._pubs: dict[tuple[str, str], zenoh.Publisher] = {}  # by (key expression, zconfig.QOS kind)
        self._matching: list = []  # a matching listener per publisher of frames, kept while it is
        self._heard: set[str] = set()  # the frame keys some subscriber matches now (set by those listeners)
        self._asking: dict[str, float] = {}  # per frame key: until when it is sent unheard (MATCH_WAIT_S), monotonic s
        self._pose_keys: list[str] = []  # each subject's pose key, in the order of ``subjects``
        self._pose_pubs: dict[tuple[str, str], zenoh.Publisher] = {}  # by (subject, zconfig.QOS kind)
        self._config_replies: list = []
        self.history = None if session is None else HistoryQueries(session, self.fusion, settings.history)
        self._declared: list[zenoh.KeyExpr] = []  # the keys devices' messages come on, declared to Zenoh
        self.intake = Intake(self.fusion, self.loop, settings.max_devices, self._ask_status, self.history,
                             self._declare_key)
        self.bad_keys = self.intake.bad_keys
        self.frame_stages: list[FrameStage] = []  # work on each tick's frames before they are encoded
        if settings.joint_angles:
            self.frame_stages.append(JointStage(self.fusion, live=settings.live_rate > 0, unheard=self.unheard))
        self._last_stats: dict[str, bytes] = {}  # each subject's newest stats message
        self._seg_subs, self._raw_subs, self._alive_subs, self._misses = [], [], [], []  # declared by open()
        self._truth_subs: list = []  # subjects' truth taps (per-device ones: _raw_subs)
        self._stats_qs: list = []
        self._time_service = None     # the time service's presence (a querier's matching listener)
        self.lock = threading.Lock()  # guards snapshots read by other threads (tests, tools)
        self.id = f"{socket.gethostname()}:{os.getpid()}"  # names this instance in its stats
        self._missed_unlogged, self._next_miss_log = 0, 0.0

    # ------------------------------------------------------------------ zenoh

    def open(self) -> None:
        """Declare the aggregator's subscribers and queryables. The devices present are known
        (online) before any of their points is taken in: their liveliness tokens are asked for
        first, and only then are the points subscribed (with a liveliness subscriber's history
        instead, a point's history often came first, and the first stats and frames called
        streaming devices offline). The subscriber, declared before the question, brings every
        change after it (with history, it would also keep the question from being answered)."""
        s = self.settings
        for pattern in s.subjects:
            selector = wire.device_selector(wire.ALIVE, pattern)
            self._alive_subs.append(self.session.liveliness().declare_subscriber(
                selector, zenoh.handlers.FifoChannel(1 << 14)))
            for reply in self.session.liveliness().get(selector, timeout=ALIVE_WAIT_S):
                if reply.ok is not None:
                    self.on_alive(str(reply.ok.key_expr), True)
        for pattern in s.subjects:
            sub = zext.declare_advanced_subscriber(
                self.session, wire.device_selector(wire.SEG, pattern), zenoh.handlers.FifoChannel(1 << 16),
                history=zext.HistoryConfig(max_samples=s.history),
                recovery=zext.RecoveryConfig(heartbeat=True),
                subscriber_detection=True,
            )
            self._seg_subs.append(sub)
            self._misses.append(sub.sample_miss_listener(zenoh.handlers.FifoChannel(1024)))
            for selector, subs in ((wire.device_selector(wire.RAW, pattern), self._raw_subs),  # truth tap: recovered
                                   (wire.subject_selector(wire.TRUTH, pattern), self._truth_subs)):  # like points
                subs.append(zext.declare_advanced_subscriber(
                    self.session, selector, zenoh.handlers.FifoChannel(1 << 14),
                    history=zext.HistoryConfig(max_samples=64),
                    recovery=zext.RecoveryConfig(heartbeat=True), subscriber_detection=True))
            self._calibrate_qs.append(self.session.declare_queryable(
                wire.subject_selector(wire.CALIBRATE, pattern), zenoh.handlers.FifoChannel(256)))
            self._stats_qs.append(self.session.declare_queryable(  # the stats as JSON, on request
                wire.subject_selector(wire.STATS, pattern), zenoh.handlers.FifoChannel(256)))
        # the time service's return: devices resync at once; their stats should follow
        self._time_querier = self.session.declare_querier(wire.time_key(), allowed_destination=zenoh.Locality.REMOTE)
        self._time_service = self._time_querier.declare_matching_listener(zenoh.handlers.FifoChannel(16))

    def close(self) -> None:
        for query, _ in self._calibrating:
            with query:
                query.reply_err("the aggregator is stopping")
        self._calibrating = []
        for group in (self._misses, self._seg_subs, self._raw_subs, self._truth_subs, self._alive_subs, self._calibrate_qs,
                      self._stats_qs):
            for entity in group:
                entity.undeclare()
        for key in self._declared:
            self.session.undeclare(key)
        self._declared = []
        if self._time_service is not None:
            self._time_service.undeclare()
            self._time_querier.undeclare()
        for listener in self._matching:
            listener.undeclare()
        self._matching = []
        for pub in self._pubs.values():
            pub.undeclare()

    # ------------------------------------------------------------------ input

    def track(self, subject: str, segment: str) -> DeviceTrack:
        return self.fusion.track(subject, segment)

    def known(self, subject: str, segment: str) -> DeviceTrack | None:
        """The track of a device seen, or None."""
        return self.intake.known(subject, segment)

    def on_point(self, key: str, payload: bytes, now: float, sample: zenoh.Sample | None = None) -> None:
        """One segment point message (a drain of one; ``sample``: the Zenoh sample that carried it)."""
        self.intake.take_points([key], [payload], now, [sample])

    def take_points(self, keys: list[str], payloads: list[bytes], now: float) -> None:
        """A drain's segment point messages (Intake.take_points)."""
        self.intake.take_points(keys, payloads, now)

    def on_raw(self, key: str, payload: bytes, now: float) -> None:
        """One truth-tap message (a drain of one)."""
        self.intake.take_raw([key], [payload], now)

    def take_raw(self, keys: list[str], payloads: list[bytes], now: float) -> None:
        """A drain's truth-tap messages (Intake.take_raw)."""
        self.intake.take_raw(keys, payloads, now)

    def on_truth(self, key: str, payload: bytes, now: float) -> None:
        """One subject truth-tap message (a drain of one)."""
        self.intake.take_truth([key], [payload], now)

    def _declare_key(self, key: str) -> None:
        """Declare ``key`` (a device's or a subject's, its first message just taken in) to Zenoh:
        a message on a key the session has not declared is routed by matching it against every
        key expression the session knows, each time (Zenoh's ``Resource::get_matches``: half of a
        core at 2,000 devices); on a declared one, from the routes Zenoh keeps for it."""
        if self.session is not None:
            self._declared.append(self.session.declare_keyexpr(key))

    def on_alive(self, key: str, online: bool) -> None:
        """A device's liveliness token appeared or vanished."""
        self.intake.on_alive(key, online)

    def on_config(self, key: str, payload: bytes) -> None:
        """A device's config reply (its status)."""
        self.intake.on_config(key, payload)

    def drain(self, now: float, budget: int = 100_000) -> int:
        """Move everything waiting in the channels into the tracks. Returns messages handled."""
        handled = 0
        for sub in self._alive_subs:
            while (sample := sub.try_recv()) is not None:
                self.on_alive(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
                handled += 1
        keys, payloads, samples = self._receive(self._seg_subs, budget - handled)
        handled += len(keys)
        if keys:
            self.intake.take_points(keys, payloads, now, samples)
        keys, payloads, _ = self._receive(self._raw_subs, budget - handled)
        truth_keys, truth_payloads, _ = self._receive(self._truth_subs, budget - handled - len(keys))
        handled += len(keys) + len(truth_keys)
        if truth_keys:
            self.intake.take_truth(truth_keys, truth_payloads, now, keys, payloads)
        elif keys:
            self.intake.take_raw(keys, payloads, now)
        if self.history is not None:
            self.history.ask()
            self.loop.points += self.history.drain(now) + self.history.refill(now)
        self._count_misses(now)
        self._take_statuses()
        self.loop.max_backlog = max(self.loop.max_backlog, handled)
        self.loop.recent_backlog = max(self.loop.recent_backlog, handled)
        return handled

    @staticmethod
    def _receive(subscribers: list, budget: int) -> tuple[list[str], list[bytes], list[zenoh.Sample]]:
        """(keys, payloads, samples) of at most ``budget`` messages waiting in ``subscribers``."""
        keys: list[str] = []
        payloads: list[bytes] = []
        samples: list[zenoh.Sample] = []
        for sub in subscribers:
            while len(keys) < budget and (sample := sub.try_recv()) is not None:
                keys.append(str(sample.key_expr))
                payloads.append(sample.payload.to_bytes())
                samples.append(sample)
        return keys, payloads, samples

    def _count_misses(self, now: float) -> None:
        """Points Zenoh's miss detection reports lost that the device's cache could not give again
        either (HistoryQueries.refill; without a session, as reported): counted, logged at most
        every 5 s."""
        lost = 0
        for listener in self._misses:
            while (miss := listener.try_recv()) is not None:
                if self.history is None:
                    lost += miss.nb
                else:
                    self.history.missed(str(miss.source), miss.nb, now)
        if self.history is not None:
            lost += self.history.settle(now)
        self.loop.missed += lost
        self._missed_unlogged += lost
        if self._missed_unlogged and now >= self._next_miss_log:
            log.warning("zenoh reports %d segment points missed for good (%d in all)",
                        self._missed_unlogged, self.loop.missed)
            self._missed_unlogged, self._next_miss_log = 0, now + 5.0

    def _take_statuses(self) -> None:
        """Device statuses that answered a config query, at most STATUSES_PER_TICK."""
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
                wire.device_selector(wire.CONFIG, subject), zenoh.handlers.FifoChannel(64), timeout=2.0))
        return len(subjects)

    def poll_configs(self) -> None:
        """Ask every device for its config (answers arrive in a channel, read by drain)."""
        self._config_replies += [
            self.session.get(wire.device_selector(wire.CONFIG, pattern), zenoh.handlers.FifoChannel(4096), timeout=2.0)
            for pattern in self.settings.subjects
        ]

    # ------------------------------------------------------------------ output

    def _publish(self, subject: str, payload: bytes) -> None:
        """An encoded pose frame of ``subject``: exact and live frames share the key, not the QoS."""
        self._pose_publisher(subject, "pose_live" if payload[_POSE_KIND_BYTE] == wire.KIND_LIVE else "pose_exact").put(payload)

    def _pose_publisher(self, subject: str, kind: str) -> zenoh.Publisher:
        """The publisher of ``subject``'s pose frames of ``kind`` (``pose_exact``, ``pose_live``),
        declared on first use (with a matching listener: :meth:`heard`)."""
        pub = self._pose_pubs.get((subject, kind))
        if pub is None:
            pub = self._pose_pubs[subject, kind] = self._publisher(wire.pose_key(subject), kind)
        return pub

    def heard(self, key: str, kind: str) -> bool:
        """Whether a subscriber matches the frames' ``key`` now (its publisher of ``kind`` declared
        with a matching listener on first ask), or may: within MATCH_WAIT_S of that, before the
        router's answer is sure to be in; always, without a session. Frames no subscriber matches
        are made (roots, scores and facing go on) but not encoded or sent (docs/protocol.md,
        "Pose frame")."""
        if self.session is None or key in self._heard:
            return True
        self._publisher(key, kind)
        return time.monotonic() < self._asking[key]

    def unheard(self, keys: list[str], owners: list[int], kind: str) -> list[int]:
        """Which frames of subjects ``owners`` (their keys ``keys[owner]``) no subscriber matches
        (:meth:`heard`), by position in ``owners``: a set lookup each (most ticks, none)."""
        if self.session is None:
            return []
        heard = self._heard
        return [j for j, i in enumerate(owners) if keys[i] not in heard and not self.heard(keys[i], kind)]

    def _put(self, key: str, kind: str, payload: bytes) -> None:
        """A frame stage's message (no session: an aggregator fed by hand, whose caller takes
        what it wants by replacing this)."""
        if self.session is not None:
            self._publisher(key, kind).put(payload)

    def _publish_stats(self, subject: str, payload: bytes) -> None:
        self._publisher(wire.stats_key(subject), "stats").put(payload)

    def _publisher(self, key: str, kind: str) -> zenoh.Publisher:
        """The publisher of ``key`` for messages of ``kind`` (zconfig.QOS), declared on first use;
        one of frames (_HEARD_KINDS) with a matching listener that keeps ``key`` in ``_heard`` while
        a subscriber matches it (called on a Zenoh thread, at once if one does: a set's add and
        discard only)."""
        pub = self._pubs.get((key, kind))
        if pub is None:
            pub = self._pubs[key, kind] = self.session.declare_publisher(key, **zconfig.publisher_options(kind))
            if kind in _HEARD_KINDS:
                heard = self._heard
                self._asking.setdefault(key, time.monotonic() + MATCH_WAIT_S)
                self._matching.append(pub.declare_matching_listener(
                    lambda status: heard.add(key) if status.matching else heard.discard(key)))
        return pub

    def advance(self, live: bool, prune: bool = True, now: float | None = None, wall: float | None = None) -> int:
        """Truth evaluation, exact frames (and live frames) of every subject; returns frames published.
        ``now``: the arrival clock of the messages (perf_counter), if time went on without any;
        ``wall``: the publication time of live frames (s since the epoch; default: the clock's)."""
        if now is not None:
            self.fusion.advance_clock(now)
        batch = self.fusion.tick(live, now, time.time() if wall is None else wall)
        self._publish_frames(batch)
        if prune:
            self.fusion.prune()
        self.loop.frames += len(batch.exact_owner)
        return len(batch.exact_owner)

    def _publish_frames(self, batch: FrameBatch) -> None:
        """A tick's frames, per subject exact ones first (each subject's in its layout), and what
        the frame stages make of them."""
        for stage in self.frame_stages:
            for key, kind, payload in stage(batch):
                self._put(key, kind, payload)
        names = list(self.subjects)
        keys = self._pose_keys
        keys += [wire.pose_key(name) for name in names[len(keys):]]
        for group in batch.exact + batch.live:  # one batch per layout and kind
            kind = "pose_live" if group.frames.kind == wire.KIND_LIVE else "pose_exact"
            owners = group.owner.tolist()
            unheard = self.unheard(keys, owners, kind)
            if unheard:
                rows = np.delete(np.arange(len(owners)), unheard)
                self.loop.unheard += len(unheard)
                owners, frames = [owners[r] for r in rows], group.frames.rows(rows)
            else:
                frames = group.frames
            for i, payload in zip(owners, frames.encode()):
                self._publish(names[i], payload)

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
        """The figures of a subject's stats message: ``devices`` (its device entries) and the
        subject fields."""
        sub = self.subjects[subject]
        return {"devices": self.fusion.device_stats([sub], now)[0]} | self._subject_fields([sub])[0]

    def _subject_fields(self, subjects: list[Subject]) -> list[dict]:
        """The subject fields of the subjects' stats messages."""
        view = self.fusion.device_view()
        scores = self.fusion.scoring.subject_figures([sub.index for sub in subjects])
        frames = self.fusion.frames
        return [{"frames": int(frames.made[sub.index]), "skipped_frames": int(frames.skipped[sub.index]),
                 "live_missed": int(frames.live_missed[sub.index]),
                 "watermark_us": None if view.watermark[sub.index] == NO_TIME else int(view.watermark[sub.index]),
                 "frame_aad_deg": aad, "joint_aad_deg": joints, "frame_error_frames": compared, "facing_deg": facing,
                 "heading_contradicted": self.fusion.heading.contradicted(sub.index, sub.name)}
                | self.fusion.layouts.fields(sub) for sub, (aad, compared, facing, joints) in zip(subjects, scores)]

    def publish_stats(self, now: float, part: int = 0, parts: int = 1, wall: float | None = None) -> None:
        """Stats of the subjects whose index % ``parts`` == ``part`` (all by default); the loop
        spreads one round over the ticks of a stats period so that no tick carries them all.
        ``wall``: their send time (s since the epoch; default: the clock's)."""
        wall = time.time() if wall is None else wall
        # load / soak figures (bench/soak.py) and messages no device could be charged with
        loop = {"id": self.id, "subjects": len(self.subjects)} | self.loop.as_dict() | {"bad_keys": dict(self.bad_keys)}
        subjects = list(self.subjects.values())[part::parts]
        counts, numbers, texts = self.fusion.stats_table(subjects, now)
        start = 0
        for sub, n, fields in zip(subjects, counts, self._subject_fields(subjects)):
            mine = {name: values[start:start + n] for name, values in texts.items()}
            payload = wire.encode_stats_table(sub.name, wall, numbers[start:start + n], mine, fields | {"aggregator": loop},
                                              self.stats_seq[sub.name])
            start += n
            self._publish_stats(sub.name, payload)
            self._last_stats[sub.name] = payload
            self.stats_seq[sub.name] += 1
        if part == parts - 1:
            self.loop.end_round(now)

    def serve_stats_queries(self) -> None:
        """Answer queries of stats keys with the newest stats message of each subject they match,
        as JSON (wire.stats_json: the form for clients that ask for it)."""
        for queryable in self._stats_qs:
            while (query := queryable.try_recv()) is not None:
                with query:
                    for subject, payload in self._last_stats.items():
                        key = wire.stats_key(subject)
                        if query.key_expr.intersects(zenoh.KeyExpr(key)):
                            query.reply(key, wire.stats_json(payload))

    # ------------------------------------------------------------------ loop

    def run(self, stop: threading.Event) -> AggregatorCounters:
        """Loop until ``stop``: drain, advance frames every tick (a live frame per live deadline:
        ``pacing.Deadlines``, those missed counted per subject), stats about once a second."""
        s = self.settings
        tick_s = min(s.tick_s, 1.0 / s.live_rate) if s.live_rate > 0 else s.tick_s
        start = time.perf_counter()
        next_config = next_frames = next_prune = next_trim = start
        next_unsynced = start + UNSYNCED_POLL_S
        watch_until = start  # the stats follow devices resyncing until then
        ticks = max(1, round(s.stats_period_s / tick_s))  # a stats round per period, in batches
        stats_parts = min(STATS_BATCHES, ticks)
        stats_every = ticks // stats_parts
        deadlines = Deadlines(1.0 / s.live_rate, start) if s.live_rate > 0 else None

        def tick(k: int, now: float) -> None:
            nonlocal next_config, next_frames, next_prune, next_trim, next_unsynced, watch_until
            with self.lock:
                now = time.perf_counter()  # (the lock may have kept the tick waiting: arrivals at the drain)
                self.drain(now)
                live, missed = (False, 0) if deadlines is None else deadlines.due(now)
                if missed:
                    self.fusion.frames.miss_live(missed)
                if live or now >= next_frames:
                    prune = now >= next_prune
                    self.advance(live, prune, now)
                    next_frames = now + s.frame_batch_s
                    next_prune = now + 0.5 if prune else next_prune
                if k % stats_every == 0:
                    self.publish_stats(now, k // stats_every % stats_parts, stats_parts)
                self.serve_calibrations()
                self.serve_stats_queries()
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

        PacedLoop(tick_s, stats=self.loop.pacing).run(stop, tick, start=start)
        return self.loop


def snapshot(aggregator: Aggregator) -> dict:
    """{device id: stats} of every device, taken under the aggregator's lock (tests and tools)."""
    now = time.perf_counter()
    with aggregator.lock:
        return {d["device"]: d for devices in aggregator.fusion.device_stats(list(aggregator.subjects.values()), now)
                for d in devices}

