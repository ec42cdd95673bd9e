"""Motion sources: every loader returns a :class:`Motion`.

``load(path)`` picks the loader from the file (or folder) type; ``generator`` is the
built-in synthetic full-body motion (the default of demos and tests). Raw sensor recordings
(angular rate and specific force, ``.mat``) are read by ``load_raw(path)`` into a
:class:`~limbstream.sources.raw.RawRecording` instead.
"""
from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from limbstream import wire
from limbstream.wire.body import SEGMENTS  # noqa: F401  (re-exported: the 10-IMU layout)

if TYPE_CHECKING:
    from limbstream.sources.bvh_positions import BvhPositions
    from limbstream.body import Body, Layout


class MotionFileError(ValueError):
    """A motion file that cannot be read; the message names the file and the problem."""

    @classmethod
    def at(cls, path: Path, line: int | None, what: str) -> MotionFileError:
        """The error for ``what`` at ``path`` (and 1-based ``line``, if known)."""
        where = f"{path}, line {line}" if line is not None else f"{path}"
        return cls(f"{where}: {what}")


class SourceNote(UserWarning):
    """A note on a source as it is read (segments or sensors left out, rows dropped, a recording
    left uncalibrated); ``limbstream`` prints it as one line, ``limbstream COMMAND: note: ...``."""


def is_number(text: str) -> bool:
    """True if ``text`` parses as a float."""
    try:
        float(text)
    except ValueError:
        return False
    return True


ORIENTATIONS = wire.ORIENTATIONS
"""What a :class:`Motion`'s orientations are (``Motion.orientations``): the contract's
:data:`limbstream.wire.ORIENTATIONS` (the segments' own, rest-calibrated real sensors, or
uncalibrated sensors), which devices also say of their streams."""


@dataclass(frozen=True)
class Motion:
    """Orientation streams of the segments of one subject.

    Attributes
    ----------
    t : (m,) float64
        Sample timestamps, seconds, increasing.
    q : (m, S, 4) float64
        Global segment orientations, scalar-first unit quaternions.
    segments : tuple of S str
        Segment names (see :data:`SEGMENTS`).
    name : str
        Where it came from (file stem, clip or generator name).
    rest_pose : str
        What identity orientations mean (``wire.REST_POSES``): a BVH clip's from its OFFSETs
        (``tpose`` for most CMU clips, :mod:`.bvh_rest`), an npz file's entry (``tpose`` if absent),
        ``standing`` for the generator and IMU recordings.
    root : (m, 3) float64 or None
        The body's root (pelvis) position in the same world frame, metres at the scale of the
        default :class:`limbstream.skeleton.Skeleton`, where the source has one (BVH clips);
        None: the body turns about a fixed root (emulated sensors then feel no travel).
    orientations : str
        What ``q`` are, one of :data:`ORIENTATIONS`: the segments' own (motion files, the
        generator), or real sensors' rest-calibrated or uncalibrated (IMU recordings, set by
        :func:`.imu_files.to_body`).
    positions : the source's own joint positions where it has them (a BVH file read as it is:
        :class:`.bvh_positions.BvhPositions`), else None.
    body : the wearer's dimensions where the source gives them (a BVH clip's, from its OFFSETs:
        :func:`.bvh_body.body_of`), None: not given (the default adult).
    """

    t: np.ndarray
    q: np.ndarray
    segments: tuple[str, ...]
    name: str = ""
    rest_pose: str = wire.DEFAULT_REST_POSE
    root: np.ndarray | None = None
    orientations: str = "segments"
    positions: BvhPositions | None = None
    body: Body | None = None

    def __post_init__(self):
        if self.t.ndim != 1 or self.q.ndim != 3 or self.q.shape[0] != len(self.t) or self.q.shape[2] != 4:
            raise ValueError(f"Motion needs t (m,) and q (m, S, 4); got {self.t.shape}, {self.q.shape}")
        if self.q.shape[1] != len(self.segments):
            raise ValueError(f"{len(self.segments)} segment names for {self.q.shape[1]} streams")
        if self.root is not None and np.shape(self.root) != (len(self.t), 3):
            raise ValueError(f"Motion root must be (m, 3) = ({len(self.t)}, 3), got {np.shape(self.root)}")
        wire.check_rest_pose(self.rest_pose)
        if self.orientations not in ORIENTATIONS:
            raise ValueError(f"Motion orientations must be one of {ORIENTATIONS}, got {self.orientations!r}")

    @property
    def fs(self) -> float:
        """Mean sample rate, Hz."""
        return (len(self.t) - 1) / (self.t[-1] - self.t[0]) if len(self.t) > 1 else float("nan")

    @property
    def layout(self) -> Layout:
        """The body layout of this motion: its body's, else the smallest built-in layout holding its
        segments (:func:`limbstream.body.layout_for`)."""
        from limbstream.body import layout_for
        return self.body.layout if self.body is not None else layout_for(self.segments)

    def segment(self, name: str) -> np.ndarray:
        """(m, 4) stream of one segment."""
        return self.q[:, self.segments.index(name), :]


NPZ_REST_POSE = "tpose"
"""The rest pose of an npz motion file without a ``rest_pose`` entry: the format began as BVH clips
converted to global segment orientations (identity = the BVH's T-pose); limbstream always writes
the entry."""


