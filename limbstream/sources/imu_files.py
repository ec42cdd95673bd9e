"""Real IMU recordings: x-IMU3 quaternion CSV files and Xsens MTw text exports.

Both give per-sensor raw streams (:class:`SensorStream`, each with its own timestamps) and a
loader (:func:`load_imu`) that aligns the sensors of a file or folder into one :class:`Motion` of
segment orientations (:func:`to_body`): each sensor named by its segment (:mod:`.names`), the
recording's world (Z up) turned onto the skeleton's (Y up), and each sensor calibrated from the
still rest pose the recording starts with (:func:`limbstream.calibration.calibrate_start`), once:
``Motion.orientations`` tells users (the export, joint angles) whether that was done.

- x-IMU3 sensors have independent, jittered clocks and drop samples. The folder's Motion is
  every sensor SLERP-resampled onto one uniform grid over the time all sensors overlap, at the
  median of the sensors' median sample rates; t starts at 0 at the start of the overlap.
  :func:`xio_streams` keeps the raw jittered timestamps for kernel evaluation.
- Xsens MTw sensors of one recording share the packet counter, so the Motion is the counter
  range all sensors cover, at the file's update rate; a sensor missing a packet is filled by
  SLERP between its neighbours.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream import calibration, quat
from limbstream.sources import Motion, MotionFileError, SourceNote, is_number, names as sensor_names

XIO_HEADER = ("Timestamp (us)", "W", "X", "Y", "Z")

ORTHONORMAL_TOL = 1e-2
"""Largest |M M^T - I| entry accepted for an Xsens rotation matrix."""

_COUNTER_MOD = 1 << 16


@dataclass(frozen=True)
class SensorStream:
    """The raw orientation stream of one sensor file.

    Attributes
    ----------
    name : str
        Segment name without a mapping (:func:`.names.default_name`: x-IMU3 file prefixes) or
        the file stem.
    t : (m,) float64
        Sample times, seconds on the device clock (x-IMU3) or counter / rate (Xsens), increasing.
    q : (m, 4) float64
        Sensor -> global orientation, scalar-first unit quaternions, signs continuous in time.
    path : Path
        The file.
    dropped : int
        Rows dropped because their time did not increase (or, Xsens, had no orientation).
    """

    name: str
    t: np.ndarray
    q: np.ndarray
    path: Path
    dropped: int = 0


def _read_lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8-sig", errors="replace").splitlines()
    except OSError as exc:
        raise MotionFileError.at(path, None, f"cannot read ({exc})") from exc


def _parse_rows(path: Path, rows: list[str], first_line: int, sep: str, width: int) -> np.ndarray:
    """(n, width) float64 from text rows; raises naming the first bad line."""
    try:
        values = np.array([r.split(sep) for r in rows], dtype=np.float64)
        if values.shape == (len(rows), width) and np.all(np.isfinite(values)):
            return values
    except ValueError:
        pass
    for i, row in enumerate(rows):
        fields = row.split(sep)
        if len(fields) != width:
            raise MotionFileError.at(path, first_line + i, f"{len(fields)} fields, expected {width}")
        for field in fields:
            try:
                value = float(field)
            except ValueError:
                raise MotionFileError.at(path, first_line + i, f"{field.strip()!r} is not a number") from None
            if not np.isfinite(value):
                raise MotionFileError.at(path, first_line + i, f"non-finite value {field.strip()!r}")
    raise MotionFileError.at(path, None, "unreadable rows")  # pragma: no cover - every case is caught above


def _keep_increasing(t: np.ndarray) -> np.ndarray:
    """Mask of samples whose time is above every earlier kept time."""
    return (
        np.concatenate([[True], t[1:] > np.maximum.accumulate(t)[:-1]])
        if len(t)
        else np.ones(0, bool)
    )


def _warn_dropped(path: Path, dropped: int, why: str) -> None:
    if dropped:
        warnings.warn(f"{path}: dropped {dropped} rows ({why})", SourceNote, stacklevel=3)


def read_xio_csv(path: str | Path) -> SensorStream:
    """One x-IMU3 quaternion CSV (``Timestamp (us),W,X,Y,Z``).

    Rows whose timestamp does not increase are dropped, counted and warned about.

    Raises
    ------
    MotionFileError naming the file (and line): wrong header, non-numeric or non-finite
    values, zero-norm quaternion, fewer than two samples.
    """
    path = Path(path)
    lines = _read_lines(path)
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise MotionFileError.at(path, None, "empty file")
    header = tuple(h.strip() for h in lines[0].split(","))
    if header != XIO_HEADER:
        raise MotionFileError.at(path, 1, f"header {','.join(header)!r}, expected {','.join(XIO_HEADER)!r}")
    values = _parse_rows(path, lines[1:], 2, ",", 5)
    if len(values) < 2:
        raise MotionFileError.at(path, None, f"{len(values)} samples, need at least 2")
    norm = np.linalg.norm(values[:, 1:], axis=1)
    if np.any(norm < 1e-6):
        raise MotionFileError.at(path, 2 + int(np.argmax(norm < 1e-6)), "zero-norm quaternion")
    keep = _keep_increasing(values[:, 0])
    dropped = int(np.count_nonzero(~keep))
    _warn_dropped(path, dropped, "timestamp not increasing")
    values = values[keep]
    q = quat.continuous(values[:, 1:] / norm[keep, None])
    return SensorStream(sensor_names.default_name(path.stem), values[:, 0] * 1e-6, q, path, dropped)


def _files(folder: Path, suffix: str) -> list[Path]:
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() == suffix and p.is_file())
    if not files:
        raise MotionFileError.at(folder, None, f"no {suffix} files")
    return files


def xio_streams(folder: str | Path) -> list[SensorStream]:
    """Raw per-sensor streams (own jittered timestamps) of every ``.csv`` in a folder."""
    return [read_xio_csv(p) for p in _files(Path(folder), ".csv")]


def align(streams: list[SensorStream], fs: float | None = None, name: str = "") -> Motion:
    """Sensors SLERP-resampled onto one uniform grid over the time they all cover.

    Parameters
    ----------
    streams : raw streams (at least one).
    fs : grid rate in Hz; default: the median of the sensors' median sample rates.
    name : the Motion's name.

    Returns
    -------
    Motion with t (n,) seconds from the start of the overlap and q (n, S, 4): the sensors'
    orientations in their fusion's Z-up world (``orientations="sensors"``; :func:`to_body`
    makes them segments').
    """
    start = max(s.t[0] for s in streams)
    end = min(s.t[-1] for s in streams)
    where = ", ".join(str(s.path) for s in streams)
    if not end > start:
        raise MotionFileError(f"{where}: the sensors' time ranges do not overlap")
    if fs is None:
        fs = float(np.median([1.0 / np.median(np.diff(s.t)) for s in streams]))
    n = int(np.floor((end - start) * fs + 1e-9)) + 1
    t = start + np.arange(n) / fs
    q = np.stack([quat.continuous(quat.interpolate(s.t, s.q, t)) for s in streams], axis=1)
    names = tuple(s.name for s in streams)
    if len(set(names)) != len(names):
        raise MotionFileError(f"{where}: two sensors map to the same segment ({names})")
    return Motion(t - start, q, names, name, orientations="sensors")


_RATE = re.compile(r"update rate:\s*([0-9.]+)\s*hz", re.IGNORECASE)
_MAT = [f"Mat[{r}][{c}]" for r in (1, 2, 3) for c in (1, 2, 3)]


def read_xsens_txt(path: str | Path, fs: float = 100.0) -> SensorStream:
    """One Xsens MT Manager text export with ``PacketCounter`` and ``Mat[r][c]`` columns.

    ``Mat[r][c]`` is taken as row r, column c of the sensor -> global rotation matrix: with it,
    the accelerometer reading of a sensor at rest maps onto the global +Z (up) axis
    (checked on the OpenSense recordings). Time is the 16-bit packet counter, unwrapped, over
    the ``// Update Rate:`` of the file (``fs`` if the file does not state it). Rows without
    orientation or with a repeated/backward counter are dropped, counted and warned about.

    Raises
    ------
    MotionFileError naming the file (and line): no header, missing columns, non-numeric
    values, a matrix that is not a rotation (off by more than :data:`ORTHONORMAL_TOL`).
    """
    path = Path(path)
    lines = _read_lines(path)
    rate = fs
    header_at = None
    for i, line in enumerate(lines):
        if line.startswith("//"):
            match = _RATE.search(line)
            if match:
                rate = float(match.group(1))
        elif line.strip():
            header_at = i
            break
    if header_at is None:
        raise MotionFileError.at(path, None, "no column header")
    if not rate > 0:
        raise MotionFileError.at(path, None, f"update rate {rate} Hz")
    header = [h.strip() for h in lines[header_at].split("\t")]
    missing = [c for c in ["PacketCounter", *_MAT] if c not in header]
    if missing:
        raise MotionFileError.at(path, header_at + 1, f"missing column(s) {', '.join(missing)}")
    cols = [header.index("PacketCounter")] + [header.index(c) for c in _MAT]
    counters, mats, line_no = [], [], []
    no_orientation = 0
    for i in range(header_at + 1, len(lines)):
        fields = lines[i].split("\t")
        if not lines[i].strip():
            continue
        picked = [fields[c].strip() if c < len(fields) else "" for c in cols]
        if any(not p for p in picked[1:]):
            no_orientation += 1
            continue
        try:
            values = [float(p) for p in picked]
        except ValueError:
            bad = next(p for p in picked if not is_number(p))
            raise MotionFileError.at(path, i + 1, f"{bad!r} is not a number") from None
        if not np.all(np.isfinite(values)) or values[0] != int(values[0]) or values[0] < 0:
            raise MotionFileError.at(path, i + 1, f"bad values (counter {picked[0]!r})")
        counters.append(int(values[0]))
        mats.append(values[1:])
        line_no.append(i + 1)
    if len(counters) < 2:
        raise MotionFileError.at(path, None, f"{len(counters)} samples with orientation, need at least 2")
    matrix = np.array(mats).reshape(-1, 3, 3)
    error = np.abs(matrix @ matrix.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(matrix)
    wrong = np.flatnonzero((error > ORTHONORMAL_TOL) | (det < 0))
    if len(wrong):
        k = int(wrong[0])
        raise MotionFileError.at(
            path,
            line_no[k],
            f"not a rotation matrix (|M M^T - I| = {error[k]:.3g}, det {det[k]:.3g})",
        )
    ticks, keep = _unwrap_counter(counters)
    dropped = no_orientation + int(np.count_nonzero(~keep))
    _warn_dropped(path, dropped, "no orientation or counter not increasing")
    q = quat.continuous(quat.from_rotation(Rotation.from_matrix(matrix[keep])))
    return SensorStream(path.stem, ticks / rate, q, path, dropped)


def _unwrap_counter(counters: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Unwrapped 16-bit packet counters of the kept rows, and the keep mask.

    A row whose counter repeats or goes back (a step of 0 or of half the range or more) is
    dropped; the next step is measured from the last kept row.
    """
    ticks = np.empty(len(counters), np.int64)
    keep = np.ones(len(counters), bool)
    last_raw, last_tick = counters[0], counters[0]
    ticks[0] = last_tick
    for i in range(1, len(counters)):
        step = (counters[i] - last_raw) % _COUNTER_MOD
        if step == 0 or step >= _COUNTER_MOD // 2:
            keep[i] = False
            continue
        last_raw, last_tick = counters[i], last_tick + step
        ticks[i] = last_tick
    return ticks[keep], keep


