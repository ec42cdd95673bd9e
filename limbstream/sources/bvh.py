"""BVH motion capture files -> global segment orientations of the 10-IMU layout.

Each joint's rotation channels are applied in the order the file lists them, as intrinsic
rotations (``R = R_first R_second R_third``, the BVH convention); the global orientation of a
joint is its parent's global orientation times its local one (forward kinematics, rotations
only: offsets and positions do not change orientations). The global frame is the BVH world
frame (Y up for the CMU clips). A joint -> segment map picks the joints that carry the
10 IMUs; defaults cover the two CMU naming schemes (see :data:`CMU_SEGMENT_MAPS`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream import quat
from limbstream.sources import SEGMENTS, Motion, MotionFileError, is_number

CMU_SEGMENT_MAPS: dict[str, dict[str, str]] = {
    # CMU BVH export of the ASF skeleton ("LeftShoulder" is the collar bone here).
    "cmu": {
        "l_shank": "LeftLeg",
        "r_shank": "RightLeg",
        "l_thigh": "LeftUpLeg",
        "r_thigh": "RightUpLeg",
        "l_lowerarm": "LeftForeArm",
        "r_lowerarm": "RightForeArm",
        "l_upperarm": "LeftArm",
        "r_upperarm": "RightArm",
        "neck": "Neck",
        "hip": "Hips",
    },
    # Anatomical naming (e.g. subject 131): "LeftShoulder" is the upper arm, "Neck" the upper neck.
    "cmu_asf": {
        "l_shank": "LeftKnee",
        "r_shank": "RightKnee",
        "l_thigh": "LeftHip",
        "r_thigh": "RightHip",
        "l_lowerarm": "LeftElbow",
        "r_lowerarm": "RightElbow",
        "l_upperarm": "LeftShoulder",
        "r_upperarm": "RightShoulder",
        "neck": "lowerneck",
        "hip": "Hips",
    },
}
"""Segment -> joint maps for the CMU naming schemes, in the order they are tried."""

_AXES = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}
_POSITIONS = {"Xposition", "Yposition", "Zposition"}


@dataclass(frozen=True)
class BvhClip:
    """A parsed BVH file.

    Attributes
    ----------
    joints : tuple of J str
        Joint names in file order (end sites excluded).
    parents : (J,) int
        Parent index of every joint, -1 for the root(s).
    offsets : (J, 3) float64
        Joint offsets from the parent, file units.
    channels : tuple of J tuples of str
        Channel names of every joint, in file order.
    frame_time : float
        Seconds between frames.
    motion : (F, C) float64
        Channel values of every frame (degrees for rotations).
    path : Path
        Where it was read from.
    """

    joints: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    motion: np.ndarray
    path: Path

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return self.motion.shape[0]

    def channel_start(self, joint: int) -> int:
        """Column of the first channel of ``joint`` in :attr:`motion`."""
        return sum(len(c) for c in self.channels[:joint])


def parse_bvh(path: str | Path) -> BvhClip:
    """Read a BVH file (HIERARCHY and MOTION sections).

    Raises
    ------
    MotionFileError
        Naming the file, the line and what is wrong.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise MotionFileError.at(path, None, f"cannot read ({exc})") from exc
    tokens: list[tuple[str, int]] = []
    motion_line = None
    for number, line in enumerate(lines, 1):
        if line.strip() == "MOTION":
            motion_line = number
            break
        tokens.extend((tok, number) for tok in line.split())
    if not tokens or tokens[0][0] != "HIERARCHY":
        raise MotionFileError.at(path, 1, "not a BVH file (expected HIERARCHY on the first line)")
    if motion_line is None:
        raise MotionFileError.at(path, None, "no MOTION section")

    joints: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    stack: list[int] = []  # joint index per open brace; -2 for an end site
    pos = 1

    def take() -> tuple[str, int]:
        nonlocal pos
        if pos >= len(tokens):
            raise MotionFileError.at(path, motion_line, "hierarchy ends early (unbalanced braces?)")
        pos += 1
        return tokens[pos - 1]

    def numbers(count: int, what: str) -> list[float]:
        values = []
        for _ in range(count):
            tok, line = take()
            try:
                values.append(float(tok))
            except ValueError:
                raise MotionFileError.at(path, line, f"{what}: {tok!r} is not a number") from None
        return values

    while pos < len(tokens):
        tok, line = take()
        if tok in ("ROOT", "JOINT"):
            name, line = take()
            if tok == "JOINT" and (not stack or stack[-1] < 0):
                raise MotionFileError.at(path, line, f"JOINT {name} outside a joint")
            parents.append(stack[-1] if stack else -1)
            joints.append(name)
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
            if take()[0] != "{":
                raise MotionFileError.at(path, line, f"expected '{{' after {tok} {name}")
            stack.append(len(joints) - 1)
        elif tok == "End":
            site, line = take()
            if site != "Site" or take()[0] != "{":
                raise MotionFileError.at(path, line, "expected 'End Site {'")
            stack.append(-2)
        elif tok == "OFFSET":
            values = numbers(3, "OFFSET")
            if not stack:
                raise MotionFileError.at(path, line, "OFFSET outside a joint")
            if stack[-1] >= 0:
                offsets[stack[-1]] = values
        elif tok == "CHANNELS":
            count_tok, _ = take()
            if not count_tok.isdigit():
                raise MotionFileError.at(path, line, f"CHANNELS count {count_tok!r} is not a number")
            names = tuple(take()[0] for _ in range(int(count_tok)))
            bad = [n for n in names if n not in _AXES and n not in _POSITIONS]
            if bad:
                raise MotionFileError.at(path, line, f"unknown channel {bad[0]!r}")
            if not stack or stack[-1] < 0:
                raise MotionFileError.at(path, line, "CHANNELS outside a joint")
            channels[stack[-1]] = names
        elif tok == "}":
            if not stack:
                raise MotionFileError.at(path, line, "unbalanced '}'")
            stack.pop()
        else:
            raise MotionFileError.at(path, line, f"unexpected {tok!r} in HIERARCHY")
    if stack:
        raise MotionFileError.at(path, motion_line, "hierarchy ends with unclosed braces")
    if not joints:
        raise MotionFileError.at(path, motion_line, "no joints in HIERARCHY")

    frames, frame_time = _motion_header(path, lines, motion_line)
    n_channels = sum(len(c) for c in channels)
    body = lines[motion_line + 2 :]
    while body and not body[-1].strip():
        body.pop()
    try:
        motion = np.array(" ".join(body).split(), dtype=np.float64)
    except ValueError:
        motion = None
    if motion is None or motion.size != frames * n_channels or not np.all(np.isfinite(motion)):
        raise _bad_frame(path, body, motion_line + 3, n_channels, frames)
    return BvhClip(
        joints=tuple(joints),
        parents=np.array(parents, dtype=int),
        offsets=np.array(offsets, dtype=np.float64),
        channels=tuple(channels),
        frame_time=frame_time,
        motion=motion.reshape(frames, n_channels),
        path=path,
    )


