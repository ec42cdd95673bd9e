"""Live state of the dashboard, fed from Zenoh callbacks through a bounded hand-off.

Zenoh callbacks run on Zenoh threads. They only put the raw payload into an :class:`Inbox`
(bounded deques; when the loop falls behind, the oldest pose frames are skipped and counted)
and, at most once until it runs, schedule :meth:`LiveState.drain` on the event loop
with ``loop.call_soon_threadsafe``. Everything else (decoding, history, fan-out to WebSocket
and SSE clients) happens on the event loop, which owns all the structures below.
"""
from __future__ import annotations

import asyncio
import json
import math
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field

from limbstream import wire

HISTORY_FIELDS = wire.HISTORY_FIELDS
"""Per-device series kept for the charts (plus the stats time ``t``): the charted stats fields."""

KINDS = {"exact": wire.KIND_EXACT, "live": wire.KIND_LIVE}
LATENCY_FRAMES = 500
"""Exact frames per subject the exact-frame latency is taken over (10 s at 50 Hz)."""


class Inbox:
    """Thread-side hand-off. Never blocks beyond a short lock; bounded; counts what it drops.

    Parameters
    ----------
    loop : the event loop that drains it.
    drain : callable run on ``loop`` (at most one pending call at a time).
    max_pending : bound of the stats and liveliness queues.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, drain, max_pending: int = 4096):
        self._loop = loop
        self._drain = drain
        self._lock = threading.Lock()
        self._scheduled = False
        self.stats: deque[tuple[float, str, bytes]] = deque()
        self.alive: deque[tuple[str, bool]] = deque()
        self.poses: deque[tuple[float, str, bytes]] = deque()
        self.max_pending = max_pending
        self.dropped = Counter()

    def _schedule(self) -> None:
        if not self._scheduled:
            self._scheduled = True
            try:
                self._loop.call_soon_threadsafe(self._drain)
            except RuntimeError:  # loop closed during shutdown
                pass

    def put_stats(self, key: str, payload: bytes) -> None:
        with self._lock:
            if len(self.stats) >= self.max_pending:
                self.dropped["stats"] += 1
                return
            self.stats.append((time.time(), key, payload))
            self._schedule()

    def put_pose(self, key: str, payload: bytes) -> None:
        with self._lock:
            if len(self.poses) >= self.max_pending:
                self.poses.popleft()  # the loop is behind: skip the oldest frame
                self.dropped["pose"] += 1
            self.poses.append((time.time(), key, payload))
            self._schedule()

    def put_alive(self, key: str, present: bool) -> None:
        with self._lock:
            if len(self.alive) >= self.max_pending:
                self.dropped["alive"] += 1
                return
            self.alive.append((key, present))
            self._schedule()

    def take(self):
        """Swap out everything pending (event-loop side)."""
        with self._lock:
            stats, self.stats = self.stats, deque()
            alive, self.alive = self.alive, deque()
            poses, self.poses = self.poses, deque()
            self._scheduled = False
        return stats, alive, poses


@dataclass
class DeviceEntry:
    """Latest stats and bounded history of one device."""

    subject: str
    segment: str
    stats: dict | None = None
    updated: float = 0.0
    history: deque = field(default_factory=deque)


AGGREGATOR_FIGURES: tuple[str, ...] = tuple(f.name for f in wire.AGGREGATOR_FIGURES)
"""Numbers an aggregator reports about its own loop in every stats message (``"aggregator"``)."""
MAX_AGGREGATORS = 64
MAX_BAD_KEY_REASONS = 32


@dataclass
class AggregatorEntry:
    """The latest loop figures of one aggregator and the subjects it reported on."""

    figures: dict
    bad_keys: dict
    updated: float
    subjects: set = field(default_factory=set)


@dataclass
class PoseEntry:
    """Latest frame of one subject and kind, with its JSON text built on first use."""

    frame: wire.PoseFrame
    rx: float
    _text: str | None = None

    def as_dict(self, subject: str) -> dict:
        return self.frame.to_json(subject) | {"rx": round(self.rx, 4)}

    def text(self, subject: str) -> str:
        if self._text is None:
            self._text = json.dumps(self.as_dict(subject), separators=(",", ":"))
        return self._text


class PoseClient:
    """One WebSocket/SSE client: a bounded queue; when full the oldest frame is skipped."""

    def __init__(self, subject: str, kind: str, maxsize: int):
        self.subject = subject
        self.kind = kind
        self.queue: asyncio.Queue[str] = asyncio.Queue(maxsize)
        self.sent = 0
        self.skipped = 0

    def offer(self, text: str) -> None:
        if self.queue.full():
            self.queue.get_nowait()
            self.skipped += 1
        self.queue.put_nowait(text)


def _clean(value):
    return None if isinstance(value, float) and not math.isfinite(value) else value


class LiveState:
    """Latest stats per device, bounded history per device, latest pose per subject.

    Parameters
    ----------
    history_seconds : seconds of history kept per device.
    max_devices, max_subjects : bounds on tracked devices / subjects.
    stale_after_s : age (s) beyond which a device's stats count as stale.
    ws_queue : per-client queue length.
    """

    def __init__(self, history_seconds: int = 900, max_devices: int = 10_000, max_subjects: int = 1_000,
                 stale_after_s: float = 5.0, ws_queue: int = 16):
        self.history_seconds = history_seconds
        self.max_devices = max_devices
        self.max_subjects = max_subjects
        self.stale_after_s = stale_after_s
        self.ws_queue = ws_queue
        self.devices: dict[str, DeviceEntry] = {}
        self.alive: set[str] = set()
        self.poses: dict[str, dict[int, PoseEntry]] = {}
        self.stats_times: dict[str, float] = {}
        self.subject_stats: dict[str, dict] = {}  # the subject fields of each subject's latest stats
        self.exact_latency: dict[str, deque[float]] = {}  # ms, frame time -> received, last exact frames
        self.aggregators: dict[str, AggregatorEntry] = {}
        self.clients: dict[str, set[PoseClient]] = {}
        self.received = Counter()
        self.errors = Counter()
        self.missed = Counter()  # messages lost on the way, by stream: stats, pose_exact, pose_live
        self._next_seq: dict[tuple[str, str], int] = {}
        self.clients_skipped = 0
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
        stats, alive, poses = self.inbox.take()
        for key, present in alive:
            self.apply_alive(key, present)
        for rx, _key, payload in stats:
            self.apply_stats(payload, rx)
        for rx, key, payload in poses:
            self.apply_pose(key, payload, rx)

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

    def aggregator_views(self) -> list[dict]:
        """The REST form of every aggregator: its figures, late ticks in %, age and staleness."""
        now = time.time()
        out = []
        for aid, agg in sorted(self.aggregators.items()):
            f = agg.figures
            late_pct = 100.0 * f["late"] / f["ticks"] if f["ticks"] and f["late"] is not None else None
            age = now - agg.updated
            out.append({"id": aid, **f, "late_pct": None if late_pct is None else round(late_pct, 4),
                        "bad_keys": agg.bad_keys, "serving": sorted(agg.subjects),
                        "age_s": round(age, 3), "stale": age > self.stale_after_s})
        return out

    def apply_pose(self, key: str, payload: bytes, rx: float | None = None) -> None:
        """Decode one pose frame, keep it as the latest and fan it out to clients."""
        rx = time.time() if rx is None else rx
        self.received["pose"] += 1
        try:
            subject, _ = wire.parse_subject_key(key)
            frame = wire.decode_pose(payload)
        except wire.WireError as exc:
            self.errors[f"pose_{exc.reason}"] += 1
            return
        slots = self.poses.get(subject)
        if slots is None:
            if len(self.poses) >= self.max_subjects:
                self.errors["too_many_subjects"] += 1
                return
            slots = self.poses[subject] = {}
        self._count_missed(subject, "pose_live" if frame.kind == wire.KIND_LIVE else "pose_exact", frame.seq)
        entry = slots[frame.kind] = PoseEntry(frame, rx)
        if frame.kind == wire.KIND_EXACT:
            lat = self.exact_latency.get(subject)
            if lat is None:
                lat = self.exact_latency[subject] = deque(maxlen=LATENCY_FRAMES)
            lat.append(1e3 * rx - frame.t_us / 1e3)
        clients = self.clients.get(subject)
        if clients:
            kind = self.auto_kind(subject)
            for client in clients:
                wanted = kind if client.kind == "auto" else KINDS[client.kind]
                if wanted == frame.kind:
                    client.offer(entry.text(subject))

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

    # ------------------------------------------------------------------ reads

    def auto_kind(self, subject: str) -> int:
        """The kind ``kind=auto`` shows now: the contract's one rule (``wire.auto_kind``)."""
        live = self.poses.get(subject, {}).get(wire.KIND_LIVE)
        return wire.auto_kind(math.inf if live is None else time.time() - live.rx)

    def latest_pose(self, subject: str, kind: str = "auto") -> PoseEntry | None:
        slots = self.poses.get(subject, {})
        if kind == "auto":
            return slots.get(self.auto_kind(subject)) or next(iter(slots.values()), None)
        return slots.get(KINDS[kind])

    def device_view(self, did: str, now: float | None = None) -> dict | None:
        """The REST form of one device: every stats field, plus subject, alive, age_s, stale."""
        entry = self.devices.get(did)
        if entry is None:
            return None
        now = time.time() if now is None else now
        stats = entry.stats or {}
        view = {k: stats.get(k) for k in wire.STATS_FIELDS}
        view |= {k: v for k, v in stats.items() if k not in view}
        age = now - entry.updated if entry.stats is not None else None
        stale = age is None or age > self.stale_after_s
        alive = did in self.alive
        view.update(device=did, segment=entry.segment, subject=entry.subject, alive=alive,
                    age_s=None if age is None else round(age, 3), stale=stale,
                    online=bool(stats.get("online")) if not stale else alive)
        return view

    def device_views(self) -> list[dict]:
        now = time.time()
        return [self.device_view(did, now) for did in sorted(self.devices)]

    def history(self, did: str, seconds: float) -> dict | None:
        """Column form ``{"t": [...], <field>: [...]}`` of the last ``seconds`` of a device."""
        entry = self.devices.get(did)
        if entry is None:
            return None
        rows = list(entry.history)
        if rows:
            cutoff = rows[-1][0] - seconds
            rows = [r for r in rows if r[0] >= cutoff]
        columns = {"t": [r[0] for r in rows]}
        for i, name in enumerate(HISTORY_FIELDS, start=1):
            columns[name] = [r[i] for r in rows]
        return columns

    def subject_views(self) -> list[dict]:
        now = time.time()
        names = sorted({e.subject for e in self.devices.values()} | set(self.poses))
        out = []
        for name in names:
            views = [self.device_view(did, now) for did, e in sorted(self.devices.items()) if e.subject == name]
            pose = self.latest_pose(name)
            out.append({
                "subject": name,
                "devices": len(views),
                "online": sum(1 for v in views if v["online"]),
                "msgs_per_s": round(sum(v["msgs_per_s"] or 0.0 for v in views), 3),
                "bytes_per_s": round(sum(v["bytes_per_s"] or 0.0 for v in views), 3),
                "stats_age_s": round(now - self.stats_times[name], 3) if name in self.stats_times else None,
                "pose": None if pose is None else {
                    "seq": pose.frame.seq, "t": pose.frame.t_us / 1e6,
                    "kind": "live" if pose.frame.kind == wire.KIND_LIVE else "exact",
                    "age_s": round(now - pose.rx, 3)},
                **self.exact_latency_view(name),
                **self.subject_stats.get(name, {}),
            })
        return out

    def exact_latency_view(self, subject: str) -> dict:
        """``exact_latency_p50_ms``, ``exact_latency_p99_ms``: frame time -> received here, over
        the subject's last :data:`LATENCY_FRAMES` exact frames (None before the first)."""
        lat = self.exact_latency.get(subject)
        if not lat:
            return {"exact_latency_p50_ms": None, "exact_latency_p99_ms": None}
        xs = sorted(lat)
        pick = lambda q: round(xs[min(len(xs) - 1, int(q * len(xs)))], 1)  # noqa: E731 - nearest rank
        return {"exact_latency_p50_ms": pick(0.5), "exact_latency_p99_ms": pick(0.99)}

    # ------------------------------------------------------------------ clients

    def add_client(self, subject: str, kind: str = "auto") -> PoseClient:
        client = PoseClient(subject, kind, self.ws_queue)
        self.clients.setdefault(subject, set()).add(client)
        latest = self.latest_pose(subject, kind)
        if latest is not None:
            client.offer(latest.text(subject))
        return client

    def remove_client(self, client: PoseClient) -> None:
        group = self.clients.get(client.subject)
        if group is not None:
            group.discard(client)
            if not group:
                del self.clients[client.subject]
        self.clients_skipped += client.skipped

    def client_count(self) -> int:
        return sum(len(g) for g in self.clients.values())


def _num(value) -> float | None:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    return None