def xsens_streams(folder: str | Path) -> list[SensorStream]:
    """Raw per-sensor streams of every ``.txt`` in a folder."""
    return [read_xsens_txt(p) for p in _files(Path(folder), ".txt")]


def load_imu(path: str | Path, names: Mapping[str, str] | None = None) -> Motion:
    """An x-IMU3 ``.csv`` or Xsens ``.txt`` file, or a folder of either, as one body Motion.

    Parameters
    ----------
    path : the file or folder.
    names : sensor -> segment (:func:`.names.parse`, its segments of the layout in effect, checked
        by the caller: :func:`.names.check_segments`); the sensors it does not name are left out
        (a one-line note names them).
        None: x-IMU3 files by their prefixes, others by their stems (:func:`.names.default_name`).

    Raises
    ------
    MotionFileError naming the file and the problem, or, when no sensor maps to a body segment,
    the sensors found and how to map them.
    """
    path = Path(path)
    xio = path.suffix.lower() == ".csv" or (path.is_dir() and any(path.glob("*.csv")))
    if path.is_dir():
        streams = xio_streams(path) if xio else xsens_streams(path)
    else:
        streams = [read_xio_csv(path) if xio else read_xsens_txt(path)]
    segments = sensor_names.name_sensors([s.path.stem for s in streams], names)
    try:
        sensor_names.check_body(str(path), [s for s in segments if s], [s.path.stem for s in streams],
                                sensor_names.BODY_SEGMENTS if names is None else tuple(names.values()))
    except ValueError as exc:
        raise MotionFileError(str(exc)) from None
    unnamed = [s.path.stem for s, seg in zip(streams, segments) if not seg]
    if unnamed:
        warnings.warn(f"{path.name}: {', '.join(unnamed)}: not named by --names, left out", SourceNote, stacklevel=2)
    streams = [replace(s, name=seg) for s, seg in zip(streams, segments) if seg]
    if path.is_file():  # one sensor: its own samples, as recorded
        (one,) = streams
        return to_body(Motion(one.t - one.t[0], one.q[:, None, :], (one.name,), path.stem, orientations="sensors"))
    fs = None
    if not xio:  # Xsens: the sensors share the packet counter at one update rate
        rates = {round(1.0 / np.min(np.diff(s.t)), 6) for s in streams}
        if len(rates) != 1:
            raise MotionFileError(f"{path}: sensors have different update rates {sorted(rates)}")
        fs = rates.pop()
    return to_body(align(streams, fs, path.name))


def to_body(motion: Motion) -> Motion:
    """A recording's sensor orientations (Z-up world) as segment orientations: the world turned Y
    up (:data:`limbstream.quat.Z_UP_TO_Y_UP`), then, if every sensor starts still, each calibrated from that start
    (:func:`limbstream.calibration.calibrate_start`: the recording starts in the standing rest
    pose; ``orientations="rest"``: the segments up to the subject's facing); a recording that does
    not start still is warned about and left uncalibrated (``orientations="sensors"``)."""
    q = quat.multiply(quat.Z_UP_TO_Y_UP, motion.q)
    try:
        q, orientations = calibration.calibrate_start(q, motion.fs, motion.segments), "rest"
    except calibration.CalibrationError as exc:
        warnings.warn(f"{motion.name}: not calibrated, the sensors do not start in a still rest pose ({exc})",
                      SourceNote, stacklevel=2)
        orientations = "sensors"
    return replace(motion, q=quat.continuous(q), rest_pose="standing", orientations=orientations)
