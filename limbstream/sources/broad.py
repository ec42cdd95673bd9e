"""BROAD trials: one IMU moved by hand, with optical ground truth.

BROAD, the Berlin Robust Orientation Estimation Assessment Dataset (D. Laidig, M. Caruso,
A. Cereatti, T. Seel, "BROAD - A Benchmark for Robust Inertial Orientation Estimation", Data
6(7):72, 2021; CC BY 4.0). Each trial is a MATLAB file with ``imu_gyr`` (n, 3) rad/s, ``imu_acc``
(n, 3) m/s^2, ``imu_mag`` (n, 3) uT, ``opt_quat`` (n, 4) the optical reference (w x y z, already
in the IMU's own frame and in the East-North-Up earth frame, NaN where the markers were not
seen), ``movement`` (n,) the movement phases the benchmark scores, and ``sampling_rate``
(285.7 Hz).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from limbstream.sources import MotionFileError
from limbstream.sources.raw import RawRecording, channel

SENSOR = "imu"
"""The name of a trial's one sensor (on no body segment)."""


def from_mat(path: Path, data: dict) -> RawRecording:
    """The trial in the variables ``data`` of the file ``path``; MotionFileError naming a missing
    or malformed channel."""
    for key, what in (("imu_gyr", "gyroscope"), ("imu_acc", "accelerometer"), ("sampling_rate", "sample rate")):
        if key not in data:
            raise MotionFileError(f"{path}: no {key} ({what}): not a BROAD trial")
    gyr = channel(path, data["imu_gyr"], "imu_gyr")
    n = len(gyr)
    acc = channel(path, data["imu_acc"], "imu_acc", n)
    mag = channel(path, data["imu_mag"], "imu_mag", n) if "imu_mag" in data else None
    truth = None
    if "opt_quat" in data:
        truth = channel(path, data["opt_quat"], "opt_quat", n)
        norm = np.linalg.norm(truth, axis=1, keepdims=True)
        truth = np.where(norm > 0.5, truth / np.where(norm > 0, norm, 1.0), np.nan)  # NaN rows stay NaN
    movement = None
    if "movement" in data:
        movement = np.asarray(data["movement"]).astype(bool).reshape(-1)
        if len(movement) != n:
            raise MotionFileError(f"{path}: movement has {len(movement)} samples, imu_gyr {n}")
    try:
        fs = float(data["sampling_rate"])
    except (TypeError, ValueError):
        raise MotionFileError(f"{path}: sampling_rate is not a number") from None
    if not fs > 0:
        raise MotionFileError(f"{path}: sampling_rate {fs} Hz")

    def one(values):
        return None if values is None else values[:, None, :]

    return RawRecording(np.arange(n) / fs, one(gyr), one(acc), (SENSOR,), (SENSOR,), one(mag), one(truth),
                        movement, path.stem)
