"""Python binding of the C kernels in ``firmware_c/`` (built into ``limbstream._kernels``).

Offline use: :func:`segment` runs a whole stream through one algorithm.
Streaming use (one device): :class:`Segmenter`. Many devices per tick: :class:`SegmenterBank`,
and their samples' common-time stamps: :class:`Stamper`. Raw IMU samples fused on the device
(VQF): :func:`fuse` offline, :class:`ImuBank` for many devices' raw-sample pipelines. Senders at their own irregular times put
on a uniform grid per device: :class:`GridBank`.

Live rule (fastSW, ``live_bound_deg`` > 0; docs/kernel.md): every segment point carries a body
angular rate ``omega`` (rad/s), and a receiver's live view of time t is
``limbstream.quat.predict(q_point, omega, t - t_point)`` from the newest point it has; the
kernel keeps every sample within ``live_bound_deg`` of that view.

Time: the kernels take ``uint32`` ticks (microseconds here, ``TICK_HZ``); only ratios of
time differences enter the SSR, so the unit does not change the result. Seconds are
converted with :func:`to_ticks`, relative to the first sample, modulo 2**32.
"""
from __future__ import annotations

from limbstream.kernel._lib import (LIVE_BOUND, MAX_DIM, NONE, POINT, REJECTED, STATE_SIZE, SW_STATE_SIZE, TICK_HZ,
                                    BankWire, BatchOut, GridDevice, Point, Settings, SvrTracker, body_rates,
                                    live_rule, make_settings, to_ticks)
from limbstream.kernel._lib import _lib  # noqa: F401  (the library itself, for the tests of its C functions)
from limbstream.kernel.fusion import ImuBank, fuse
from limbstream.kernel.grid import GridBank
from limbstream.kernel.offline import ALGORITHMS, Segmentation, segment
from limbstream.kernel.stamper import Stamper
from limbstream.kernel.streaming import Segmenter, SegmenterBank

__all__ = ["ALGORITHMS", "LIVE_BOUND", "MAX_DIM", "NONE", "POINT", "REJECTED", "STATE_SIZE", "SW_STATE_SIZE",
           "TICK_HZ", "BankWire", "BatchOut", "GridBank", "GridDevice", "ImuBank", "Point", "Segmentation", "Segmenter", "SegmenterBank", "Settings",
           "Stamper", "SvrTracker", "body_rates", "fuse", "live_rule", "make_settings", "segment",
           "to_ticks"]