def load_npz(path: str | Path) -> list[Motion]:
    """All clips of a ``cmu_10seg_50hz.npz``-style file (``clip_<name>`` arrays, ``fs``,
    ``segment_names``, optional ``rest_pose``: a 0-d string, :data:`NPZ_REST_POSE` if absent;
    optional ``root_<name>`` (m, 3) m, a clip's root path: ``Motion.root``)."""
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
        names = tuple(str(s) for s in data["segment_names"])
        fs = float(data["fs"])
        clips = [k for k in data.files if k.startswith("clip_")]
        rest_pose = wire.check_rest_pose(str(data["rest_pose"])) if "rest_pose" in data.files else NPZ_REST_POSE
    except (OSError, KeyError, ValueError) as exc:
        raise MotionFileError(f"{path}: not a limbstream npz motion file ({exc})") from exc
    if not clips:
        raise MotionFileError(f"{path}: no clip_<name> arrays")
    motions = []
    for key in clips:
        q = np.asarray(data[key], np.float64)
        if q.ndim != 3 or q.shape[1:] != (len(names), 4):
            raise MotionFileError(f"{path}: {key} has shape {q.shape}, expected (m, {len(names)}, 4)")
        name = key[len("clip_"):]
        root = np.asarray(data[f"root_{name}"], np.float64) if f"root_{name}" in data.files else None
        if root is not None and root.shape != (len(q), 3):
            raise MotionFileError(f"{path}: root_{name} has shape {root.shape}, expected ({len(q)}, 3)")
        motions.append(Motion(np.arange(len(q)) / fs, q, names, name, rest_pose, root))
    return motions


def on_layout(motion: Motion, layout: Layout) -> Motion:
    """``motion`` with only the segments ``layout`` has (in the motion's order); a one-line warning
    names those it leaves out."""
    off = [s for s in motion.segments if s not in layout.segment_index]
    if not off:
        return motion
    keep = [k for k, s in enumerate(motion.segments) if s in layout.segment_index]
    if not keep:
        raise MotionFileError(f"{motion.name}: none of its segments ({', '.join(motion.segments)}) is one of layout "
                              f"{layout.name}'s ({', '.join(layout.segment_names)})")
    warnings.warn(f"{motion.name}: {', '.join(off)}: no segment of layout {layout.name}, left out", SourceNote,
                  stacklevel=2)
    return replace(motion, q=motion.q[:, keep], segments=tuple(motion.segments[k] for k in keep))


def load(path: str | Path, names: Mapping[str, str] | None = None,
         fs: float | None = wire.DEVICE_RATE_HZ, layout: str | Layout | None = None) -> list[Motion]:
    """Load every motion in a file or folder, onto ``layout`` (a built-in's name, a layout file or
    a :class:`~limbstream.body.Layout`; None: BVH files onto ``paper10``, other sources with every
    segment they have).

    - ``.npz``: every clip (:func:`load_npz`); ``.bvh``: one clip at ``fs`` Hz (None: the file's
      own frames; :mod:`.bvh`; ``names``
      maps its joints to segments of the layout, JOINT -> SEGMENT, over the naming schemes).
    - An x-IMU3 ``.csv`` or Xsens ``.txt`` file (one segment, its own samples), or a folder of
      either (one segment per sensor, aligned on a common time base): one Motion of segment
      orientations (see :mod:`.imu_files`); ``names`` maps its sensors to segments (:mod:`.names`:
      segments of ``layout`` where one is given).
    - Any other folder: every ``.npz`` and ``.bvh`` in it, in name order.

    With a ``layout``, a BVH file maps a joint to each of its segments (:func:`.bvh.load_bvh`), and
    the segments of other sources it does not have are left out (:func:`on_layout`).

    Raises
    ------
    MotionFileError naming the file and what is wrong (also: an IMU recording in which no sensor
    maps to a body segment, and ``names`` for a source whose segments are named already).
    """
    from limbstream.body import layout as layout_named
    from limbstream.sources import bvh, imu_files, names as sensor_names

    path = Path(path)
    if not path.exists():
        raise MotionFileError(f"{path}: no such file or folder")
    try:
        shape = layout_named(layout) if isinstance(layout, (str, Path)) else layout
    except (ValueError, OSError) as exc:
        raise MotionFileError(f"{path}: {exc}") from None
    suffixes = {p.suffix.lower() for p in path.iterdir() if p.is_file()} if path.is_dir() else {path.suffix.lower()}
    if suffixes & {".csv", ".txt"}:
        try:
            if shape is not None:
                sensor_names.check_segments(names, shape)
        except ValueError as exc:
            raise MotionFileError(f"{path}: {exc}") from None
        motion = imu_files.load_imu(path, names)
        return [motion if shape is None else on_layout(motion, shape)]
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".npz", ".bvh"))
        if not files:
            raise MotionFileError(f"{path}: folder holds no .npz, .bvh, .csv or .txt motion files")
        return [m for f in files for m in load(f, names if f.suffix.lower() == ".bvh" else None, fs, shape)]
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        return [bvh.load_bvh(path, fs, names=names, layout=shape or "paper10")]
    if names is not None:
        raise MotionFileError(f"{path}: --names maps the sensors of IMU recordings (x-IMU3 .csv, Xsens .txt) "
                              "and the joints of BVH files; this source names its segments itself")
    if suffix == ".npz":
        return [m if shape is None else on_layout(m, shape) for m in load_npz(path)]
    if suffix == ".mat":
        raise MotionFileError(f"{path}: a raw sensor recording (angular rate, specific force), not orientations: "
                              "limbstream fuse, eval and export fuse it as devices do")
    raise MotionFileError(f"{path}: unknown motion file type (expected .npz, .bvh, .csv, .txt or a folder)")


from limbstream.sources.raw import RawRecording, load_raw  # noqa: E402  (needs MotionFileError above)

__all__ = ["ORIENTATIONS", "SEGMENTS", "Motion", "MotionFileError", "RawRecording", "SourceNote", "is_number", "load",
           "load_npz", "load_raw", "on_layout"]
