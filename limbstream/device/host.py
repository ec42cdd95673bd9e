"""The device host: the Zenoh side of the devices one process serves, the same for every kind of
device (docs/protocol.md, "Key expressions").

Per device: its segment point publisher (advanced: a cache for recovery, miss detection), its
truth-tap publisher (with ``truth``; with ``truth_by_subject`` one per subject instead, its
messages holding the batches of all the subject's devices: ``wire.truth``), and its liveliness
token while it is online. Per subject: one config queryable, read between ticks (never in a
Zenoh callback), at most :data:`QUERIES_PER_TICK` queries per call. What a device answers comes from its owner: the
``configure`` and ``status`` callbacks (devices whose kernels run in this process:
:class:`~limbstream.device.bank.DeviceBank`; a device on a serial link asks its firmware).
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
import zenoh

from limbstream import wire
from limbstream.device import io
from limbstream.device.io import Refused
from limbstream.pacing import PacedLoop

__all__ = ["IDLE_S", "QUERIES_PER_TICK", "Device", "DeviceHost", "HostSettings", "Refused"]
log = logging.getLogger("limbstream.device")
QUERIES_PER_TICK = 10
"""Config queries one call answers at most (each may name a whole subject's devices): an
aggregator's status poll asks every subject at once, and answering 100 subjects in one tick
would make it late; the rest wait a tick."""

IDLE_S = 0.05
"""After a finite run, config queries are answered this often, s."""

S = TypeVar("S")


@dataclass(frozen=True)
class HostSettings:
    """What every device of a host shares.

    Attributes
    ----------
    fs : device sample rate, Hz.
    config : initial fastSW settings of every device (limbstream.wire.TUNABLES).
    truth : publish each device's truth tap (its samples, with their reference times).
    raw_batch : samples per truth-tap batch (at most).
    truth_by_subject : the truth tap goes out one message per subject and batch, on the subject's
        ``truth`` key, holding the batches of its devices that are due together
        (:meth:`DeviceHost.publish_raws`): a host that samples a subject's devices together (the
        emulator). Else one message per device and batch on its ``raw`` key (gateways, replay:
        their devices' batches come one at a time).
    cache : segment points each device keeps for recovery (advanced publisher cache).
    heartbeat_s : segment points' miss-detection heartbeat period, s: sporadic, sent only if a
        point went out since the last one (:func:`limbstream.device.io.point_publisher`).
    """

    fs: float = wire.DEVICE_RATE_HZ
    config: wire.DeviceConfig = wire.DeviceConfig()
    truth: bool = True
    raw_batch: int = 25
    truth_by_subject: bool = False
    cache: int = 512
    heartbeat_s: float = 2.0


@dataclass(eq=False)
class Device(Generic[S]):
    """One device of a host. ``source`` is where its samples come from, as its owner knows it
    (the SlimeVR sensor feeding it, ...); ``points`` and ``last`` count its current stream."""

    subject: str
    segment: str
    slot: int
    config: wire.DeviceConfig
    source: S | None = None
    publisher: Any = None
    raw_pub: Any = None
    token: Any = None
    streams: int = 0                 # streams started
    points: int = 0                  # segment points published in the current stream
    last: bytes | None = None        # the newest of them

    @property
    def id(self) -> str:
        return wire.device_id(self.subject, self.segment)

    @property
    def online(self) -> bool:
        """Its liveliness token is declared."""
        return self.token is not None


def _messages(slots: np.ndarray, payload: bytes, ends: np.ndarray) -> Iterator[tuple[int, bytes]]:
    """(slot, message) of messages laid end to end (message i, device ``slots[i]``'s, is
    ``payload[ends[i - 1]:ends[i]]``, from 0 for i = 0)."""
    start = 0
    for slot, end in zip(slots.tolist(), ends.tolist()):
        yield slot, payload[start:end]
        start = end


class DeviceHost(Generic[S]):
    """The devices of one process and their Zenoh side.

    Parameters
    ----------
    session : an open Zenoh session (client).
    settings : HostSettings.
    configure : ``configure(device, config)`` applies a config (raises :class:`Refused` or
        ``wire.WireError`` when it cannot: the query gets that error and nothing changes).
    status : ``status(device)``: the device's answer (may raise :class:`Refused`).
    offline_answers : a device offline answers config queries too (else only online devices do).

    Devices added before :meth:`declare` are declared by it; later ones at once.
    """

    def __init__(self, session: zenoh.Session, settings: HostSettings,
                 configure: Callable[[Device[S], wire.DeviceConfig], None],
                 status: Callable[[Device[S]], wire.DeviceStatus], offline_answers: bool = False):
        self.session, self.settings = session, settings
        self.configure, self.status, self.offline_answers = configure, status, offline_answers
        self.devices: list[Device[S]] = []       # by slot
        self.by_id: dict[str, Device[S]] = {}
        self.subjects: dict[str, list[tuple[zenoh.KeyExpr, Device[S]]]] = {}  # each served subject's devices
        self._queryables: dict[str, Any] = {}    # by subject
        self.truth_pubs: dict[str, Any] = {}     # by subject, with truth_by_subject
        self.declared = False

    def add(self, subject: str, segment: str, source: S | None = None) -> Device[S]:
        """A new device in the next slot (its subject's config queries are answered from now on)."""
        d: Device[S] = Device(subject, segment, len(self.devices), self.settings.config, source)
        self.devices.append(d)
        self.by_id[d.id] = d
        self.serve(subject)
        self.subjects[subject].append((zenoh.KeyExpr(wire.config_key(subject, segment)), d))
        if self.declared:
            self._declare(d)
        return d

    def serve(self, subject: str) -> None:
        """Answer the config queries of ``subject``'s devices (a queryable per subject)."""
        if subject not in self.subjects:
            self.subjects[subject] = []
            if self.declared:
                self._declare_queryable(subject)
                self._declare_truth(subject)

    def declare(self) -> None:
        """Declare the publishers of the devices added so far and the subjects' queryables."""
        if self.declared:
            return
        self.declared = True
        for subject in self.subjects:
            self._declare_queryable(subject)
            self._declare_truth(subject)
        for d in self.devices:
            self._declare(d)

    def _declare(self, d: Device[S]) -> None:
        s = self.settings
        d.publisher = io.point_publisher(self.session, d.subject, d.segment, s.cache, s.heartbeat_s)
        if s.truth and not s.truth_by_subject:
            d.raw_pub = io.raw_publisher(self.session, d.subject, d.segment)

    def _declare_truth(self, subject: str) -> None:
        if self.settings.truth and self.settings.truth_by_subject:
            self.truth_pubs[subject] = io.truth_publisher(self.session, subject)

    def _declare_queryable(self, subject: str) -> None:
        self._queryables[subject] = self.session.declare_queryable(wire.device_selector(wire.CONFIG, subject),
                                                                   zenoh.handlers.FifoChannel(1024))

    def online(self, d: Device[S]) -> None:
        """The device comes online: its liveliness token."""
        if d.token is None:
            d.token = io.alive_token(self.session, d.subject, d.segment)

    def offline(self, d: Device[S]) -> None:
        """The device goes offline: its token is dropped (subscribers see it leave)."""
        if d.token is not None:
            d.token.undeclare()
            d.token = None

    def publish(self, d: Device[S], payload: bytes) -> None:
        """One segment point message of the device's current stream."""
        d.last = payload
        d.publisher.put(payload)
        d.points += 1

    def publish_points(self, slots: np.ndarray, payload: bytes, ends: np.ndarray) -> None:
        """Segment point messages of several devices, laid end to end: :meth:`publish` of each.

        Parameters
        ----------
        slots : (K,) the devices' slots, message by message.
        payload : bytes, the K messages back to back.
        ends : (K,) offset in payload just after each message (message i is
            ``payload[ends[i - 1]:ends[i]]``, from 0 for i = 0).
        """
        devices = self.devices
        for slot, message in _messages(slots, payload, ends):
            d = devices[slot]
            d.last = message
            d.publisher.put(message)
            d.points += 1

    def publish_raw(self, d: Device[S], batch: wire.RawBatch | bytes) -> None:
        """One truth-tap batch, or its payload as encoded (nothing without ``truth``); with
        ``truth_by_subject``, a subject message of this batch alone."""
        payload = batch if isinstance(batch, bytes) else wire.encode_raw(batch)
        if d.raw_pub is not None:
            d.raw_pub.put(payload)
        elif d.subject in self.truth_pubs:
            self.truth_pubs[d.subject].put(wire.encode_truth([d.segment], [payload]))

    def publish_raws(self, slots: np.ndarray, payload: bytes, ends: np.ndarray) -> None:
        """Truth-tap batches of several devices, laid end to end (as :meth:`publish_points`;
        ``wire.encode_raws`` writes them so): one message per device (:meth:`publish_raw` of
        each), or with ``truth_by_subject`` one per subject holding its devices' batches, in order."""
        devices = self.devices
        if not self.truth_pubs:
            for slot, message in _messages(slots, payload, ends):
                pub = devices[slot].raw_pub
                if pub is not None:
                    pub.put(message)
            return
        by_subject: dict[str, tuple[list[str], list[bytes]]] = {}
        for slot, message in _messages(slots, payload, ends):
            d = devices[slot]
            segments, batches = by_subject.setdefault(d.subject, ([], []))
            segments.append(d.segment)
            batches.append(message)
        for subject, (segments, batches) in by_subject.items():
            self.truth_pubs[subject].put(wire.encode_truth(segments, batches))

    def answer_queries(self, budget: int = QUERIES_PER_TICK) -> None:
        """Apply and answer the config queries that arrived since the last call, at most ``budget``."""
        for subject, queryable in self._queryables.items():
            while budget > 0 and (query := queryable.try_recv()) is not None:
                budget -= 1
                selector = query.key_expr
                targets = [d for key, d in self.subjects[subject]
                           if (d.online or self.offline_answers) and key.intersects(selector)]
                io.answer_config(query, targets, self.configure, self.status)

    def idle(self, stop: threading.Event, also: Callable[[], object] | None = None) -> None:
        """After a finite run: answer config queries (and call ``also``) every IDLE_S until ``stop``
        (the recovery caches keep serving meanwhile)."""
        def serve(k: int, now: float) -> None:
            self.answer_queries()
            if also is not None:
                also()
        PacedLoop(IDLE_S).run(stop, serve)

    def close(self) -> None:
        """Undeclare everything (the devices go offline)."""
        for d in self.devices:
            self.offline(d)
            for obj in (d.publisher, d.raw_pub):
                if obj is not None:
                    obj.undeclare()
            d.publisher = d.raw_pub = None
        for obj in [*self._queryables.values(), *self.truth_pubs.values()]:
            obj.undeclare()
        self._queryables.clear()
        self.truth_pubs.clear()
        self.declared = False
