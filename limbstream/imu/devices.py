"""Emulated IMUs, one per device: mounting, filter start heading and a part's errors.

Each device's sensor sits on its segment turned by its mounting ``m`` (segment <- sensor, drawn
by :class:`limbstream.calibration.SensorModel` as for modelled sensors: the same seed gives the
same mountings), so it reads its segment's ideal readings turned into its own frame
(``m^-1 v m``), then its part's errors (:mod:`.models`). Everything a device draws is a function
of (seed, stream, device index) alone and its noise of the sample number too, so a device reads
the same whether its samples are asked for one tick at a time or for a whole recording.

Heading. Raw readings do not depend on where the world faces (turning the motion about the
vertical leaves every angular rate and specific force unchanged), so ``--heading-deg`` cannot be
in the readings: it is the fusion filter's. VQF 6D starts its earth frame at the sensor's own
heading at switch-on, so headings are arbitrary already; a device's filter is turned further by
its drawn heading ``h``: VQF with its gyroscope quaternion set to :func:`earth_heading` ``(h)``
before the first sample. That is turning every output by ``earth_heading(h)`` on the left, but for
VQF's motion bias estimate, which clips its correction per earth axis (tests/test_imu.py: 1e-5 deg
without it, 0.05 deg with it). The heading then drifts with the gyroscope offset the filter has not
learned; ``--yaw-drift-dps``, the modelled sensors' drift formula, has no meaning here.
"""
from __future__ import annotations

import numpy as np

from limbstream import quat
from limbstream.calibration import SensorModel, axis_angle
from limbstream.imu.kinematics import GRAVITY
from limbstream.imu.models import WARMUP_C, WARMUP_TAU_S, ImuModel

BLOCK = 256
"""Noise samples per independently seeded block (each device caches its current block)."""
_KEY = 0x1A70
"""Keeps the parts' draws apart from the sensor model's (which use [seed, stream])."""


def earth_heading(angle_rad: np.ndarray) -> np.ndarray:
    """(..., 4) rotations about the earth's vertical (Z) by ``angle_rad`` (...): a device's filter
    start heading."""
    return axis_angle(np.array([0.0, 0.0, 1.0]), angle_rad)


class ImuDevices:
    """``n`` emulated IMUs of one part at one rate.

    Parameters
    ----------
    n : number of devices.
    model : the part (:data:`limbstream.imu.models.MODELS`).
    rate : sensor rate, Hz (the noise bandwidth is half of it).
    sensors : mounting and heading bounds and the seed (``yaw_drift_dps`` must be 0).
    stream : keeps the draws of several emulators apart (as :meth:`SensorModel.draw`'s).

    Attributes
    ----------
    mounting : (n, 4) segment <- sensor.
    heading : (n,) the filters' start headings, rad.
    gyro_offset, accel_offset : (n, 3) turn-on offsets, rad/s and m/s^2.
    gyro_tempco, accel_tempco : (n, 3) offset change per degC, rad/s and m/s^2.
    """

    def __init__(self, n: int, model: ImuModel, rate: float, sensors: SensorModel | None = None, stream: int = 0):
        sensors = sensors or SensorModel()
        if sensors.yaw_drift_dps > 0:
            raise ValueError("--yaw-drift-dps is the modelled sensors' drift formula; raw sensors drift with "
                             "their gyroscope offset (use --imu-model)")
        if not rate > 0:
            raise ValueError(f"sensor rate must be > 0 Hz, got {rate}")
        self.model, self.rate, self.n = model, float(rate), n
        drawn = sensors.draw(n, stream)
        self.mounting, self.heading = drawn.mounting, drawn.heading
        self._keys = [[sensors.seed, stream, _KEY, d] for d in range(n)]
        u = np.array([np.random.default_rng(key).uniform(-1.0, 1.0, 12) for key in self._keys]).reshape(n, 4, 3)
        mg = 1e-3 * GRAVITY
        self.gyro_offset = np.radians(model.gyro_offset_dps) * u[:, 0]
        self.gyro_tempco = np.radians(model.gyro_tempco_dps_c) * u[:, 1]
        self.accel_offset = model.accel_offset_mg * mg * u[:, 2]
        self.accel_tempco = model.accel_tempco_mg_c * mg * u[:, 3]
        band = np.sqrt(self.rate / 2.0)
        self._sigma = band * np.concatenate([np.full(3, np.radians(model.gyro_noise_dps_rthz)),
                                             np.asarray(model.accel_noise_ug_rthz) * 1e-6 * GRAVITY])
        self._noisy = bool(np.any(self._sigma > 0))
        self._cache = np.zeros((n if self._noisy else 0, BLOCK, 6), np.float32)
        self._block = np.full(n, -1, np.int64)

    def read(self, devices: np.ndarray, k: np.ndarray, gyr: np.ndarray, acc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What the devices read for their segments' ideal readings.

        Parameters
        ----------
        devices : (m,) int device indices (any order, repeats allowed: one entry per sample).
        k : (m,) int sample numbers since each device's switch-on (its time is ``k / rate``).
        gyr, acc : (m, 3) the ideal segment-frame readings (:class:`.kinematics.Readings`).

        Returns
        -------
        gyr : (m, 3) float64 rad/s and acc : (m, 3) float64 m/s^2 in each sensor's frame, on
        the part's 16-bit grid (where it has a range).
        """
        devices = np.asarray(devices, np.int64)
        k = np.asarray(k, np.int64)
        back = quat.conjugate(self.mounting[devices])
        g, a = quat.rotate(back, gyr), quat.rotate(back, acc)
        warm = WARMUP_C * (1.0 - np.exp(-(k / self.rate) / WARMUP_TAU_S))[:, None]
        g = g + self.gyro_offset[devices] + self.gyro_tempco[devices] * warm
        a = a + self.accel_offset[devices] + self.accel_tempco[devices] * warm
        if self._noisy:
            noise = self._noise(devices, k) * self._sigma
            g, a = g + noise[:, :3], a + noise[:, 3:]
        m = self.model
        if m.gyro_range_dps is not None:
            g = _quantise(g, np.radians(m.gyro_range_dps), m.bits)
        if m.accel_range_g is not None:
            a = _quantise(a, m.accel_range_g * GRAVITY, m.bits)
        return g, a

    def _noise(self, devices: np.ndarray, k: np.ndarray) -> np.ndarray:
        """(m, 6) standard normal noise (gyro x y z, accel x y z) of each (device, sample)."""
        block, row = np.divmod(k, BLOCK)
        out = np.empty((len(k), 6))
        hit = self._block[devices] == block
        out[hit] = self._cache[devices[hit], row[hit]]
        if not hit.all():
            pairs, which = np.unique(np.stack([devices[~hit], block[~hit]], axis=1), axis=0, return_inverse=True)
            fresh = np.stack([np.random.default_rng(self._keys[d] + [1 + int(b)]).standard_normal((BLOCK, 6))
                              for d, b in pairs.tolist()]).astype(np.float32)
            out[~hit] = fresh[which.reshape(-1), row[~hit]]
            last = np.append(pairs[1:, 0] != pairs[:-1, 0], True)  # each device's last block (sorted pairs)
            self._cache[pairs[last, 0]] = fresh[last]
            self._block[pairs[last, 0]] = pairs[last, 1]
        return out


def _quantise(values: np.ndarray, full_scale: float, bits: int) -> np.ndarray:
    """``values`` rounded to the grid of a ``bits``-bit word spanning +-``full_scale`` and
    saturated at its ends."""
    lsb = full_scale / 2 ** (bits - 1)
    counts = np.clip(np.round(values / lsb), -(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
    return counts * lsb