def _motion_header(path: Path, lines: list[str], motion_line: int) -> tuple[int, float]:
    """(frames, frame_time) from the two lines after MOTION."""
    try:
        key, value = lines[motion_line].split(":", 1)
        assert key.strip() == "Frames"
        frames = int(value)
    except (IndexError, ValueError, AssertionError):
        raise MotionFileError.at(path, motion_line + 1, "expected 'Frames: <count>'") from None
    try:
        key, value = lines[motion_line + 1].split(":", 1)
        assert key.strip() == "Frame Time"
        frame_time = float(value)
    except (IndexError, ValueError, AssertionError):
        raise MotionFileError.at(path, motion_line + 2, "expected 'Frame Time: <seconds>'") from None
    if frames < 1 or not frame_time > 0:
        raise MotionFileError.at(
            path,
            motion_line + 1,
            f"needs Frames >= 1 and Frame Time > 0, got {frames}, {frame_time}",
        )
    return frames, frame_time


def _bad_frame(
    path: Path, body: list[str], first_line: int, n_channels: int, frames: int
) -> MotionFileError:
    """The error for a MOTION block that does not hold frames x channels numbers."""
    for i, line in enumerate(body):
        values = line.split()
        if len(values) != n_channels:
            return MotionFileError.at(
                path, first_line + i, f"frame has {len(values)} values, expected {n_channels}"
            )
        try:
            row = np.array(values, dtype=np.float64)
        except ValueError:
            bad = next(v for v in values if not is_number(v))
            return MotionFileError.at(path, first_line + i, f"{bad!r} is not a number")
        if not np.all(np.isfinite(row)):
            return MotionFileError.at(path, first_line + i, "non-finite channel value")
    return MotionFileError.at(path, None, f"MOTION holds {len(body)} frames, header says Frames: {frames}")


