"""The one subscription path of every live output: decoded pose frames, joint angles, stats,
segment points and truth batches of the subjects matching a pattern, from bounded hand-off channels.

Zenoh delivers into bounded FIFO channels (Zenoh's own: its threads never wait for Python, so a
busy consumer never stalls the transport; a full channel holds Zenoh back instead of losing
messages on this side). The consumer's own loop takes :class:`Item` s out
(:meth:`Subscription.get`, :meth:`Subscription.drain`), decoded with the wire contract's
decoders; undecodable messages are counted by reason in :attr:`Subscription.errors`, never raised.

Segment points and truth batches come through advanced subscribers with history, like the
aggregator's, so a consumer that starts after the devices still gets what their caches hold.
Segment points are subscribed without Zenoh's late-publisher detection (its cost per sample grows
with the devices present: docs/benchmarks.md, "Late-publisher detection"); as the aggregator does,
a device whose liveliness token comes back is asked for the points after the newest received
(what it sent while its link or the router was down), and a point received twice is given once.
Truth batches come on a device's ``raw`` key or, several devices' at once, on its subject's
``truth`` key: a ``raw`` subscription takes both, and gives a subject message's batches as the
``raw`` items they stand for (each with its device's ``raw`` key and its own batch's bytes).

Example::

    with Subscription(zconfig.ZenohSettings(), "s0*", ("pose",)) as sub:
        while (item := sub.get(timeout=1.0)) is not None:
            print(item.subject, item.value.seq)
"""
from __future__ import annotations

import collections
import re
import threading
import time
from collections.abc import Callable, Iterable
from typing import NamedTuple, Self

import zenoh
import zenoh.ext as zext

from limbstream import wire, zconfig
from limbstream.subject_layouts import SubjectLayouts

KINDS: tuple[str, ...] = (wire.POSE, wire.STATS, wire.ANGLES, wire.SEG, wire.RAW)
"""What a subscription can carry: subject kinds (pose, stats, angles) and device kinds (seg, raw)."""

_DECODERS: dict[str, Callable[[bytes], object]] = {
    wire.POSE: wire.decode_pose, wire.STATS: wire.decode_stats, wire.ANGLES: wire.decode_angles,
    wire.SEG: wire.decode_point, wire.RAW: wire.decode_raw,
}


def open_session(settings: zconfig.ZenohSettings, stop: threading.Event | None = None) -> zenoh.Session | None:
    """:func:`zconfig.open_session`, with a Zenoh error (e.g. a ``--listen`` port in use) raised
    as ValueError in one line naming the flag. None if ``stop`` was set while waiting."""
    try:
        return zconfig.open_session(settings, stop)
    except zenoh.ZError as exc:
        flag = f"--listen {','.join(settings.listen)}" if settings.listen else f"--connect {','.join(settings.connect)}"
        raise ValueError(f"{flag}: {re.sub(r' at [^ ]+[.]rs:[0-9]+[.]?', '', str(exc)).strip()}") from None


class Item(NamedTuple):
    """One decoded message.

    Attributes
    ----------
    kind : "pose" | "stats" | "angles" | "seg" | "raw"
    subject : the subject key chunk.
    segment : the segment of a device kind, None for the subject kinds.
    value : :class:`wire.PoseFrame` | stats dict | :class:`wire.JointAngles` | :class:`wire.SegmentPoint` |
        :class:`wire.RawBatch`.
    key : the key expression it came on.
    payload : the wire bytes as received.
    received_ns : when the consumer took it out of the channel, ns since the Unix epoch (this
        host's clock; :meth:`Subscription.drain` stamps all it takes with one time).
    """

    kind: str
    subject: str
    segment: str | None
    value: object
    key: str
    payload: bytes
    received_ns: int


_MAX_KEYS = 100_000  # parsed keys kept (keys invented by a faulty client cannot grow it further)
_ALIVE = "alive"  # the channel of the devices' liveliness tokens (segment point subscriptions)
_RESUME = "resume"  # the channel of a query for what a device back online sent meanwhile (segment points)
RESUME_WAIT_S = 5.0
"""How long a device back online has to answer the query for what it sent meanwhile, s."""
POLL_S = 0.002
"""How often :meth:`Subscription.get` looks at empty channels, seconds."""


