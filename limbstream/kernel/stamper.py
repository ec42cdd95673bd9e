"""Common-time stamps of many devices' samples in one C call (lsw_clock.h)."""
from __future__ import annotations

import ctypes

import numpy as np

from limbstream.kernel._lib import _Sync, _lib


class Stamper:
    """Common-time stamps of ``n`` devices' samples with a bounded slew (lsw_clock.h), one C call
    per tick. The caller sets each device's line (``a``, ``b``, ``ref``), ``step`` and ``ever``;
    the stamps keep ``c``, ``c_local`` and ``stepped``.

    Attributes
    ----------
    a, b, ref : (n,) float64 the line: correction ``a + b * (L - ref)`` at device time L (us).
    c, c_local : (n,) float64 correction of each device's last stamp and its device time (NaN: none yet).
    step : (n,) bool the next stamp sets c to the line at once.
    ever : (n,) bool synced once (else a stamp is the device's own time).
    stepped : (n,) bool the device's last stamp was a step.
    """

    def __init__(self, n: int, slew: float):
        self.a, self.b, self.ref, self.c = (np.zeros(n) for _ in range(4))
        self.c_local = np.full(n, np.nan)
        self.step, self.ever, self.stepped = (np.zeros(n, bool) for _ in range(3))
        arrays = (self.a, self.b, self.ref, self.c, self.c_local, self.step, self.ever, self.stepped)
        self._sync = ctypes.pointer(_Sync(*(x.ctypes.data for x in arrays), slew))
        # the call's arguments, in buffers whose addresses are taken once (numpy's .ctypes costs
        # tens of microseconds per tick when the tick loop wakes with cold caches)
        self._slots, self._local, self._out = np.zeros(n, np.int64), np.zeros(n), np.zeros(n)
        self._ptrs = tuple(x.ctypes.data for x in (self._slots, self._local, self._out))

    def stamp(self, slots: np.ndarray, local_us: np.ndarray) -> tuple[np.ndarray, int]:
        """Stamps of samples taken at device times ``local_us`` (K,) float64 us by devices ``slots``
        (K,) (each once, its times increasing over calls): (K,) float64 us (a view, valid until
        the next call), and how many of them were steps (``stepped`` tells which)."""
        k = len(slots)
        self._slots[:k] = slots
        self._local[:k] = local_us
        steps = _lib.lsw_stamp(self._sync, k, *self._ptrs)
        return self._out[:k], int(steps)
