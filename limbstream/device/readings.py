"""Raw sensor feeds: what emulated IMUs read, per tick, for many devices at once.

A :class:`RawFeed` is one subject's sensors as a device feed: its ideal readings at the sensor
rate (:class:`limbstream.imu.ReadingFeed`: the calibration script, then the motion, looped or
played once, or the generator), and, as every feed has, ``sample(k)``: the truth at device sample
``k``, the segments' true orientations at the raw sample that is the device's sample for that
instant. :class:`RawSensors` are the sensors of all devices of a process
(:class:`limbstream.imu.ImuDevices`: mounting, the part's errors) read for one tick in one
vectorised call; the device bank's raw stage fuses what they read
(:class:`limbstream.device.bank.RawStage`).

The sensor rate is a whole multiple of the device rate (200 Hz: 4 raw samples per device
sample), so each tick of the device rate brings every device the same raw samples and its device
instant falls on the first of them.
"""
from __future__ import annotations

import math

import numpy as np

from limbstream import imu
from limbstream.calibration import SensorModel
from limbstream.imu.kinematics import Readings
from limbstream.sources import Motion
from limbstream.sources.generator import GeneratorSource


def raw_per_sample(rate_hz: float, fs: float) -> int:
    """Raw samples per device sample; ValueError unless ``rate_hz`` is a whole multiple of the
    device rate ``fs``."""
    per = rate_hz / fs
    if not (math.isfinite(per) and per >= 1 and abs(per - round(per)) < 1e-9):
        raise ValueError(f"--imu-rate must be a whole multiple of the device rate {fs:g} Hz, got {rate_hz:g}")
    return int(round(per))


class RawFeed:
    """One subject's sensors at ``rate_hz``, ticked at the device rate ``fs``.

    Parameters
    ----------
    source : a recorded Motion (uniform rate) or the built-in GeneratorSource.
    rate_hz : sensor rate, Hz (a whole multiple of ``fs``).
    fs : device rate, Hz.
    once : play a recording once (``length`` device samples) instead of looping it.
    """

    orientations = "sensors"  # wire.ORIENTATIONS: a device fuses its sensor's readings

    def __init__(self, source: Motion | GeneratorSource, rate_hz: float, fs: float, once: bool = False):
        self.per = raw_per_sample(rate_hz, fs)
        self.readings_feed = imu.ReadingFeed(source, rate_hz, once=once)
        self.segments, self.rest_pose = self.readings_feed.segments, self.readings_feed.rest_pose
        self.body = getattr(source, "body", None)  # a recording's wearer (the generator's: the default adult)
        raw = self.readings_feed.length
        self.length = None if raw is None else -(-raw // self.per)  # device instants on raw samples 0, per, ...
        self._tick: tuple[int, Readings] | None = None

    def tick(self, k: int) -> Readings:
        """The ideal readings of device sample k's raw samples (``per`` of them, fewer at the end
        of a finite feed), cached: every device of the subject asks for them."""
        if self._tick is None or self._tick[0] != k:
            j = k * self.per + np.arange(self.per)
            if self.readings_feed.length is not None:
                j = j[j < self.readings_feed.length]
            self._tick = (k, self.readings_feed.readings(j))
        return self._tick[1]

    def sample(self, k: int) -> np.ndarray:
        """(S, 4) float32 the segments' true orientations at device sample k (the truth tap)."""
        if self.length is not None and not 0 <= k < self.length:
            raise IndexError(f"sample {k} of a {self.length}-sample stream")
        return self.tick(k).q[0].astype(np.float32)


class RawSensors:
    """The sensors of every device of a process, in slot order.

    Parameters
    ----------
    feeds : the subjects' feeds in slot order; each has one device per segment, in its order.
    model : the part (:func:`limbstream.imu.model`).
    rate_hz : sensor rate, Hz.
    sensors : mounting and heading bounds and their seed (``yaw_drift_dps`` 0).
    stream : keeps the draws of several emulators apart.

    Attributes
    ----------
    devices : the :class:`limbstream.imu.ImuDevices` (``heading``: each filter's start heading).
    """

    def __init__(self, feeds: list[RawFeed], model: imu.ImuModel, rate_hz: float, sensors: SensorModel | None = None,
                 stream: int = 0):
        self.feeds = feeds
        self.per = feeds[0].per if feeds else 1
        self._feed = np.concatenate([np.full(len(f.segments), i) for i, f in enumerate(feeds)]).astype(np.int64)
        self._column = np.concatenate([np.arange(len(f.segments)) for f in feeds]).astype(np.int64)
        self.devices = imu.ImuDevices(len(self._feed), model, rate_hz, sensors, stream)

    def read(self, k: int, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What devices ``slots`` (j,) read over device sample k's raw samples.

        Returns
        -------
        gyr, acc : (per, j, 3) float64 rad/s and m/s^2, in each sensor's frame (a feed that ended
            gives NaN rows: those devices take no sample).
        """
        slots = np.asarray(slots, np.int64)
        per, j = self.per, len(slots)
        ideal_g = np.full((per, j, 3), np.nan)
        ideal_a = np.full((per, j, 3), np.nan)
        feed_of = self._feed[slots]
        for i in np.unique(feed_of):
            mine = np.flatnonzero(feed_of == i)
            r = self.feeds[i].tick(k)
            n = len(r.t)
            ideal_g[:n, mine] = r.gyr[:, self._column[slots[mine]]]
            ideal_a[:n, mine] = r.acc[:, self._column[slots[mine]]]
        raw = k * per + np.arange(per)
        g, a = self.devices.read(np.tile(slots, per), np.repeat(raw, j), ideal_g.reshape(-1, 3), ideal_a.reshape(-1, 3))
        return g.reshape(per, j, 3), a.reshape(per, j, 3)
