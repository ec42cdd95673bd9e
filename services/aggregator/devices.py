"""The columns every tick reads: per device slot (its subject, liveliness, newest times, live
horizon, settled) and per subject (the device slot of each segment), kept
current as messages arrive so that a tick reads all devices in a few NumPy calls."""
from __future__ import annotations

import numpy as np

from limbstream.wire import SEGMENTS

NO_TIME = np.iinfo(np.int64).min
"""A time column's value where there is none (int64 min)."""
SEGMENT_INDEX = {name: i for i, name in enumerate(SEGMENTS)}


class DeviceTable:
    """Per device slot (rows in the order devices were first seen; the point store's rows):

    - ``owner`` (slots,) int64 subject index;
    - ``online`` (slots,) bool: liveliness token present; ``active``: online and its stream not ended;
    - ``latest_t`` (slots,) int64 newest device time of a point or truth sample, us (NO_TIME: none);
      ``latest_arrival`` (slots,) float64 arrival clock when it arrived, s (NaN: none);
    - ``last_raw_t`` (slots,) int64 newest truth sample time, us (NO_TIME: none);
    - ``horizon_us`` (slots,) int64 longest extrapolation of the newest point in a live frame;
    - ``settled`` (slots,) bool: DeviceTrack.settled, as last refreshed.

    Per subject: ``seg_slots`` (subjects, 10) int64 device slot of each segment (SEGMENTS order), -1
    where the subject has no such device.
    """

    def __init__(self) -> None:
        self.seg_slots = np.full((0, len(SEGMENTS)), -1, np.int64)
        self.owner = np.zeros(0, np.int64)
        self.online = np.zeros(0, bool)
        self.active = np.zeros(0, bool)
        self.latest_t = np.zeros(0, np.int64)
        self.latest_arrival = np.zeros(0)
        self.last_raw_t = np.zeros(0, np.int64)
        self.horizon_us = np.zeros(0, np.int64)
        self.settled = np.zeros(0, bool)

    def __len__(self) -> int:
        return len(self.owner)

    def add_subject(self) -> int:
        """A new subject without devices; returns its index."""
        self.seg_slots = np.vstack([self.seg_slots, np.full((1, len(SEGMENTS)), -1, np.int64)])
        return len(self.seg_slots) - 1

    def add_device(self, subject: int, segment: str, horizon_us: int) -> int:
        """A new device of ``subject`` (offline, no data yet); returns its slot."""
        slot = len(self.owner)
        for name, value in (("owner", subject), ("online", False), ("active", False),
                            ("latest_t", NO_TIME), ("latest_arrival", np.nan), ("last_raw_t", NO_TIME),
                            ("horizon_us", horizon_us), ("settled", True)):
            setattr(self, name, np.append(getattr(self, name), value))
        if segment in SEGMENT_INDEX:
            self.seg_slots[subject, SEGMENT_INDEX[segment]] = slot
        return slot

    def new_stream(self, slot: int) -> None:
        """The device in ``slot`` began a new stream: no data of it yet."""
        self.latest_t[slot] = self.last_raw_t[slot] = NO_TIME
