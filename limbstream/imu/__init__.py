"""Emulated IMUs: what a gyroscope and an accelerometer strapped on each segment read.

- :mod:`.kinematics`: the ideal readings of a smooth motion (body angular rate, specific force
  at the sensor's place from the skeleton's forward kinematics), conventions and constants;
- :mod:`.models`: named parts (``ideal``, ``icm42688p``) and their datasheet errors;
- :mod:`.devices`: per-device mounting, filter start heading and the part's errors, read per
  tick for many devices at once;
- :mod:`.feed`: a subject's readings by sample number (calibration script, loops, the
  generator) and :func:`record`, a whole emulated recording.

docs/evaluation.md, "Raw sensors", describes the model and what it gives with VQF.
"""
from __future__ import annotations

from limbstream.imu.devices import ImuDevices, earth_heading
from limbstream.imu.feed import ReadingFeed, record, scripted
from limbstream.imu.kinematics import GRAVITY, Z_UP, Readings, SmoothMotion, readings, to_earth
from limbstream.imu.models import MODELS, ImuModel, model

DEFAULT_RATE_HZ = 200.0
"""The emulated sensors' rate unless told (``--imu-rate``); the device rate stays 50 Hz."""

__all__ = ["DEFAULT_RATE_HZ", "GRAVITY", "MODELS", "Z_UP", "ImuDevices", "ImuModel", "ReadingFeed", "Readings",
           "SmoothMotion", "earth_heading", "model", "readings", "record", "scripted", "to_earth"]
