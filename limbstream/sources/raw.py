"""Raw sensor recordings: angular rate and specific force (and magnetic field) per sensor.

A :class:`RawRecording` is what IMUs measure, before any fusion: the BROAD benchmark's trials
(:mod:`.broad`), the qmt full-body recording (:mod:`.qmt`) and emulated sensors
(:func:`limbstream.imu.record`) all give one. :func:`load_raw` reads a file.

Frames: each sensor's readings are in its own frame; ``truth`` is the sensor's orientation in an
earth frame with Z up (a 9D filter's: East-North-Up for BROAD), the frame a fusion filter's
estimate is compared in (:mod:`limbstream.evaluation.fusion`).
"""
from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from limbstream.body import Layout
from limbstream.sources import Motion, MotionFileError, SourceNote
from limbstream.wire import SEGMENTS

CHANNELS: dict[str, str] = {
    "gyr": "angular rate, rad/s",
    "acc": "specific force, m/s^2",
    "mag": "magnetic field, uT",
    "truth": "reference orientation, w x y z",
}
"""What each channel holds (error messages name them)."""


@dataclass(frozen=True)
class RawRecording:
    """Raw readings of S sensors on one time base.

    Attributes
    ----------
    t : (n,) float64
        Sample times, s from the first sample, increasing.
    gyr : (n, S, 3) float64
        Angular rate, rad/s, sensor frame.
    acc : (n, S, 3) float64
        Specific force, m/s^2, sensor frame (+9.81 on the up axis at rest).
    sensors : tuple of S str
        The sensors' names in the file.
    segments : tuple of S str
        The body segment each sensor is on (:data:`~limbstream.wire.SEGMENTS`), or the sensor's
        own name where it is on none of them.
    mag : (n, S, 3) float64 or None
        Magnetic field, uT, sensor frame.
    truth : (n, S, 4) float64 or None
        Reference orientation of each sensor in the Z-up earth frame, scalar-first; NaN where
        the reference did not see it.
    movement : (n,) bool or None
        The samples an error is scored over (a benchmark's movement phases); None: all.
    name : str
        Where it came from.
    """

    t: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    sensors: tuple[str, ...]
    segments: tuple[str, ...]
    mag: np.ndarray | None = None
    truth: np.ndarray | None = None
    movement: np.ndarray | None = None
    name: str = ""

    def __post_init__(self):
        n, s = len(self.t), len(self.sensors)
        if np.ndim(self.t) != 1 or (n > 1 and not np.all(np.diff(self.t) > 0)):
            raise ValueError(f"raw recording {self.name!r}: t must be (n,) increasing")
        if len(self.segments) != s:
            raise ValueError(f"raw recording {self.name!r}: {len(self.segments)} segments for {s} sensors")
        for channel, width in (("gyr", 3), ("acc", 3), ("mag", 3), ("truth", 4)):
            value = getattr(self, channel)
            if value is not None and np.shape(value) != (n, s, width):
                raise ValueError(f"raw recording {self.name!r}: {channel} ({CHANNELS[channel]}) must be "
                                 f"({n}, {s}, {width}), got {np.shape(value)}")
        if self.movement is not None and np.shape(self.movement) != (n,):
            raise ValueError(f"raw recording {self.name!r}: movement must be ({n},), got {np.shape(self.movement)}")

    @property
    def fs(self) -> float:
        """Mean sample rate, Hz."""
        return (len(self.t) - 1) / (self.t[-1] - self.t[0]) if len(self.t) > 1 else float("nan")

    def select(self, sensors: list[int] | np.ndarray) -> RawRecording:
        """The recording of the sensors at indices ``sensors`` only, in that order."""
        idx = np.asarray(sensors, int)

        def pick(value):
            return None if value is None else value[:, idx]

        return replace(self, gyr=self.gyr[:, idx], acc=self.acc[:, idx], mag=pick(self.mag), truth=pick(self.truth),
                       sensors=tuple(self.sensors[i] for i in idx), segments=tuple(self.segments[i] for i in idx))

    def body(self, layout: Layout | None = None) -> RawRecording:
        """The sensors on the segments of ``layout`` (None: the 10-IMU body's), in its order (those
        of the segments it has); a one-line warning names the sensors left out."""
        names = SEGMENTS if layout is None else layout.segment_names
        left_out(self.name, [(s, g) for s, g in zip(self.sensors, self.segments) if g not in names],
                 f"layout {'paper10' if layout is None else layout.name}")
        return self.select([self.segments.index(s) for s in names if s in self.segments])


def left_out(name: str, sensors: list[tuple[str, str]], whose: str) -> None:
    """One warning line naming the ``sensors`` (sensor, its segment: empty or its own name where it
    has none) of recording ``name`` left out for having no segment of ``whose`` (``layout full``);
    none if there are none."""
    if sensors:
        listed = ", ".join(s if not g or g == s else f"{s} ({g})" for s, g in sensors)
        warnings.warn(f"{name}: {listed}: no segment of {whose}, left out", SourceNote, stacklevel=3)


