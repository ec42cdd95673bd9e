"""The aggregator's message handling and outputs as of 8cc7f27, without Zenoh: every message
decoded and taken in one by one, stats as one JSON dict per device. What it publishes goes to
``sent`` as (key, payload)."""
from __future__ import annotations

import collections

from limbstream import wire
from support.reference_aggregator.skeleton import Skeleton
from support.reference_aggregator.fusion import Fusion, Subject
from support.reference_aggregator.track import DeviceTrack


class ReferenceAggregator:
    """The old computation: ``on_point`` / ``on_raw`` / ``on_alive`` / ``on_config`` per message,
    ``advance`` per tick, ``publish_stats`` per stats round."""

    def __init__(self, rate: float = 50.0, history: int = 512, error_window_s: float = 60.0,
                 calibrate_on_start: bool = False, max_devices: int = 10_000):
        self.fusion = Fusion(rate, Skeleton(), capacity=max(1024, 2 * history), error_window=int(error_window_s * rate),
                             calibrate_on_start=calibrate_on_start)
        self.subjects: dict[str, Subject] = self.fusion.subjects
        self.bad_keys: collections.Counter = collections.Counter()
        self.max_devices = max_devices
        self.points = self.raw_batches = self.frames = 0
        self.stats_seq: collections.Counter = collections.Counter()
        self.sent: list[tuple[str, bytes]] = []

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
        track = self._known(*ids)
        if track is None:
            if reason is not None:
                self.bad_keys[wire.undecodable(kind)] += 1
                return None
            if len(self.fusion.tracks) >= self.max_devices:
                self.bad_keys["too_many_devices"] += 1
                return None
            track = self.fusion.track(*ids)
        if reason is not None:
            track.dropped[wire.device_reason(kind, reason)] += 1
        return track

    def on_point(self, key: str, payload: bytes, now: float) -> None:
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
            self.points += 1

    def on_raw(self, key: str, payload: bytes, now: float) -> None:
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
            self.raw_batches += 1

    def on_alive(self, key: str, online: bool) -> None:
        ids = self._parse_key(key, "alive")
        if ids is not None and (track := self._device(ids, "alive", None)) is not None:
            self.fusion.set_online(track, online)

    def on_config(self, key: str, payload: bytes) -> None:
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

    def advance(self, live: bool, prune: bool, now: float, wall: float) -> None:
        self.fusion.advance_clock(now)
        self.fusion.calibrate_ready()
        self.fusion.evaluate_truth()
        owners, frames = self.fusion.exact_frames()
        self.fusion.evaluate_frames()
        for sub, payload in zip(owners, frames.encode()):
            self.sent.append((wire.pose_key(sub.name), payload))
        if live:
            owners, live_frames = self.fusion.live_frames(now, wall)
            for sub, payload in zip(owners, live_frames.encode()):
                self.sent.append((wire.pose_key(sub.name), payload))
        if prune:
            self.fusion.prune()
        self.frames += len(frames)

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

    def publish_stats(self, now: float, wall: float, part: int = 0, parts: int = 1) -> None:
        for sub in list(self.subjects.values()):
            if sub.index % parts != part:
                continue
            snapshot = self.subject_stats(sub.name, now)
            devices = snapshot.pop("devices")
            snapshot["aggregator"] = {"subjects": len(self.subjects), "points": self.points,
                                      "raw_batches": self.raw_batches, "frames": self.frames,
                                      "bad_keys": dict(self.bad_keys)}
            payload = wire.encode_stats(sub.name, wall, devices, snapshot, seq=self.stats_seq[sub.name])
            self.sent.append((wire.stats_key(sub.name), payload))
            self.stats_seq[sub.name] += 1
