"""A device's estimate of the common time base from four-timestamp exchanges with the time
service (docs/protocol.md, "Time exchange"): what a device runs, emulated or real.

:class:`SyncEstimator`: a sliding window of exchanges, weighted by their round trip (the
shortest round trips carry the smallest asymmetry), fitted with a line (offset and drift);
answers inconsistent with that line are held back until JUMP_CONFIRM agree (a service clock
jump), then followed. Times are microseconds.
"""
from __future__ import annotations

import collections
import math

import numpy as np

from limbstream import wire

WINDOW = 96
"""Exchanges kept per device (the newest)."""
MIN_SPREAD_US = 2e6
"""The drift is fitted only once the weighted exchanges span at least this much (std of their
times), else the previous drift stands."""
MAX_DRIFT = 2e-3
"""Largest drift a fit may report (2000 ppm); beyond it is treated as noise (clipped)."""
JUMP_FLOOR_US = 1000.0
"""An answer is held back as a possible service jump when its offset is further from the fit
than the two could be apart, whatever the path's asymmetry (half its round trip and half the
window's shortest one), plus max(4 x jitter, this)."""
JUMP_CONFIRM = 3
"""Held-back answers that must agree before the device follows a service jump."""
SANE_US = 10e6
"""A synced device discards answers more than 10 s from its estimate (``future`` / ``past``)."""


class SyncEstimator:
    """One device's estimate of the common time base from its exchanges.

    The correction ``service - local`` at local time ``L`` is ``a + b * (L - ref)``. Each
    exchange gives the offset at its midpoint, off by at most half its round-trip excess
    over the shortest one seen; a weighted least-squares line through the window
    (weights 1 / (eps^2 + (excess / 2)^2), eps the floor of that bound) gives ``a`` and the
    drift ``b``.
    """

    def __init__(self, window: int = WINDOW):
        self.x: collections.deque[float] = collections.deque(maxlen=window)      # midpoint, local us
        self.theta: collections.deque[float] = collections.deque(maxlen=window)  # offset, us
        self.delay: collections.deque[float] = collections.deque(maxlen=window)  # round trip, us
        self.a = self.b = self.ref = 0.0
        self.fitted = False
        self.jitter = math.inf
        self.drift_se = math.inf   # standard error of b
        self.offset_se = math.inf  # standard error of the line at the newest exchange, us
        self.held: list[tuple[float, float, float]] = []

    def __len__(self) -> int:
        return len(self.x)

    def predict(self, local_us: float) -> float:
        return self.a + self.b * (local_us - self.ref)

    def add(self, t1: float, t2: float, t3: float, t4: float) -> str:
        """Take one exchange. Returns ``ok``, ``held`` (inconsistent with the fit: a possible
        service jump, not used yet), ``jump`` (JUMP_CONFIRM such answers agree: the window starts
        over from them), or a discard reason: ``negative_rtt``, ``future``, ``past``."""
        theta, delay = wire.offset_delay(t1, t2, t3, t4)
        if delay < 0:
            return "negative_rtt"
        x = (t1 + t4) / 2.0
        if self.fitted:
            residual = theta - self.predict(x)
            if abs(residual) > SANE_US:
                return "future" if residual > 0 else "past"
            # an exchange's offset is off by at most half its round trip (all of it on one side),
            # the line by about half the best one's: only answers further off than both allow
            # are a jump (half the round-trip excess alone, as NTP's filter weighs answers, holds
            # back the answers the jitter happens to skew, and three of them "agree")
            slack = max(4.0 * self.jitter, JUMP_FLOOR_US)
            if abs(residual) > (delay + min(self.delay)) / 2.0 + slack:
                self.held.append((x, theta, delay))
                if len(self.held) < JUMP_CONFIRM:
                    return "held"
                shifted = [th - self.b * (hx - x) for hx, th, _ in self.held]
                if max(shifted) - min(shifted) > max(d for _, _, d in self.held) + slack:
                    self.held = self.held[1:]
                    return "held"
                for window in (self.x, self.theta, self.delay):
                    window.clear()
                for hx, th, d in self.held:
                    self._append(hx, th, d)
                self.held = []
                self._fit()
                return "jump"
        self.held = []
        self._append(x, theta, delay)
        self._fit()
        return "ok"

    def _append(self, x: float, theta: float, delay: float) -> None:
        self.x.append(x)
        self.theta.append(theta)
        self.delay.append(delay)

    def _fit(self) -> None:
        ref = self.x[-1]
        x = np.fromiter(self.x, float, len(self.x)) - ref
        y = np.fromiter(self.theta, float, len(self.x))
        excess = np.fromiter(self.delay, float, len(self.x))
        excess -= excess.min()
        eps = max(25.0, float(np.partition(excess, len(excess) // 4)[len(excess) // 4]) / 2.0)
        w = 1.0 / (eps * eps + (excess / 2.0) ** 2)
        sw = w.sum()
        mx, my = float(w @ x) / sw, float(w @ y) / sw
        sxx = float(w @ (x - mx) ** 2) / sw
        neff = sw * sw / float(w @ w)
        fitted_b = len(x) >= 3 and neff >= 3.0 and sxx >= MIN_SPREAD_US ** 2
        if fitted_b:
            self.b = min(MAX_DRIFT, max(-MAX_DRIFT, float(w @ ((x - mx) * (y - my))) / sw / sxx))
        self.a, self.ref = my - self.b * mx, ref
        if len(x) >= 3:
            self.jitter = math.sqrt(float(w @ (y - self.a - self.b * x) ** 2) / sw)
            self.offset_se = max(self.jitter, 1.0) / math.sqrt(max(neff - 2.0, 1.0))
            if fitted_b:
                self.drift_se = max(self.jitter, 1.0) / math.sqrt(max(neff - 2.0, 1.0) * sxx)
        self.fitted = True