class Subscription:
    """Subscribers of ``kinds`` for the subjects matching ``subjects``, each into a bounded channel.

    Parameters
    ----------
    source : an open session (left open by :meth:`close`) or the settings to open one (closed by it).
    subjects : subject pattern: ``*``, a name, or a name with ``*`` inside (``s0*``), see
        :func:`wire.subject_pattern`. ValueError naming it if it is not one.
    kinds : some of :data:`KINDS`.
    capacity : messages each kind's channel holds; while it is full, Zenoh waits (and the router
        may drop what is not published with congestion control BLOCK: pose frames, stats, truth).
    history : segment points per device asked for when joining late (truth batches: 64).

    Attributes
    ----------
    errors : Counter of dropped messages by reason: ``<kind>_key`` (a key outside the grammar),
        ``<kind>_<wire reason>`` (e.g. ``pose_size``, ``stats_json``, ``truth_size``; ``pose_layout``:
        a layout file's frame before its subject's devices said their layout, which it then asks).
    layouts : each subject's layout as its devices announce it (:class:`SubjectLayouts`): pose
        frames and joint angles of a layout file's layout are read with it.
    received : messages taken out of the channels so far (decoded or not).
    """

    def __init__(self, source: zenoh.Session | zconfig.ZenohSettings, subjects: str = "*",
                 kinds: Iterable[str] = ("pose", "stats"), capacity: int = 1 << 16, history: int = 512):
        kinds = tuple(kinds)
        bad = [k for k in kinds if k not in KINDS]
        if bad or not kinds:
            raise ValueError(f"kinds must be some of {KINDS}, got {kinds!r}")
        wire.subject_pattern(subjects)  # ValueError naming a bad pattern, before any session opens
        if not capacity >= 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        if isinstance(source, zconfig.ZenohSettings):
            self.session, self.owns_session = zconfig.open_session(source), True
        elif isinstance(source, zenoh.Session):
            self.session, self.owns_session = source, False
        else:
            raise TypeError(f"source must be a zenoh.Session or ZenohSettings, got {type(source).__name__}")
        self.subjects, self.kinds, self.capacity = subjects, kinds, capacity
        self.errors: collections.Counter = collections.Counter()
        self.received = 0
        self._subscribers: list[tuple[str, object]] = []
        self._turn = 0  # which channel get() looks at first (each gets its turn)
        self._keys: dict[str, tuple[str, str | None]] = {}  # valid keys seen, parsed
        self._pending: collections.deque[Item] = collections.deque()  # the rest of a split truth message
        self.layouts = SubjectLayouts()  # what a layout file's frames and angles are read with
        self.history = history
        self._newest: dict[str, list] = {}  # point key -> [Zenoh source, newest sequence number, those skipped]
        try:
            for kind in kinds:
                self._subscribers.append((kind, self._declare(kind, history)))
                if kind == wire.RAW:  # a subject's truth message: its devices' batches, split into raw items
                    self._subscribers.append((wire.TRUTH, self._declare(wire.TRUTH, history)))
            if wire.SEG in kinds:  # devices back online: asked for what they sent meanwhile
                self._subscribers.append((_ALIVE, self.session.liveliness().declare_subscriber(
                    wire.device_selector(wire.ALIVE, subjects), zenoh.handlers.FifoChannel(1 << 14))))
        except BaseException:
            self.close()
            raise

    def _declare(self, kind: str, history: int):
        channel = zenoh.handlers.FifoChannel(self.capacity)
        if kind == wire.TRUTH:
            return zext.declare_advanced_subscriber(
                self.session, wire.subject_selector(kind, self.subjects), channel,
                history=zext.HistoryConfig(detect_late_publishers=True, max_samples=64),
                recovery=zext.RecoveryConfig(heartbeat=True), subscriber_detection=True)
        if kind in wire.SUBJECT_KINDS:
            return self.session.declare_subscriber(wire.subject_selector(kind, self.subjects), channel)
        history_config = (zext.HistoryConfig(max_samples=history) if kind == wire.SEG
                          else zext.HistoryConfig(detect_late_publishers=True, max_samples=64))
        return zext.declare_advanced_subscriber(
            self.session, wire.device_selector(kind, self.subjects), channel, history=history_config,
            recovery=zext.RecoveryConfig(heartbeat=True), subscriber_detection=True)

    def _resume(self, sample: zenoh.Sample) -> None:
        """A device's liveliness token came (back): ask its cache for the points after the newest
        received; the answers come in as the resume channel's samples."""
        if sample.kind != zenoh.SampleKind.PUT:
            return
        try:
            subject, segment, _ = wire.parse_device_key(str(sample.key_expr))
        except wire.WireError:
            return
        newest = self._newest.get(wire.seg_key(subject, segment))
        if newest is not None:
            selector = wire.history_selector(subject, segment, self.history, (newest[1] + 1, newest[1] + self.history))
            self._subscribers.append((_RESUME, zconfig.ask_caches(self.session, selector, self.history, RESUME_WAIT_S)))

    def _seen(self, key: str, sample: zenoh.Sample) -> bool:
        """Whether the point ``sample`` carries was received before: its Zenoh source sequence
        number is not after the newest of its key's source, and not one skipped (a gap that a
        resume's or Zenoh's recovery may still fill)."""
        info = sample.source_info
        if info is None or info.source_id is None or info.source_sn is None:
            return False
        source, sn = str(info.source_id), info.source_sn
        state = self._newest.get(key)
        if state is None or state[0] != source:
            if len(self._newest) < _MAX_KEYS or state is not None:
                self._newest[key] = [source, sn, set()]
            return False
        newest, holes = state[1], state[2]
        if sn <= newest:
            if sn in holes:
                holes.discard(sn)
                return False
            return True
        if sn > newest + 1:  # a gap: at most the cache's worth of it can still come
            holes.update(range(max(newest + 1, sn - self.history), sn))
            holes.difference_update([h for h in holes if h < sn - self.history])
        state[1] = sn
        return False

    @property
    def resuming(self) -> bool:
        """Whether a query for what a device back online sent meanwhile is still open."""
        return any(kind == _RESUME for kind, _ in self._subscribers)

    def _take(self, sub, kind: str) -> zenoh.Sample | None:
        """The next sample waiting in ``sub`` (a resume query's reply unwrapped; one that ended
        is dropped from the channels), or None."""
        try:
            sample = sub.try_recv()
        except zenoh.ZError:  # a resume query, complete
            self._subscribers = [(k, s) for k, s in self._subscribers if s is not sub]
            return None
        if sample is None or not isinstance(sample, zenoh.Reply):
            return sample
        return sample.ok  # (an error reply: None, like an empty channel)

    # ------------------------------------------------------------------ consumer side

    def _split_truth(self, sample: zenoh.Sample, received_ns: int) -> Item | None:
        """A subject truth message as the raw items of the batches it holds: the first returned,
        the rest pending (a message that does not split counts as ``truth_<reason>``)."""
        self.received += 1
        try:
            batches = wire.truth_batches(str(sample.key_expr), sample.payload.to_bytes())
        except wire.WireError as exc:
            self.errors[f"truth_{exc.reason}"] += 1
            return None
        items = [item for key, batch in batches if (item := self._item(wire.RAW, key, batch, received_ns)) is not None]
        self._pending.extend(items[1:])
        return items[0] if items else None

    def _decode(self, kind: str, sample: zenoh.Sample, received_ns: int) -> Item | None:
        if kind == wire.TRUTH:
            return self._split_truth(sample, received_ns)
        if kind == _ALIVE:
            self._resume(sample)
            return None
        kind = wire.SEG if kind == _RESUME else kind
        key = str(sample.key_expr)
        if kind == wire.SEG and self._seen(key, sample):
            return None
        self.received += 1
        return self._item(kind, key, sample.payload.to_bytes(), received_ns)

    def _item(self, kind: str, key: str, payload: bytes, received_ns: int) -> Item | None:
        """The message ``payload`` of ``kind`` on ``key`` decoded, or None (counted in ``errors``)."""
        ids = self._keys.get(key)
        try:
            if ids is None:
                if kind in wire.SUBJECT_KINDS:
                    subject, got = wire.parse_subject_key(key)
                    segment = None
                else:
                    subject, segment, got = wire.parse_device_key(key)
                if got != kind:
                    raise wire.WireError("key", f"{key!r} is not a {kind} key")
                ids = (subject, segment)
                if len(self._keys) < _MAX_KEYS:
                    self._keys[key] = ids
            subject, segment = ids
            return Item(kind, subject, segment, self._value(kind, subject, payload), key, payload, received_ns)
        except wire.WireError as exc:
            self.errors[f"{kind}_{exc.reason}"] += 1
            if exc.reason == "layout" and ids is not None:  # a layout file's: its devices say which
                self.layouts.ask(self.session, ids[0])
            return None

    def _value(self, kind: str, subject: str, payload: bytes) -> object:
        """The message decoded (pose frames and joint angles with the subject's layout, :attr:`layouts`)."""
        if kind == wire.POSE:
            return self.layouts.decode_pose(subject, payload)
        if kind == wire.ANGLES:
            return self.layouts.decode_angles(subject, payload)
        return _DECODERS[kind](payload)

    def get(self, timeout: float | None = None) -> Item | None:
        """The next decodable message, waiting at most ``timeout`` seconds (None: forever);
        None if none came in time. The channels take turns."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if self._pending:
                return self._pending.popleft()
            subscribers = list(self._subscribers)  # (a resume query's channel may come or go)
            n = len(subscribers)
            for k in range(n):
                kind, sub = subscribers[(self._turn + k) % n]
                while (sample := self._take(sub, kind)) is not None:
                    if (item := self._decode(kind, sample, time.time_ns())) is not None:
                        self._turn = (self._turn + k + 1) % max(1, len(self._subscribers))
                        return item
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None
            time.sleep(POLL_S if left is None else min(POLL_S, left))

    def drain(self, limit: int = 1 << 20) -> list[Item]:
        """Every decodable message waiting now (at most ``limit`` taken out), without blocking."""
        items: list[Item] = list(self._pending)
        self._pending.clear()
        taken, now = 0, time.time_ns()
        for kind, sub in list(self._subscribers):
            while taken < limit and (sample := self._take(sub, kind)) is not None:
                taken += 1
                if (item := self._decode(kind, sample, now)) is not None:
                    items.append(item)
                    items.extend(self._pending)
                    self._pending.clear()
        return items

    def close(self) -> None:
        """Undeclare the subscribers (and close the session if this subscription opened it)."""
        for kind, sub in self._subscribers:
            try:
                if kind != _RESUME:
                    sub.undeclare()
            except zenoh.ZError:
                pass
        self._subscribers.clear()
        if self.owns_session:
            self.session.close()
            self.owns_session = False

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PoseSubscription:
    """:func:`subscribe_pose`'s handle: ``close()`` (or leaving the ``with`` block) stops the
    callback thread and closes the :class:`Subscription`. ``errors``: undecodable frames."""

    def __init__(self, subscription: Subscription, callback: Callable[[str, wire.PoseFrame], None]):
        self.subscription = subscription
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(callback,), name="pose-callback", daemon=True)
        self._thread.start()

    @property
    def errors(self) -> int:
        return sum(self.subscription.errors.values())

    def _run(self, callback) -> None:
        while not self._stop.is_set():
            item = self.subscription.get(timeout=0.1)
            if item is not None:
                callback(item.subject, item.value)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join()
        self.subscription.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def subscribe_pose(source: zenoh.Session | zconfig.ZenohSettings, subjects: str,
                   callback: Callable[[str, wire.PoseFrame], None]) -> PoseSubscription:
    """Call ``callback(subject, frame)`` for every pose frame of the subjects matching ``subjects``
    (a pattern, as in :class:`Subscription`), on a thread of its own (not a Zenoh thread).

    For Python programs that prefer callbacks to a loop over :meth:`Subscription.get`.
    """
    return PoseSubscription(Subscription(source, subjects, ("pose",)), callback)
