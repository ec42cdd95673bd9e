"""Full-body raw recordings in qmt's example layout: one MATLAB struct per IMU.

The file (qmt's ``examples/full_body_example_data.mat``, (c) 2021 Bo Yang, MIT) holds ``t`` (n,)
s and, per IMU named by body part, a struct with ``acc`` (n, 3) m/s^2 and ``gyr`` (n, 3) rad/s
(and ``quat``, an orientation estimate of an undocumented filter, not read). It has 16 IMUs, at
100 Hz for 100 s, the first 4 s still; no reference orientations. Its body parts map onto the
10-IMU body by :data:`QMT_SEGMENTS`; the others (:data:`QMT_OFF_BODY`) keep their names and are
left out by :meth:`RawRecording.body`. Onto another layout (``full``) each part takes the first
of its :data:`QMT_PARTS` candidates the layout has and no other part took (:func:`segments_on`):
``full`` keeps the feet, hands, head and the upper back (as its chest); the lower back, whose
pelvis the hip IMU measures, has none (the body's sensors, :meth:`RawRecording.body` and
:func:`.raw.to_motion`, leave it out with a note).
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from limbstream.body import PAPER10, Layout

from limbstream.sources import MotionFileError
from limbstream.sources.raw import RawRecording, channel

QMT_SEGMENTS: dict[str, str] = {
    "lower_leg_left": "l_shank", "lower_leg_right": "r_shank",
    "upper_leg_left": "l_thigh", "upper_leg_right": "r_thigh",
    "forearm_left": "l_lowerarm", "forearm_right": "r_lowerarm",
    "upper_arm_left": "l_upperarm", "upper_arm_right": "r_upperarm",
    "head": "neck", "hip": "hip",
}
"""qmt body part -> segment. The head IMU stands for the neck segment (the body has no head
segment: the neck's orientation is the head's direction from the neck's base)."""

QMT_OFF_BODY: tuple[str, ...] = ("foot_left", "foot_right", "hand_left", "hand_right", "lower_back", "upper_back")
"""qmt body parts the 10-IMU body has no segment for (no feet or hands; its trunk follows the
pelvis)."""

QMT_PARTS: dict[str, tuple[str, ...]] = {
    **{part: (segment,) for part, segment in QMT_SEGMENTS.items() if part != "head"},
    "head": ("head", "neck"), "foot_left": ("l_foot",), "foot_right": ("r_foot",), "hand_left": ("l_hand",),
    "hand_right": ("r_hand",), "upper_back": ("upper_back", "chest"), "lower_back": ("lower_back", "hip"),
}
"""qmt body part -> the segments it can stand for, in order of preference (a back sensor on the
layout's own back segment, else on the trunk segment it moves with)."""


def segments_on(sensors: Sequence[str], layout: Layout) -> tuple[str, ...]:
    """Each sensor's segment in ``layout``: the first of its :data:`QMT_PARTS` candidates the layout
    has that no sensor took before (the sensors' own candidates first, then the others'), else the
    sensor's own name (off the body)."""
    taken: dict[str, str] = {}
    for rank in range(max(len(c) for c in QMT_PARTS.values())):
        for name in sensors:
            options = QMT_PARTS.get(name, ())
            if name not in taken.values() and rank < len(options) and options[rank] in layout.segment_index \
                    and options[rank] not in taken:
                taken[options[rank]] = name
    by_sensor = {name: segment for segment, name in taken.items()}
    return tuple(by_sensor.get(name, name) for name in sensors)


def from_mat(path: Path, data: dict, layout: Layout | None = None) -> RawRecording:
    """The recording in the variables ``data`` of the file ``path``, its sensors on the segments of
    ``layout`` (None: the 10-IMU body's, :data:`QMT_SEGMENTS`; else :func:`segments_on`; a sensor
    it has no segment for keeps its own name); MotionFileError naming a missing or malformed
    channel."""
    sensors = [name for name, value in data.items() if hasattr(value, "_fieldnames")]
    if not sensors:
        raise MotionFileError(f"{path}: no sensor structs (with acc and gyr) and no imu_gyr: "
                              "neither a qmt-style nor a BROAD recording")
    if "t" not in data:
        raise MotionFileError(f"{path}: no t (sample times, s)")
    t = np.asarray(data["t"], np.float64).reshape(-1)
    if len(t) < 2 or not np.all(np.isfinite(t)) or not np.all(np.diff(t) > 0):
        raise MotionFileError(f"{path}: t must hold at least 2 increasing finite times")
    gyr, acc = [], []
    for name in sensors:
        fields = data[name]._fieldnames
        for key, what in (("gyr", "angular rate, rad/s"), ("acc", "specific force, m/s^2")):
            if key not in fields:
                raise MotionFileError(f"{path}: sensor {name} has no {key} ({what})")
        gyr.append(channel(path, data[name].gyr, f"{name}.gyr", len(t)))
        acc.append(channel(path, data[name].acc, f"{name}.acc", len(t)))
    if layout is None or layout == PAPER10:
        segments = tuple(QMT_SEGMENTS.get(name, name) for name in sensors)
    else:
        segments = segments_on(sensors, layout)
    return RawRecording(t - t[0], np.stack(gyr, axis=1), np.stack(acc, axis=1), tuple(sensors), segments,
                        name=path.stem)
