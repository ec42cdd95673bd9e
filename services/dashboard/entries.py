"""What the dashboard keeps of each device, aggregator and subject's latest pose (owned by the
event loop: :class:`~.state.LiveState`)."""
from __future__ import annotations

import json
from collections import deque
from dataclasses import dataclass, field

from limbstream import wire

HISTORY_FIELDS = wire.HISTORY_FIELDS
"""Per-device series kept for the charts (plus the stats time ``t``): the charted stats fields."""

KINDS = wire.FRAME_KINDS
LATENCY_FRAMES = 500
"""Exact frames per subject the exact-frame latency is taken over (10 s at 50 Hz)."""
ANGLES_HISTORY_S = 20.0
"""Seconds of joint angles kept per subject and kind (received time): the REST history, the page's plots."""


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
