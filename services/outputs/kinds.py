"""Which pose frames a live output shows: live frames when the subject has them, else exact ones.

An aggregator publishes two kinds of pose frames on the same key: exact frames (final, at its
frame rate, about 0.4 s behind) and live frames (at "now", at its live rate; none with
``--live-rate 0``). An avatar or a 3-D view wants "now": it takes a subject's live frames, and its
exact frames only while no live frame of that subject came for :data:`LIVE_WINDOW_S`.
"""
from __future__ import annotations

import math
import time

from limbstream import wire

LIVE_WINDOW_S = 1.0
"""Seconds without a live frame of a subject after which its exact frames are shown."""


class LiveFirst:
    """The frame-kind rule above, per subject. ``skipped`` counts exact frames passed over."""

    def __init__(self, window_s: float = LIVE_WINDOW_S):
        self.window_s = window_s
        self.last_live: dict[str, float] = {}
        self.skipped = 0

    def wanted(self, subject: str, frame: wire.PoseFrame, now: float | None = None) -> bool:
        """Whether ``frame`` of ``subject`` is shown; ``now``: time.monotonic() seconds."""
        now = time.monotonic() if now is None else now
        if frame.kind == wire.KIND_LIVE:
            self.last_live[subject] = now
            return True
        if now - self.last_live.get(subject, -math.inf) < self.window_s:
            self.skipped += 1
            return False
        return True
