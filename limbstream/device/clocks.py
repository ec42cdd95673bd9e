"""Device clocks (docs/reliability.md, "Device clocks") and the true time they are measured
against.

- :class:`DeviceClocks`: every emulated device's own clock, vectorised: a fixed offset drawn
  uniform in +-MAX, a drift drawn uniform in +-MAX ppm (seeded), optional read jitter uniform
  in +-J. A device samples on its own clock's grid (a random phase after boot), so a fast clock
  takes more samples than a slow one.
- :class:`TimeBase`: "true" time, the host clock scaled by ``--speed`` around an anchor; it is
  what the time service serves and what the truth tap's reference times carry.

Times are microseconds.
"""
from __future__ import annotations

import random
import time
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClockSettings:
    """Clocks and sync of the devices of one process (a gateway has one clock: its own).

    Attributes
    ----------
    offset_ms, drift_ppm : each device's offset and drift are drawn uniform in +- these.
    jitter_us : every clock read is off by uniform +- this (stamps and exchange times).
    seed : seed of the draws (with the first subject number: distinct per emulator process).
    sync : run the time exchange (else devices stamp with their own clock).
    poll_s : longest interval between exchanges, device seconds.
    holdover_s : a device without a valid answer for this long reports itself unsynced.
    wait_s : at start, wait this long (wall seconds) at most for the first exchanges.
    timeout_s : a time query without an answer for this long counts as lost (wall seconds).
    """

    offset_ms: float = 0.0
    drift_ppm: float = 0.0
    jitter_us: float = 0.0
    seed: int = 0
    sync: bool = True
    poll_s: float = 512.0
    holdover_s: float = 600.0
    wait_s: float = 10.0
    timeout_s: float = 1.0

    @property
    def modelled(self) -> bool:
        """Devices have clocks of their own (not the emulation's true clock)."""
        return self.offset_ms > 0 or self.drift_ppm > 0 or self.jitter_us > 0


class TimeBase:
    """The emulation's true time: ``anchor + speed * (host clock - anchor)``, us.

    Parameters
    ----------
    speed : time scale (1: the host clock).
    anchor_us : the instant the scaled time agrees with the host clock (processes that share a
        time base at speed != 1 must share it), us since the epoch; None: now.
    """

    def __init__(self, speed: float = 1.0, anchor_us: float | None = None):
        self.speed = float(speed)
        self.anchor_us = float(time.time_ns() / 1e3 if anchor_us is None else anchor_us)

    def now_us(self) -> float:
        return self.anchor_us + self.speed * (time.time_ns() / 1e3 - self.anchor_us)


class DeviceClocks:
    """The local clocks of ``n`` devices: ``local(T) = T + offset + drift * (T - boot)``.

    Attributes
    ----------
    offset_us, drift, phase_us : (n,) float64: offset at boot (us), drift (fraction), phase of
        the sampling grid after boot (us, in [0, period)).
    boot_us : true time of boot (set by :meth:`boot`).
    """

    def __init__(self, n: int, settings: ClockSettings, period_us: float, base: TimeBase, seed: int = 0):
        rng = np.random.default_rng([settings.seed, seed])
        self.settings, self.period_us, self.base = settings, float(period_us), base
        self.offset_us = rng.uniform(-1, 1, n) * settings.offset_ms * 1e3
        self.drift = rng.uniform(-1, 1, n) * settings.drift_ppm * 1e-6
        self.phase_us = rng.uniform(0, period_us, n) if settings.modelled else np.zeros(n)
        self.max_drift = settings.drift_ppm * 1e-6
        self.boot_us = self.grid_us = 0.0
        self.grid_local = np.zeros(n)
        self._jitter = random.Random(settings.seed)

    def boot(self, true_us: float) -> None:
        """The devices power up at true time ``true_us`` (their drift counts from then)."""
        self.boot_us = float(true_us)

    def start_grid(self, true_us: float) -> None:
        """The devices start sampling at true time ``true_us``: sample 0 of each is taken at its
        first grid point after it (its phase)."""
        self.grid_us = float(true_us)
        self.grid_local = self.local(self.grid_us)

    def local(self, true_us, slots=slice(None)) -> np.ndarray:
        """Local clocks of ``slots`` at true time(s) ``true_us`` (no jitter), us."""
        return true_us + self.offset_us[slots] + self.drift[slots] * (true_us - self.boot_us)

    def jitter(self, n: int) -> np.ndarray:
        j = self.settings.jitter_us
        return np.zeros(n) if j <= 0 else np.random.default_rng(self._jitter.getrandbits(64)).uniform(-j, j, n)

    def read(self, slot: int) -> int:
        """Device ``slot`` reads its clock now (with jitter), us (any thread)."""
        t = self.base.now_us()
        j = self.settings.jitter_us
        noise = self._jitter.uniform(-j, j) if j > 0 else 0.0
        return int(round(t + self.offset_us[slot] + self.drift[slot] * (t - self.boot_us) + noise))

    def sample_time(self, n: np.ndarray, slots) -> np.ndarray:
        """True time at which sample ``n`` of each device is taken: its local grid point
        (:meth:`sample_local`) mapped back to true time, us."""
        return self.grid_us + (self.phase_us[slots] + n * self.period_us) / (1.0 + self.drift[slots])

    def sample_local(self, n: np.ndarray, slots) -> np.ndarray:
        """Local time of sample ``n``: ``local(grid start) + phase + n * period``, us."""
        return self.grid_local[slots] + self.phase_us[slots] + n * self.period_us

    def describe(self, names: list[str]) -> list[str]:
        return [f"clock {name}: offset {o / 1e3:+.3f} ms, drift {d * 1e6:+.2f} ppm"
                for name, o, d in zip(names, self.offset_us, self.drift)]
