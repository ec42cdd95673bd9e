"""Which pose frames a live output shows: the contract's one frame-kind rule
(:func:`limbstream.wire.auto_kind`): a subject's live frames, and its exact frames only while no
live frame of that subject came for ``wire.AUTO_LIVE_WINDOW_S``.

An aggregator publishes two kinds of pose frames on the same key: exact frames (final, at its
frame rate, about 0.4 s behind) and live frames (at "now", at its live rate; none with
``--live-rate 0``).
"""
from __future__ import annotations

import math
import time

from limbstream import wire

class LiveFirst:
    """The frame-kind rule above, per subject. ``skipped`` counts exact frames passed over."""

    def __init__(self):
        self.last_live: dict[str, float] = {}
        self.skipped = 0

    def wanted(self, subject: str, frame: wire.PoseFrame, now: float | None = None) -> bool:
        """Whether ``frame`` of ``subject`` is shown; ``now``: time.monotonic() seconds."""
        now = time.monotonic() if now is None else now
        if frame.kind == wire.KIND_LIVE:
            self.last_live[subject] = now
            return True
        if wire.auto_kind(now - self.last_live.get(subject, -math.inf)) == wire.KIND_LIVE:
            self.skipped += 1
            return False
        return True
