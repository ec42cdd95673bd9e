"""Fan-out of pose frames to the WebSocket and SSE clients attached to a subject: a bounded queue
per client, the oldest frame skipped (counted) when a client is slow. The live state
(:class:`~.state.LiveState`) holds one and offers it every new frame."""
from __future__ import annotations

import asyncio

from .entries import KINDS, PoseEntry


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


class FanOut:
    """The WebSocket and SSE clients of each subject and the frames offered to them.

    Parameters
    ----------
    queue_size : frames each client's queue holds.
    """

    def __init__(self, queue_size: int):
        self.queue_size = queue_size
        self.clients: dict[str, set[PoseClient]] = {}
        self.skipped = 0  # frames skipped for the clients that left

    def add(self, subject: str, kind: str, latest: PoseEntry | None) -> PoseClient:
        """A new client of ``subject``'s frames of ``kind``, offered ``latest`` (its first frame) at once."""
        client = PoseClient(subject, kind, self.queue_size)
        self.clients.setdefault(subject, set()).add(client)
        if latest is not None:
            client.offer(latest.text(subject))
        return client

    def remove(self, client: PoseClient) -> None:
        group = self.clients.get(client.subject)
        if group is not None:
            group.discard(client)
            if not group:
                del self.clients[client.subject]
        self.skipped += client.skipped

    def count(self) -> int:
        return sum(len(g) for g in self.clients.values())

    def skipped_total(self) -> int:
        """Frames skipped for slow clients, those still here and those that left."""
        return self.skipped + sum(c.skipped for g in self.clients.values() for c in g)

    def watched(self, subject: str) -> bool:
        """Some client takes ``subject``'s frames."""
        return bool(self.clients.get(subject))

    def publish(self, subject: str, entry: PoseEntry, auto_kind: int) -> None:
        """Offer a subject's new frame to each of its clients that wants its kind (``auto``
        clients: ``auto_kind``, the kind ``auto`` shows now)."""
        for client in self.clients.get(subject, ()):
            wanted = auto_kind if client.kind == "auto" else KINDS[client.kind]
            if wanted == entry.frame.kind:
                client.offer(entry.text(subject))