def local_rotations(clip: BvhClip, joint: int) -> Rotation:
    """(F,) local rotations of one joint from its rotation channels (identity if it has none)."""
    names = clip.channels[joint]
    start = clip.channel_start(joint)
    cols = [start + i for i, n in enumerate(names) if n in _AXES]
    if not cols:
        return Rotation.identity(clip.n_frames)
    seq = "".join(_AXES[clip.channels[joint][c - start]] for c in cols)  # uppercase = intrinsic
    return Rotation.from_euler(seq, clip.motion[:, cols], degrees=True)


def global_rotations(clip: BvhClip, joints: list[str]) -> dict[str, Rotation]:
    """(F,) global rotations of the named joints (parent global * local, down from the root)."""
    index = {name: i for i, name in enumerate(clip.joints)}
    cache: dict[int, Rotation] = {}

    def of(j: int) -> Rotation:
        if j not in cache:
            local = local_rotations(clip, j)
            parent = clip.parents[j]
            cache[j] = local if parent < 0 else of(parent) * local
        return cache[j]

    missing = [name for name in joints if name not in index]
    if missing:
        raise MotionFileError.at(
            clip.path, None, f"no joint named {missing[0]!r} (joints: {', '.join(clip.joints)})"
        )
    return {name: of(index[name]) for name in joints}


def pick_segment_map(joints: tuple[str, ...] | list[str]) -> dict[str, str]:
    """The first of :data:`CMU_SEGMENT_MAPS` whose joints all exist; ``{}`` if none fits."""
    have = set(joints)
    for mapping in CMU_SEGMENT_MAPS.values():
        if set(mapping.values()) <= have:
            return dict(mapping)
    return {}


def is_synthetic_tpose(clip: BvhClip) -> bool:
    """Whether frame 0 is a synthetic rest pose that precedes the capture (as in CMU 01_01).

    Heuristic: the root rotation of frame 0 is exactly zero, every rotation value of frame 0
    is a whole number of degrees and at least 3/4 of them are exactly zero. Captured frames
    have fractional angles nearly everywhere, so the test does not fire on real data.
    """
    if clip.n_frames < 2:
        return False
    rot_cols = []
    for j, names in enumerate(clip.channels):
        start = clip.channel_start(j)
        rot_cols += [start + i for i, n in enumerate(names) if n in _AXES]
    root = [c for c in rot_cols if c < len(clip.channels[0])]
    frame = clip.motion[0, rot_cols]
    return (
        bool(np.all(clip.motion[0, root] == 0.0))
        and bool(np.all(frame == np.round(frame)))
        and float(np.mean(frame == 0.0)) >= 0.75
    )


