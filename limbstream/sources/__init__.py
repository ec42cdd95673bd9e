"""Motion sources: every loader returns a :class:`Motion`.

``load(path)`` picks the loader from the file (or folder) type; ``generator`` is the
built-in synthetic full-body motion (the default of demos and tests).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

SEGMENTS: tuple[str, ...] = (
    "l_shank", "r_shank", "l_thigh", "r_thigh", "l_lowerarm",
    "r_lowerarm", "l_upperarm", "r_upperarm", "neck", "hip",
)
"""The 10-IMU layout, in the order of ``cmu_10seg_50hz.npz``."""


class MotionFileError(ValueError):
    """A motion file that cannot be read; the message names the file and the problem."""


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
    """

    t: np.ndarray
    q: np.ndarray
    segments: tuple[str, ...]
    name: str = ""

    def __post_init__(self):
        if self.t.ndim != 1 or self.q.ndim != 3 or self.q.shape[0] != len(self.t) or self.q.shape[2] != 4:
            raise ValueError(f"Motion needs t (m,) and q (m, S, 4); got {self.t.shape}, {self.q.shape}")
        if self.q.shape[1] != len(self.segments):
            raise ValueError(f"{len(self.segments)} segment names for {self.q.shape[1]} streams")

    @property
    def fs(self) -> float:
        """Mean sample rate, Hz."""
        return (len(self.t) - 1) / (self.t[-1] - self.t[0]) if len(self.t) > 1 else float("nan")

    def segment(self, name: str) -> np.ndarray:
        """(m, 4) stream of one segment."""
        return self.q[:, self.segments.index(name), :]


def load_npz(path: str | Path) -> list[Motion]:
    """All clips of a ``cmu_10seg_50hz.npz``-style file (``clip_<name>`` arrays, ``fs``, ``segment_names``)."""
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
        names = tuple(str(s) for s in data["segment_names"])
        fs = float(data["fs"])
        clips = [k for k in data.files if k.startswith("clip_")]
    except (OSError, KeyError, ValueError) as exc:
        raise MotionFileError(f"{path}: not a limbstream npz motion file ({exc})") from exc
    if not clips:
        raise MotionFileError(f"{path}: no clip_<name> arrays")
    motions = []
    for key in clips:
        q = np.asarray(data[key], np.float64)
        if q.ndim != 3 or q.shape[1:] != (len(names), 4):
            raise MotionFileError(f"{path}: {key} has shape {q.shape}, expected (m, {len(names)}, 4)")
        motions.append(Motion(np.arange(len(q)) / fs, q, names, key[len("clip_"):]))
    return motions


def load(path: str | Path) -> list[Motion]:
    """Load every motion in a file or folder (.npz, .bvh, x-IMU3 .csv, Xsens .txt).

    Raises
    ------
    MotionFileError naming the file and what is wrong.
    """
    path = Path(path)
    if not path.exists():
        raise MotionFileError(f"{path}: no such file or folder")
    if path.suffix == ".npz":
        return load_npz(path)
    raise MotionFileError(f"{path}: unknown motion file type (expected .npz, .bvh, .csv, .txt or a folder)")
