"""Samples that arrive at a sender's own irregular times, put on a uniform grid per device, in C
(``firmware_c/host/lsw_grid.c``; the SlimeVR gateway's devices, docs/protocol.md "Timing").

Each device keeps its sender's last 16 samples, a grid of instants one period apart locked to the
lower edge of their arrivals, and its truth samples until they are taken. At each tick every
device takes its sample at its own grid instant: the sample that arrived less than ``late_us``
after it or ``early_us`` before it (that sample's truth is stamped at the instant), else the SLERP
of the two around it, or the newest held for at most ``hold_us``.

Times are microseconds (the gateway's clock) unless named otherwise; quaternions (w, x, y, z).
"""
from __future__ import annotations

import ctypes
from collections.abc import Sequence

import numpy as np

from limbstream.kernel._lib import GRID_JITTER, GRID_TRUTH, GridDevice, GridSettings, _lib


class GridBank:
    """``count`` devices on their grids.

    Parameters
    ----------
    count : devices.
    period_us : grid period.
    hold_us, late_us, early_us : see the module.
    phase_gain : share of a late arrival's offset from its instant the grid moves by.
    rise_after : arrivals after an early one before the grid may move later again.
    axes : (w, x, y, z) turn applied to every sample as it arrives (``axes * q``).
    truth : keep every sample for the truth tap.

    ``devices[k]`` is device k's C record (read its ``held``, ``quiet``, ``last_t``,
    ``truth_len``, ``truth_dropped``; set its ``online``); ``offset_us`` (common time base minus
    the gateway's clock) stamps the truth samples and grid samples. ``settings_ptr`` and
    ``devices_ptr`` are their addresses, for other C code that feeds the bank
    (``lsw_slimevr.c``).
    """

    def __init__(self, count: int, period_us: float, hold_us: float, late_us: float, early_us: float,
                 phase_gain: float, rise_after: int, axes: Sequence[float], truth: bool):
        self.count = count
        self.settings = GridSettings(period_us, hold_us, late_us, early_us, phase_gain, 0.0,
                                     (ctypes.c_double * 4)(*axes), rise_after, int(truth))
        self.devices = (GridDevice * max(count, 1))()
        size = max(count, 1)
        self.have = np.zeros(size, np.uint8)
        self.tick_u32 = np.zeros(size, np.uint32)
        self.stamp = np.zeros(size, np.int64)
        self.y = np.zeros((size, 4), np.float32)
        self._due = np.zeros((2, size), np.uint32)
        self._truth_t = np.zeros(GRID_TRUTH, np.int64)
        self._truth_q = np.zeros((GRID_TRUTH, 4), np.float32)
        self._q = (ctypes.c_double * 4)()
        # addresses taken once: numpy's .ctypes costs microseconds per call
        self.settings_ptr = ctypes.addressof(self.settings)
        self.devices_ptr = ctypes.addressof(self.devices)
        self._size = ctypes.sizeof(GridDevice)
        self._tick_ptrs = tuple(a.ctypes.data for a in (self.have, self.tick_u32, self.stamp, self.y))
        self._due_ptrs = (self._due[0].ctypes.data, self._due[1].ctypes.data)
        self._truth_ptrs = (self._truth_t.ctypes.data, self._truth_q.ctypes.data)

    @property
    def offset_us(self) -> float:
        return self.settings.offset_us

    @offset_us.setter
    def offset_us(self, value: float) -> None:
        self.settings.offset_us = value

    def address(self, k: int) -> int:
        """Address of device k's record (for the C calls that take one)."""
        return self.devices_ptr + k * self._size

    def reset(self, k: int) -> None:
        """Device k starts a new stream: no samples, no grid, no truth (its jitter figure stays)."""
        _lib.lsw_grid_reset(self.address(k))

    def push(self, k: int, t_us: float, q: Sequence[float], now: float) -> None:
        """Device k's sender's sample ``q`` (unit, its axes) arrived at ``t_us``, at monotonic ``now`` (s)."""
        self._q[:] = list(q)
        _lib.lsw_grid_push(self.settings_ptr, self.address(k), t_us, self._q, now)

    def tick(self, m: int, at_us: float) -> int:
        """Devices 0..m-1 at the gateway's grid instant ``at_us``: ``have[:m]`` 1 where a device
        took a sample: ``y[k]`` (turned), ``tick_u32[k]`` (its own instant mod 2**32),
        ``stamp[k]`` (common time base); returns how many took one."""
        return _lib.lsw_grid_tick(self.settings_ptr, self.devices_ptr, m, at_us, *self._tick_ptrs)

    def truth_due(self, m: int, now: float, batch: int, max_age_s: float) -> list[tuple[int, int]]:
        """(device, samples to take) of devices 0..m-1 whose truth is due at monotonic ``now``:
        ``batch`` settled samples (no later tick can restamp them), or some waiting ``max_age_s``."""
        n = _lib.lsw_grid_truth_due(self.settings_ptr, self.devices_ptr, m, now, batch, max_age_s, *self._due_ptrs)
        return list(zip(self._due[0, :n].tolist(), self._due[1, :n].tolist()))

    def take_truth(self, k: int, n: int, now: float) -> tuple[np.ndarray, np.ndarray]:
        """Device k's first ``n`` truth samples, taken: stamps (n,) int64, common time base, made
        non-decreasing; samples (n, 4) float32, turned. The rest wait from monotonic ``now``."""
        n = _lib.lsw_grid_take_truth(self.address(k), n, *self._truth_ptrs, now)
        return self._truth_t[:n].copy(), self._truth_q[:n].copy()

    def jitter_us(self, k: int) -> np.ndarray:
        """Device k's recent |arrival - grid instant| (up to the last 500 arrivals near an instant), us."""
        d = self.devices[k]
        return np.ctypeslib.as_array(d.jitter)[:min(d.jitter_len, GRID_JITTER)].astype(np.float64)

    def history(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Device k's kept samples, oldest first: arrivals (n,) and samples (n, 4), turned."""
        d = self.devices[k]
        order = (d.hist_head + np.arange(d.hist_len)) % len(d.hist_t)
        return np.ctypeslib.as_array(d.hist_t)[order].copy(), np.ctypeslib.as_array(d.hist_q)[order].copy()

    def truth(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Device k's truth samples not taken yet: stamps (n,) and arrivals (n,)."""
        d = self.devices[k]
        n = d.truth_len
        return np.ctypeslib.as_array(d.truth_t)[:n].copy(), np.ctypeslib.as_array(d.truth_a)[:n].copy()
