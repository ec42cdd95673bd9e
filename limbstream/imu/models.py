"""Named IMU parts: the errors an emulated sensor adds to its ideal readings.

``ideal`` adds none (no noise, bias, quantisation or range). ``icm42688p`` is TDK InvenSense's
ICM-42688-P, from its datasheet (DS-000347, Table 1 "Gyroscope specifications" and Table 2
"Accelerometer specifications"), at its widest full-scale ranges (body motion reaches 1,000 deg/s
in an arm swing and more than 8 g at a foot strike):

=========================  ====================  ==========================
quantity                   gyroscope             accelerometer
=========================  ====================  ==========================
full-scale range           +-2000 deg/s          +-16 g
ADC word                   16 bits               16 bits
noise spectral density     0.0028 deg/s/sqrt(Hz) 65 (x, y), 70 (z) ug/sqrt(Hz)
initial (turn-on) offset   +-0.5 deg/s           +-20 mg
offset change with temp.   +-0.005 deg/s/degC    +-0.15 mg/degC
=========================  ====================  ==========================

How they are applied (:class:`limbstream.imu.devices.ImuDevices`):

- white noise of standard deviation ``density * sqrt(rate / 2)`` per sample (the density over the
  Nyquist band: the datasheet's total RMS noise is its density times the square root of its
  bandwidth);
- a turn-on offset per device and axis, uniform within the datasheet's tolerance;
- the datasheet gives no in-run bias instability; what moves a body-worn sensor's offset is its
  warming from room to skin temperature, so each device and axis draws a temperature coefficient
  uniform within the datasheet's, and its sensor warms by :data:`WARMUP_C` with a time constant
  of :data:`WARMUP_TAU_S` after switch-on (both assumed: a small strapped case against skin);
- readings rounded to the 16-bit word at the full scale (``range / 32768`` per count) and
  saturated at its ends.

Not modelled: sensitivity (scale factor) and cross-axis errors, nonlinearity, vibration
rectification, the magnetometer (the part has none).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from limbstream.imu.kinematics import GRAVITY

WARMUP_C = 10.0
"""Temperature rise of a strapped sensor from switch-on to steady state, degC (room to skin)."""
WARMUP_TAU_S = 300.0
"""Time constant of that warming, s."""


@dataclass(frozen=True)
class ImuModel:
    """One part's error budget (all zero and ranges None: the ideal sensor).

    Attributes
    ----------
    name : the model's name (``--imu-model``).
    datasheet : where the numbers come from.
    gyro_range_dps, accel_range_g : full-scale range (+-), None: unlimited and not quantised.
    bits : ADC word length at the full scale.
    gyro_noise_dps_rthz : rate noise spectral density, deg/s/sqrt(Hz).
    accel_noise_ug_rthz : (3,) noise spectral density per axis, ug/sqrt(Hz).
    gyro_offset_dps, accel_offset_mg : turn-on offset tolerance (+-), per axis.
    gyro_tempco_dps_c, accel_tempco_mg_c : offset change with temperature (+-), per degC.
    """

    name: str
    datasheet: str = ""
    gyro_range_dps: float | None = None
    accel_range_g: float | None = None
    bits: int = 16
    gyro_noise_dps_rthz: float = 0.0
    accel_noise_ug_rthz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_offset_dps: float = 0.0
    accel_offset_mg: float = 0.0
    gyro_tempco_dps_c: float = 0.0
    accel_tempco_mg_c: float = 0.0

    def at_full_scale(self, gyr: np.ndarray, acc: np.ndarray) -> np.ndarray:
        """(n,) bool: the samples with a reading at the part's full scale (within its last count),
        of angular rates ``gyr`` (n, 3) rad/s and specific forces ``acc`` (n, 3) m/s^2. Such a
        sample is clipped: the motion may have gone beyond it. All False for an unlimited part."""
        hits = np.zeros(len(gyr), bool)
        for values, full in ((gyr, self.gyro_range_dps and np.radians(self.gyro_range_dps)),
                             (acc, self.accel_range_g and self.accel_range_g * GRAVITY)):
            if full:
                hits |= (np.abs(values) >= full * (1 - 2.0 ** (1 - self.bits))).any(axis=1)
        return hits


MODELS: dict[str, ImuModel] = {
    "ideal": ImuModel("ideal", "none: the readings of the motion itself"),
    "icm42688p": ImuModel(
        "icm42688p", "TDK InvenSense ICM-42688-P datasheet DS-000347, Tables 1 and 2",
        gyro_range_dps=2000.0, accel_range_g=16.0, bits=16,
        gyro_noise_dps_rthz=0.0028, accel_noise_ug_rthz=(65.0, 65.0, 70.0),
        gyro_offset_dps=0.5, accel_offset_mg=20.0,
        gyro_tempco_dps_c=0.005, accel_tempco_mg_c=0.15),
}
"""The named parts (``--imu-model``)."""


def model(name: str) -> ImuModel:
    """The part named ``name``; ValueError listing the names otherwise."""
    if name not in MODELS:
        raise ValueError(f"--imu-model must be one of {', '.join(MODELS)}, got {name!r}")
    return MODELS[name]
