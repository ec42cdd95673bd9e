"""Fan-out of pose frames to the WebSocket and SSE clients attached to a subject: a bounded queue
per client, the oldest frame skipped (counted) when a client is slow."""
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
    """The clients of a :class:`~.state.LiveState` (mixed into it: reads its latest poses)."""

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

    def _fan_out(self, subject: str, entry: PoseEntry) -> None:
        """Offer a subject's new frame to each of its clients that wants its kind."""
        clients = self.clients.get(subject)
        if clients:
            kind = self.auto_kind(subject)
            for client in clients:
                wanted = kind if client.kind == "auto" else KINDS[client.kind]
                if wanted == entry.frame.kind:
                    client.offer(entry.text(subject))
