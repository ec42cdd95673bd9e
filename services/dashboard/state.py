"""Live state of the dashboard: the messages taken in (stats, pose frames, liveliness), decoded
and kept on the event loop, which owns every structure here.

Zenoh callbacks hand payloads over through an :class:`~.inbox.Inbox`; :meth:`LiveState.drain`
applies them. The REST views of this state: :class:`~.views.Views`; the fan-out of pose frames to
WebSocket and SSE clients: :class:`~.fanout.FanOut`, held here (``fanout``).
"""
from __future__ import annotations

import asyncio
import math
import time
from collections import Counter, deque
from collections.abc import Callable

from limbstream import wire
from limbstream.subject_layouts import SubjectLayouts

from .entries import (AGGREGATOR_FIGURES, ANGLES_HISTORY_S, HISTORY_FIELDS, KINDS, LATENCY_FRAMES, MAX_AGGREGATORS,
                      MAX_BAD_KEY_REASONS, AggregatorEntry, DeviceEntry, PoseEntry)
from .fanout import FanOut
from .inbox import Inbox


def _clean(value):
    return None if isinstance(value, float) and not math.isfinite(value) else value


class LiveState:
    """Latest stats per device, bounded history per device, latest pose and the last
    ANGLES_HISTORY_S of joint angles per subject, and the clients its pose frames fan out to.

    Parameters
    ----------
    history_seconds : seconds of history kept per device.
    max_devices, max_subjects : bounds on tracked devices / subjects.
    ws_queue : per-client queue length.
    """

    def __init__(self, history_seconds: int = 900, max_devices: int = 10_000, max_subjects: int = 1_000,
                 ws_queue: int = 16):
        self.history_seconds = history_seconds
        self.max_devices = max_devices
        self.max_subjects = max_subjects
        self.devices: dict[str, DeviceEntry] = {}
        self.alive: set[str] = set()
        self.poses: dict[str, dict[int, PoseEntry]] = {}
        self.angles: dict[str, dict[int, deque[tuple[float, wire.JointAngles]]]] = {}  # (rx, angles) by kind
        self.stats_times: dict[str, float] = {}
        self.subject_stats: dict[str, dict] = {}  # the subject fields of each subject's latest stats
        self.pose_refused: dict[str, str] = {}  # why a subject's latest pose frame was refused (its layout)
        self.layouts = SubjectLayouts(max_subjects)  # what a layout file's frames and angles are read with
        self.ask_layout: Callable[[str], object] | None = None  # asks a subject's devices their layout (once connected)
        self.exact_latency: dict[str, deque[float]] = {}  # ms, frame time -> received, last exact frames
        self.aggregators: dict[str, AggregatorEntry] = {}
        self.fanout = FanOut(ws_queue)
        self.received = Counter()
        self.errors = Counter()
        self.missed = Counter()  # messages lost on the way, by stream: stats, pose_exact, pose_live, angles_*
        self._next_seq: dict[tuple[str, str], int] = {}
        self.inbox: Inbox | None = None

    # ------------------------------------------------------------------ hand-off

    def attach(self, loop: asyncio.AbstractEventLoop) -> Inbox:
        """Create the inbox that Zenoh callbacks feed, drained on ``loop``."""
        self.inbox = Inbox(loop, self.drain)
        return self.inbox

    def drain(self) -> None:
        """Apply everything the inbox holds (runs on the event loop)."""
        if self.inbox is None:
            return
        stats, alive, poses, angles = self.inbox.take()
        for key, present in alive:
            self.apply_alive(key, present)
        for rx, _key, payload in stats:
            self.apply_stats(payload, rx)
        for rx, key, payload in poses:
            self.apply_pose(key, payload, rx)
        if angles:
            self.apply_angles(angles)

    def apply_alive(self, key: str, present: bool) -> None:
        try:
            subject, segment, _ = wire.parse_device_key(key)
        except wire.WireError:
            self.errors["alive_key"] += 1
            return
        did = wire.device_id(subject, segment)
        if present:
            self.alive.add(did)
            self._entry(subject, segment)
        else:
            self.alive.discard(did)

    def apply_stats(self, payload: bytes, rx: float | None = None) -> None:
        """Decode one stats message and update latest values and history."""
        rx = time.time() if rx is None else rx
        self.received["stats"] += 1
        try:
            data = wire.decode_stats(payload)
            subject = wire.check_chunk(data["subject"], "subject")
            t = float(data.get("t") or rx)
        except (wire.WireError, ValueError, TypeError) as exc:
            self.errors[getattr(exc, "reason", "stats")] += 1
            return
        self.stats_times[subject] = rx
        self.subject_stats[subject] = {f.name: _clean(data.get(f.name)) for f in wire.SUBJECT_FIELDS}
        self._count_missed(subject, "stats", data.get("seq"))
        self._apply_aggregator(data.get("aggregator"), subject, rx)
        for d in data["devices"]:
            try:
                dev_subject, segment = wire.split_device_id(d["device"])
            except (ValueError, TypeError):
                self.errors["stats_device"] += 1
                continue
            entry = self._entry(dev_subject, segment)
            if entry is None:
                continue
            entry.stats = {k: _clean(v) for k, v in d.items()}
            entry.updated = rx
            row = (t,) + tuple(_num(d.get(k)) for k in HISTORY_FIELDS)
            entry.history.append(row)
            while entry.history and (entry.history[0][0] < t - self.history_seconds
                                     or len(entry.history) > 2 * self.history_seconds):
                entry.history.popleft()

    def _apply_aggregator(self, entry, subject: str, rx: float) -> None:
        """Keep the loop figures an aggregator sent along with a subject's stats (bounded: at
        most MAX_AGGREGATORS, the longest silent one makes room; malformed entries are counted)."""
        if entry is None:
            return
        aid = entry.get("id") if isinstance(entry, dict) else None
        if not isinstance(aid, str) or not 0 < len(aid) <= 128:
            self.errors["stats_aggregator"] += 1
            return
        if aid not in self.aggregators and len(self.aggregators) >= MAX_AGGREGATORS:
            del self.aggregators[min(self.aggregators, key=lambda a: self.aggregators[a].updated)]
        bad = entry.get("bad_keys")
        bad = {str(k)[:64]: v for k, v in bad.items() if _num(v) is not None} if isinstance(bad, dict) else {}
        for other in self.aggregators.values():  # a subject is served by one aggregator at a time
            other.subjects.discard(subject)
        agg = self.aggregators.setdefault(aid, AggregatorEntry({}, {}, rx))
        agg.figures = {k: _num(entry.get(k)) for k in AGGREGATOR_FIGURES}
        agg.bad_keys = dict(sorted(bad.items())[:MAX_BAD_KEY_REASONS])
        agg.updated = rx
        agg.subjects.add(subject)

    def apply_pose(self, key: str, payload: bytes, rx: float | None = None) -> None:
        """Decode one pose frame, keep it as the latest and fan it out to clients."""
        rx = time.time() if rx is None else rx
        self.received["pose"] += 1
        try:
            subject, _ = wire.parse_subject_key(key)
            frame = self.layouts.decode_pose(subject, payload)
        except wire.WireError as exc:
            self.errors[f"pose_{exc.reason}"] += 1
            if exc.reason == "layout" and (subject in self.pose_refused or len(self.pose_refused) < self.max_subjects):
                self.pose_refused[subject] = str(exc)
                self._ask_layout(subject)
            return
        self.pose_refused.pop(subject, None)
        slots = self.poses.get(subject)
        if slots is None:
            if len(self.poses) >= self.max_subjects:
                self.errors["too_many_subjects"] += 1
                return
            slots = self.poses[subject] = {}
        self._count_missed(subject, wire.pose_stream(frame.kind), frame.seq)
        entry = slots[frame.kind] = PoseEntry(frame, rx)
        if frame.kind == wire.KIND_EXACT:
            lat = self.exact_latency.get(subject)
            if lat is None:
                lat = self.exact_latency[subject] = deque(maxlen=LATENCY_FRAMES)
            lat.append(1e3 * rx - frame.t_us / 1e3)
        if self.fanout.watched(subject):
            self.fanout.publish(subject, entry, self.auto_kind(subject))

    def apply_angles(self, items) -> None:
        """A drain's joint-angle messages ((rx, key, payload) each), decoded together (the batch
        decoder: one NumPy pass, whatever their number); each subject's kept for ANGLES_HISTORY_S."""
        self.received["angles"] += len(items)
        subjects, kept = [], []
        for rx, key, payload in items:
            try:
                subjects.append(wire.parse_subject_key(key)[0])
                kept.append((rx, payload))
            except wire.WireError:
                self.errors["angles_key"] += 1
        frames, reasons = wire.decode_angles_many([payload for _, payload in kept])
        row = 0
        for subject, (rx, payload), reason in zip(subjects, kept, reasons):
            if reason == "layout":  # another layout than the batch's, or a layout file's: read alone, with the subject's
                try:
                    angles = self.layouts.decode_angles(subject, payload)
                except wire.WireError as exc:
                    self.errors[f"angles_{exc.reason}"] += 1
                    self._ask_layout(subject)
                    continue
            elif reason:
                self.errors[f"angles_{reason}"] += 1
                continue
            else:
                angles, row = frames[row], row + 1
            kinds = self.angles.get(subject)
            if kinds is None:
                if len(self.angles) >= self.max_subjects:
                    self.errors["too_many_subjects"] += 1
                    continue
                kinds = self.angles[subject] = {}
            self._count_missed(subject, f"{wire.ANGLES}_{wire.kind_name(angles.kind)}", angles.seq)
            kept_rows = kinds.setdefault(angles.kind, deque())
            kept_rows.append((rx, angles))
            while kept_rows[0][0] < rx - ANGLES_HISTORY_S:
                kept_rows.popleft()

    def _ask_layout(self, subject: str) -> None:
        """Ask ``subject``'s devices which layout they announce (a frame of a layout file's came)."""
        if self.ask_layout is not None:
            self.ask_layout(subject)

    def angles_kind(self, subject: str) -> int | None:
        """The kind of joint angles ``kind=auto`` gives: the pose frames' rule (live while they come
        within wire.AUTO_LIVE_WINDOW_S, else exact), of the kinds there are (None: none)."""
        kinds = self.angles.get(subject, {})
        live, exact = kinds.get(wire.KIND_LIVE), kinds.get(wire.KIND_EXACT)
        if live and (not exact or wire.auto_kind(time.time() - live[-1][0]) == wire.KIND_LIVE):
            return wire.KIND_LIVE
        return wire.KIND_EXACT if exact else None

    def auto_kind(self, subject: str) -> int:
        """The kind ``kind=auto`` shows now: the contract's one rule (``wire.auto_kind``)."""
        live = self.poses.get(subject, {}).get(wire.KIND_LIVE)
        return wire.auto_kind(math.inf if live is None else time.time() - live.rx)

    def latest_pose(self, subject: str, kind: str = "auto") -> PoseEntry | None:
        """The subject's latest frame of ``kind`` (``auto``: the kind it shows now, else any)."""
        slots = self.poses.get(subject, {})
        if kind == "auto":
            return slots.get(self.auto_kind(subject)) or next(iter(slots.values()), None)
        return slots.get(KINDS[kind])

    def _count_missed(self, subject: str, stream: str, seq: int | None) -> None:
        """Sequence check of one of a subject's streams: a jump forward counts the messages
        skipped as missed; a number at or below the last one is a restarted sender (starts over)."""
        if seq is None:
            return
        key = (subject, stream)
        expected = self._next_seq.get(key)
        if expected is not None and seq > expected:
            self.missed[stream] += seq - expected
        self._next_seq[key] = seq + 1

    def _entry(self, subject: str, segment: str) -> DeviceEntry | None:
        did = wire.device_id(subject, segment)
        entry = self.devices.get(did)
        if entry is None:
            if len(self.devices) >= self.max_devices:
                self.errors["too_many_devices"] += 1
                return None
            entry = self.devices[did] = DeviceEntry(subject, segment)
        return entry


def _num(value) -> float | None:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    return None