def channel(path: Path, values, name: str, n: int | None = None) -> np.ndarray:
    """``values`` as an (n, 3) float64 array of channel ``name`` (MotionFileError naming the file,
    the channel and the problem)."""
    try:
        array = np.asarray(values, np.float64)
    except (TypeError, ValueError):
        raise MotionFileError(f"{path}: {name} is not numeric") from None
    width = 4 if name.endswith("quat") else 3
    if array.ndim != 2 or array.shape[1] != width or (n is not None and len(array) != n):
        want = f"({n if n is not None else 'n'}, {width})"
        raise MotionFileError(f"{path}: {name} has shape {array.shape}, expected {want}")
    return array


def load_raw(path: str | Path, layout: Layout | None = None) -> RawRecording:
    """A raw recording from a file: a BROAD trial or a qmt-style full-body ``.mat`` (one struct
    per sensor with ``acc`` and ``gyr``; its sensors on the segments of ``layout``, None: the
    10-IMU body's, :func:`.qmt.from_mat`).

    Raises
    ------
    MotionFileError naming the file and what is wrong (a missing channel by name).
    """
    from limbstream.sources import broad, qmt

    path = Path(path)
    if not path.is_file():
        raise MotionFileError(f"{path}: no such file")
    if path.suffix.lower() != ".mat":
        raise MotionFileError(f"{path}: not a raw sensor recording (expected a BROAD or qmt-style .mat file)")
    data = read_mat(path)
    if any(key.startswith("imu_") or key == "opt_quat" for key in data):
        return broad.from_mat(path, data)
    return qmt.from_mat(path, data, layout)


def raw_files(path: str | Path) -> list[Path]:
    """The raw recordings ``path`` names: a ``.mat`` file, or the ``.mat`` files of a folder that
    holds no other data (licence files aside); ``[]`` for anything else (motion files)."""
    p = Path(path)
    if p.is_file():
        return [p] if p.suffix.lower() == ".mat" else []
    if not p.is_dir():
        return []
    files = sorted(f for f in p.iterdir() if f.is_file() and not f.name.startswith("."))
    mats = [f for f in files if f.suffix.lower() == ".mat"]
    return mats if mats and len(mats) == len([f for f in files if f.suffix.lower() != ".license"]) else []


def fuse(rec: RawRecording, mag: bool = False, rest_th_gyr_dps: float | None = None,
         vqf_precision: str | None = None) -> np.ndarray:
    """(n, S, 4) every sensor's orientation after each sample as a device fuses it (the kernel's
    VQF, :func:`limbstream.kernel.fusion.fuse`; 9D with ``mag``), in the filter's Z-up earth frame,
    scalar-first; VQF in ``vqf_precision`` (``fusion.VQF_PRECISIONS``; None: the firmware's);
    ValueError when ``mag`` is asked of a recording without a magnetometer."""
    from limbstream.kernel import fusion

    if mag and rec.mag is None:
        raise ValueError(f"{rec.name}: no magnetometer channel (imu_mag): fuse it without --mag (6D)")
    threshold = fusion.REST_TH_GYR_DPS if rest_th_gyr_dps is None else rest_th_gyr_dps
    out = np.empty(rec.gyr.shape[:2] + (4,))
    for s in range(len(rec.sensors)):
        out[:, s] = fusion.fuse(rec.gyr[:, s], rec.acc[:, s], rec.mag[:, s] if mag and rec.mag is not None else None,
                                rate_hz=rec.fs, t=rec.t, rest_th_gyr_dps=threshold,
                                vqf_precision=vqf_precision or fusion.DEFAULT_VQF_PRECISION)
    return out


def to_motion(rec: RawRecording, names: Mapping[str, str] | None = None, layout: Layout | None = None) -> Motion:
    """The body's segment orientations of a raw recording: its sensors on the segments of ``layout``
    (None: a built-in layout's, :data:`.names.BODY_SEGMENTS`; ``names``: sensor -> segment,
    :mod:`.names`, overrides the file's own), fused as devices fuse them (:func:`fuse`, 6D), then
    turned Y up and calibrated from the still start as IMU recordings are
    (:func:`.imu_files.to_body`); a one-line warning names the sensors left out (on no segment of
    the layout, or not named by ``names``); MotionFileError if no sensor is on the body."""
    from limbstream.sources import imu_files, names as sensor_names

    named = list(rec.segments) if names is None else sensor_names.name_sensors(rec.sensors, names)
    segments = [seg or "" for seg in named]
    allowed = sensor_names.BODY_SEGMENTS if layout is None else layout.segment_names
    keep = [k for k, seg in enumerate(segments) if seg in allowed]
    if not keep:
        raise MotionFileError(f"{rec.name}: no sensor maps to a body segment (sensors found: "
                              f"{', '.join(rec.sensors)}); map them with {sensor_names.FLAG}")
    left_out(rec.name, [(s, g) for s, g in zip(rec.sensors, segments) if g not in allowed],
             "a built-in layout" if layout is None else f"layout {layout.name}")
    body = rec.select(keep)
    motion = Motion(body.t, fuse(body), tuple(segments[k] for k in keep), rec.name, orientations="sensors")
    return imu_files.to_body(motion)


def read_mat(path: Path) -> dict:
    """The variables of a MATLAB file (structs as objects), or MotionFileError."""
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    try:
        data = loadmat(path, squeeze_me=True, struct_as_record=False)
    except (MatReadError, OSError, ValueError, NotImplementedError, TypeError, IndexError, KeyError) as exc:
        raise MotionFileError(f"{path}: not a readable MATLAB file ({exc})") from exc
    return {k: v for k, v in data.items() if not k.startswith("__")}
