"""Each subject's body layout as its devices announce it: what a receiver reads pose frames and
joint-angle messages of a layout file's layout with (layout byte ``wire.OTHER_LAYOUT``, 255), the
one place each consumer keeps "subject -> layout" (docs/protocol.md, "Layout files on the wire").

A device's status body (``wire.encode_body``) names a built-in layout or carries a layout file's
table; :class:`SubjectLayouts` keeps the layout of each subject's latest status that says one. A
live receiver that meets a frame it cannot read asks the subject's devices for their status
(:meth:`SubjectLayouts.ask`, at most every :data:`ASK_EVERY_S`; the answers are read at its next
look-up); a recording's reader learns
from the statuses it holds.
"""
from __future__ import annotations

import queue
import threading
import time

import zenoh

from limbstream import wire
from limbstream.body import Layout

ASK_EVERY_S = 1.0
"""How often a receiver asks a subject's devices for their status while it cannot read its frames, s."""

ASK_TIMEOUT_S = 2.0
"""How long such a query waits for the devices' answers, s."""


class SubjectLayouts:
    """Subject -> the layout its devices announce (at most ``max_subjects`` subjects). :meth:`ask`'s
    answers are handed off by Zenoh's threads as they come and read on the next look-up."""

    def __init__(self, max_subjects: int = 10_000):
        self.max_subjects = max_subjects
        self._layouts: dict[str, Layout] = {}
        self._asked: dict[str, float] = {}
        self._lock = threading.Lock()
        self._replies: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()  # (key, payload) of ask's answers

    def learn(self, subject: str, status: wire.DeviceStatus) -> Layout | None:
        """Take the layout of ``status`` (a device of ``subject``'s): its body's; None (and nothing
        kept) where it carries none or the subjects are at their bound."""
        if status.body is None:
            return None
        with self._lock:
            if subject not in self._layouts and len(self._layouts) >= self.max_subjects:
                return None
            self._layouts[subject] = status.body.layout
        return status.body.layout

    def learn_reply(self, key: str, payload: bytes) -> Layout | None:
        """Take the layout of a config reply (a device status on ``key``, its config key); None for
        one that says none, is not a status or comes on another key."""
        try:
            subject, _, kind = wire.parse_device_key(key)
            if kind != wire.CONFIG:
                return None
            return self.learn(subject, wire.decode_status(payload))
        except wire.WireError:
            return None

    def layout_of(self, subject: str) -> Layout | None:
        """The layout ``subject``'s devices announce (None: none known)."""
        while not self._replies.empty():  # the answers that came meanwhile, decoded here, not on Zenoh's threads
            try:
                self.learn_reply(*self._replies.get_nowait())
            except queue.Empty:  # (another reader took it)
                break
        return self._layouts.get(subject)

    def decode_pose(self, subject: str, payload: bytes) -> wire.PoseFrame:
        """``wire.decode_pose`` with ``subject``'s layout: WireError ``layout`` for a layout file's
        frame of a subject whose layout is not known (or is another)."""
        return wire.decode_pose(payload, self.layout_of(subject))

    def decode_angles(self, subject: str, payload: bytes) -> wire.JointAngles:
        """``wire.decode_angles`` with ``subject``'s layout (as :meth:`decode_pose`)."""
        return wire.decode_angles(payload, self.layout_of(subject))

    def ask(self, session: zenoh.Session, subject: str) -> bool:
        """Ask ``subject``'s devices for their status, their answers handed off as they come (not
        waited for) and learnt at the next look-up; at most every :data:`ASK_EVERY_S` per subject. Whether it asked."""
        now = time.monotonic()
        with self._lock:
            if now - self._asked.get(subject, -ASK_EVERY_S) < ASK_EVERY_S:
                return False
            if subject not in self._asked and len(self._asked) >= self.max_subjects:
                self._asked.pop(next(iter(self._asked)))
            self._asked[subject] = now

        def on_reply(reply: zenoh.Reply) -> None:  # (on a Zenoh thread: only handed off)
            if reply.ok is not None:
                self._replies.put((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))

        try:
            session.get(wire.device_selector(wire.CONFIG, subject), on_reply, timeout=ASK_TIMEOUT_S)
        except (zenoh.ZError, ValueError):  # a closed session; a subject that is no pattern
            return False
        return True
