"""The hand-off from Zenoh threads to the dashboard's event loop.

Zenoh callbacks run on Zenoh threads. They only put the raw payload into an :class:`Inbox`
(bounded deques; when the loop falls behind, the oldest pose frames and joint angles are skipped
and counted)
and, at most once until it runs, schedule the drain (:meth:`~.state.LiveState.drain`) on the
event loop with ``loop.call_soon_threadsafe``. Decoding and everything after it happen on the
loop.
"""
from __future__ import annotations

import asyncio
import threading
import time
from collections import Counter, deque


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
        self.angles: deque[tuple[float, str, bytes]] = deque()
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

    def put_angles(self, key: str, payload: bytes) -> None:
        with self._lock:
            if len(self.angles) >= self.max_pending:
                self.angles.popleft()  # the loop is behind: skip the oldest
                self.dropped["angles"] += 1
            self.angles.append((time.time(), key, payload))
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
            angles, self.angles = self.angles, deque()
            self._scheduled = False
        return stats, alive, poses, angles