def resample(t: np.ndarray, q: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """SLERP (m, S, 4) streams sampled at ``t`` onto ``t[0] + k / fs`` for every k inside ``t``.

    Returns
    -------
    t_out : (n,) float64 seconds, starting at 0 (relative to ``t[0]``).
    q_out : (n, S, 4) float64 unit quaternions, signs continuous at the input rate.
    """
    t = np.asarray(t, np.float64) - t[0]
    n = int(np.floor(t[-1] * fs + 1e-9)) + 1
    t_out = np.arange(n) / fs
    k = np.clip(np.searchsorted(t, t_out, side="right") - 1, 0, max(len(t) - 2, 0))
    if len(t) == 1:
        return t_out, quat.continuous(np.repeat(q[:1], n, axis=0))
    u = np.clip((t_out - t[k]) / (t[k + 1] - t[k]), 0.0, 1.0)
    q = quat.continuous(q)
    q_out = quat.slerp(q[k], q[k + 1], u[:, None])  # keeps the hemisphere of q[k]
    return t_out, q_out


def load_bvh(
    path: str | Path,
    fs: float | None = 50.0,
    segment_map: Mapping[str, str] | None = None,
    drop_first: bool | None = None,
) -> Motion:
    """Global segment orientations of a BVH clip, optionally resampled.

    Parameters
    ----------
    path : BVH file.
    fs : target rate in Hz (SLERP at ``k / fs`` s from the first kept frame); None keeps the
        file's frames and rate.
    segment_map : segment name -> joint name; default: the first fitting
        :data:`CMU_SEGMENT_MAPS` entry, in :data:`SEGMENTS` order.
    drop_first : drop frame 0; None (default) drops it when :func:`is_synthetic_tpose` says so.

    Returns
    -------
    Motion with t (m,) seconds from 0, q (m, S, 4) global orientations in the BVH world frame
    and, where the root joint has position channels and the map names both legs' thigh and
    shank, the root's path (:func:`root_path`, linearly resampled with the orientations).

    Raises
    ------
    MotionFileError naming the file and what is wrong (syntax, missing joints, no map fits).
    """
    clip = parse_bvh(path)
    if segment_map is None:
        segment_map = pick_segment_map(clip.joints)
        if not segment_map:
            raise MotionFileError.at(clip.path, None, "joint names match no CMU naming scheme; pass segment_map")
        segment_map = {s: segment_map[s] for s in SEGMENTS}
    segments = tuple(segment_map)
    rotations = global_rotations(clip, [segment_map[s] for s in segments])
    q = np.stack([quat.from_rotation(rotations[segment_map[s]]) for s in segments], axis=1)
    if drop_first is None:
        drop_first = is_synthetic_tpose(clip)
    first = 1 if drop_first and clip.n_frames > 1 else 0
    q = q[first:]
    root = root_path(clip, segment_map)
    root = None if root is None else root[first:]
    t = np.arange(len(q)) * clip.frame_time
    if fs is None:
        return Motion(t, quat.continuous(q), segments, clip.path.stem, "tpose", root)
    t_out, q = resample(t, q, fs)
    if root is not None:
        root = np.stack([np.interp(t_out, t, axis) for axis in root.T], axis=1)
    return Motion(t_out, q, segments, clip.path.stem, "tpose", root)


def root_path(clip: BvhClip, segment_map: Mapping[str, str]) -> np.ndarray | None:
    """(F, 3) float64 the root joint's position channels in metres of the default skeleton.

    BVH files do not say their unit (CMU's are 1/0.45 inch), so the path is scaled by the
    default :class:`~limbstream.skeleton.Skeleton`'s leg (thigh + shank) over the clip's own
    (the offsets of the ``l_shank`` joint and of its child): the skeleton that emulated sensors
    ride then travels as far as the clip's legs carried it. None if the root has no position
    channels or the map has no ``l_thigh`` -> ``l_shank`` chain with a child below it.
    """
    from limbstream.skeleton import Skeleton

    names = clip.channels[0]
    cols = [names.index(axis) for axis in ("Xposition", "Yposition", "Zposition") if axis in names]
    shank = clip.joints.index(segment_map["l_shank"]) if segment_map.get("l_shank") in clip.joints else -1
    below = [j for j in range(len(clip.joints)) if clip.parents[j] == shank] if shank >= 0 else []
    if len(cols) != 3 or shank < 0 or not below or clip.joints[clip.parents[shank]] != segment_map.get("l_thigh"):
        return None
    leg = np.linalg.norm(clip.offsets[shank]) + np.linalg.norm(clip.offsets[below[0]])
    if not leg > 0:
        return None
    default = Skeleton()
    return clip.motion[:, cols] * ((default.thigh + default.shank) / leg)
