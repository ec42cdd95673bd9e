"""BVH motion capture files -> global segment orientations of a body layout (``paper10``, the
10-IMU body, by default; ``full``, with feet, hands, chest and head).

Each joint's rotation channels are applied in the order the file lists them, as intrinsic
rotations (``R = R_first R_second R_third``, the BVH convention); the global orientation of a
joint is its parent's global orientation times its local one (forward kinematics, rotations
only: offsets and positions do not change orientations). The global frame is the BVH world
frame (Y up for the CMU clips). A joint -> segment map picks the joints that carry the
layout's segments (:mod:`.bvh_names`: the CMU, Mixamo and sided naming schemes, or ``--names``;
a segment turns with the joint whose bone it is, :func:`.bvh_names.carriers`); the
file's rest pose comes from its OFFSETs (:mod:`.bvh_rest`). Position channels may sit on any
joint (some exporters write six on every one); only the pelvis's path is read from them.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream import quat, wire
from limbstream.body import Body, Layout, layout as layout_of
from limbstream.sources import SEGMENTS, Motion, MotionFileError, bvh_body, bvh_names, bvh_rest, is_number
from limbstream.sources.bvh_names import CMU_SEGMENT_MAPS, pick_segment_map  # noqa: F401  (re-exported)
from limbstream.sources.bvh_positions import BvhPositions

log = logging.getLogger("limbstream.sources")
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
    end_offsets : (J, 3) float64
        The OFFSET of each joint's End Site, file units; NaN where it has none.
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
    end_offsets: np.ndarray

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
    for number, text in enumerate(lines, 1):
        if text.strip() == "MOTION":
            motion_line = number
            break
        tokens.extend((tok, number) for tok in text.split())
    if not tokens or tokens[0][0] != "HIERARCHY":
        raise MotionFileError.at(path, 1, "not a BVH file (expected HIERARCHY on the first line)")
    if motion_line is None:
        raise MotionFileError.at(path, None, "no MOTION section")
    h = _Hierarchy(path, tokens, motion_line)
    h.parse()

    frames, frame_time = _motion_header(path, lines, motion_line)
    n_channels = sum(len(c) for c in h.channels)
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
        joints=tuple(h.joints),
        parents=np.array(h.parents, dtype=int),
        offsets=np.array(h.offsets, dtype=np.float64),
        channels=tuple(h.channels),
        frame_time=frame_time,
        motion=motion.reshape(frames, n_channels),
        path=path,
        end_offsets=np.array(h.ends, dtype=np.float64).reshape(-1, 3),
    )


class _Hierarchy:
    """The HIERARCHY section of a BVH file, from its tokens (each with its line): joints, their
    parents (-1: the root), offsets and channels. MotionFileError names the line of a mistake."""

    def __init__(self, path: Path, tokens: list[tuple[str, int]], motion_line: int):
        self.path, self.tokens, self.motion_line = path, tokens, motion_line
        self.joints: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[list[float]] = []
        self.channels: list[tuple[str, ...]] = []
        self.ends: list[list[float]] = []  # per joint, its End Site's OFFSET (NaN: none)
        self.stack: list[int] = []  # joint index per open brace; -2 for an end site
        self.pos = 1

    def error(self, line: int | None, message: str) -> MotionFileError:
        return MotionFileError.at(self.path, line, message)

    def take(self) -> tuple[str, int]:
        if self.pos >= len(self.tokens):
            raise self.error(self.motion_line, "hierarchy ends early (unbalanced braces?)")
        self.pos += 1
        return self.tokens[self.pos - 1]

    def numbers(self, count: int, what: str) -> list[float]:
        values = []
        for _ in range(count):
            tok, line = self.take()
            try:
                values.append(float(tok))
            except ValueError:
                raise self.error(line, f"{what}: {tok!r} is not a number") from None
        return values

    def parse(self) -> None:
        while self.pos < len(self.tokens):
            tok, line = self.take()
            if tok in ("ROOT", "JOINT"):
                self.joint(tok)
            elif tok == "End":
                site, line = self.take()
                if site != "Site" or self.take()[0] != "{":
                    raise self.error(line, "expected 'End Site {'")
                self.stack.append(-2)
            elif tok == "OFFSET":
                values = self.numbers(3, "OFFSET")
                if not self.stack:
                    raise self.error(line, "OFFSET outside a joint")
                if self.stack[-1] >= 0:
                    self.offsets[self.stack[-1]] = values
                elif len(self.stack) > 1 and self.stack[-2] >= 0:
                    self.ends[self.stack[-2]] = values
            elif tok == "CHANNELS":
                self.channel_list(line)
            elif tok == "}":
                if not self.stack:
                    raise self.error(line, "unbalanced '}'")
                self.stack.pop()
            else:
                raise self.error(line, f"unexpected {tok!r} in HIERARCHY")
        if self.stack:
            raise self.error(self.motion_line, "hierarchy ends with unclosed braces")
        if not self.joints:
            raise self.error(self.motion_line, "no joints in HIERARCHY")

    def joint(self, tok: str) -> None:
        """``ROOT name {`` or ``JOINT name {`` (inside a joint)."""
        name, line = self.take()
        if tok == "JOINT" and (not self.stack or self.stack[-1] < 0):
            raise self.error(line, f"JOINT {name} outside a joint")
        self.parents.append(self.stack[-1] if self.stack else -1)
        self.joints.append(name)
        self.offsets.append([0.0, 0.0, 0.0])
        self.ends.append([np.nan] * 3)
        self.channels.append(())
        if self.take()[0] != "{":
            raise self.error(line, f"expected '{{' after {tok} {name}")
        self.stack.append(len(self.joints) - 1)

    def channel_list(self, line: int) -> None:
        """``CHANNELS n name...`` of the open joint."""
        count_tok, _ = self.take()
        if not count_tok.isdigit():
            raise self.error(line, f"CHANNELS count {count_tok!r} is not a number")
        names = tuple(self.take()[0] for _ in range(int(count_tok)))
        bad = [n for n in names if n not in _AXES and n not in _POSITIONS]
        if bad:
            raise self.error(line, f"unknown channel {bad[0]!r}")
        if not self.stack or self.stack[-1] < 0:
            raise self.error(line, "CHANNELS outside a joint")
        self.channels[self.stack[-1]] = names


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
    fs: float | None = wire.DEVICE_RATE_HZ,
    segment_map: Mapping[str, str] | None = None,
    drop_first: bool | None = None,
    names: Mapping[str, str] | None = None,
    layout: str | Layout = "paper10",
) -> Motion:
    """Global segment orientations of a BVH clip, from its rest pose, optionally resampled.

    Parameters
    ----------
    path : BVH file.
    fs : target rate in Hz (SLERP at ``k / fs`` s from the first kept frame); None keeps the
        file's frames and rate.
    segment_map : segment name -> joint name, any segment names; default: from ``names``
        (joint -> segment, as ``--names`` gives it) or the naming schemes (:mod:`.bvh_names`),
        the segments of ``layout`` in its order.
    drop_first : drop frame 0; None (default) drops it when :func:`is_synthetic_tpose` says so.
    names : joint -> segment (``--names``, :func:`limbstream.sources.names.parse`) for a file
        whose joint names no scheme fits; ignored with ``segment_map``.
    layout : the body layout the file is read onto (a built-in's name, a layout file, or a
        :class:`~limbstream.body.Layout`): ``paper10`` (default) or ``full`` (feet, hands, chest
        and head too; :func:`.bvh_names.layout_map`).

    Returns
    -------
    Motion with t (m,) seconds from 0, q (m, S, 4) global orientations in the BVH world frame
    from the file's rest pose (``rest_pose``, :func:`.bvh_rest.rest_pose`), its wearer's body
    from its OFFSETs (``body``: :func:`wearer` on ``paper10``; on another layout the layout's
    bones measured on the file, :meth:`.bvh_positions.BvhPositions.body`), the file's own joint
    positions (``positions``, :class:`.bvh_positions.BvhPositions`; None if the layout's bones
    cannot be measured on its skeleton: a bone of zero length or beyond 1.5 m) and, where the hip joint has a path
    (position channels on it or above it) and the map names the left thigh and shank, the
    pelvis's path (:func:`root_path`, linearly resampled with the orientations).

    Raises
    ------
    MotionFileError naming the file and what is wrong (syntax, missing joints, no map fits, a
    segment of ``layout`` without a joint).
    """
    return motion_of_clip(parse_bvh(path), fs, segment_map, drop_first, names, layout)


def motion_of_clip(clip: BvhClip, fs: float | None = wire.DEVICE_RATE_HZ, segment_map: Mapping[str, str] | None = None,
                   drop_first: bool | None = None, names: Mapping[str, str] | None = None,
                   layout: str | Layout = "paper10", name: str | None = None) -> Motion:
    """:func:`load_bvh` of a parsed clip, the Motion named ``name`` (None: the file's stem)."""
    name = clip.path.stem if name is None else name
    try:
        shape = layout if isinstance(layout, Layout) else layout_of(layout)
    except (ValueError, OSError) as exc:
        raise MotionFileError.at(clip.path, None, str(exc)) from None
    if segment_map is None:
        segment_map = bvh_names.layout_map(clip, names, shape)
    segments = tuple(segment_map)
    turns = bvh_names.carriers(clip, segment_map)
    rotations = global_rotations(clip, [turns[s] for s in segments])
    q = np.stack([quat.from_rotation(rotations[turns[s]]) for s in segments], axis=1)
    rest_pose, corrections = bvh_rest.rest_pose(clip, segment_map)
    for seg, c in corrections.items():
        k = segments.index(seg)
        q[:, k] = quat.multiply(q[:, k], c)
    if drop_first is None:
        drop_first = is_synthetic_tpose(clip)
    first = 1 if drop_first and clip.n_frames > 1 else 0
    q = q[first:]
    root = root_path(clip, segment_map)
    root = None if root is None else root[first:]
    t = np.arange(len(q)) * clip.frame_time
    own = BvhPositions(clip, dict(segment_map), corrections, rest_pose, first * clip.frame_time)
    try:
        own.body(shape)  # the layout's bones measured on the file (each within the body's bounds)
        positions: BvhPositions | None = own
    except ValueError:
        positions = None  # a skeleton the layout cannot take: no positions of its own
    body = wearer(clip, segment_map) if shape.name == "paper10" else (positions.body(shape) if positions else None)
    if fs is None:
        return Motion(t, quat.continuous(q), segments, name, rest_pose, root, positions=positions, body=body)
    t_out, q = resample(t, q, fs)
    if root is not None:
        root = np.stack([np.interp(t_out, t, axis) for axis in root.T], axis=1)
    return Motion(t_out, q, segments, name, rest_pose, root, positions=positions, body=body)


def wearer(clip: BvhClip, segment_map: Mapping[str, str]) -> Body | None:
    """The clip's body from its OFFSETs (:func:`.bvh_body.body_of`); None (the default adult)
    where its map is not of the 10 segments, its joints do not give every bone, or a bone they
    give is out of bounds (a thigh joint on the pelvis, an elbow on its shoulder: a warning names
    the file, the bone and its bound; ``--height-m`` or ``--body`` give the wearer's)."""
    if set(segment_map) != set(SEGMENTS) or bvh_body.bone_vectors(clip, segment_map) is None:
        return None
    try:
        return bvh_body.body_of(clip, segment_map)
    except ValueError as exc:
        log.warning("%s: its skeleton's OFFSETs give no body (%s): drawn with the default adult's bones "
                    "(--height-m or --body give the wearer's)", clip.path, exc)
        return None


def joint_positions(clip: BvhClip, joints: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The file's forward kinematics, file units: (F, J, 3) float64 every joint's world position
    and (F, J, 3) its End Site's (NaN where it has none), of ``joints`` (and the joints above
    them; None: every joint; the others are NaN). A joint's position is its parent's plus the
    parent's global rotation applied to its OFFSET, or to its position channels where it has all
    three (they stand for the OFFSET; the root's are its path); its global rotation is its
    parent's times its local one (:func:`local_rotations`); an End Site is its joint's position
    plus the joint's global rotation applied to the site's OFFSET."""
    n, count = clip.n_frames, len(clip.joints)
    needed = set(range(count)) if joints is None else set()
    for j in joints or ():
        while j >= 0 and j not in needed:
            needed.add(j)
            j = int(clip.parents[j])
    place, ends = np.full((n, count, 3), np.nan), np.full((n, count, 3), np.nan)
    turns: dict[int, Rotation] = {}
    for j in sorted(needed):  # parents come before their children
        names = clip.channels[j]
        cols = [clip.channel_start(j) + names.index(a) for a in ("Xposition", "Yposition", "Zposition") if a in names]
        local = clip.motion[:, cols] if len(cols) == 3 else clip.offsets[j]
        parent = int(clip.parents[j])
        place[:, j] = local if parent < 0 else place[:, parent] + turns[parent].apply(local)
        turns[j] = local_rotations(clip, j) if parent < 0 else turns[parent] * local_rotations(clip, j)
        if np.all(np.isfinite(clip.end_offsets[j])):
            ends[:, j] = place[:, j] + turns[j].apply(clip.end_offsets[j])
    return place, ends


def _moves(clip: BvhClip, joint: int) -> bool:
    """Whether a joint from the root down to ``joint`` has all three position channels."""
    while joint >= 0:
        if _POSITIONS <= set(clip.channels[joint]):
            return True
        joint = int(clip.parents[joint])
    return False


def root_path(clip: BvhClip, segment_map: Mapping[str, str]) -> np.ndarray | None:
    """(F, 3) float64 the pelvis's (the ``hip`` segment's joint's) path in metres of the default
    skeleton.

    BVH files do not say their unit (CMU's are 1/0.45 inch), so the path is scaled by the
    default :class:`~limbstream.skeleton.Skeleton`'s leg (thigh + shank) over the clip's own
    (the offsets of the ``l_shank`` joint and of its child): the skeleton that emulated sensors
    ride then travels as far as the clip's legs carried it. None if nothing above the pelvis has
    position channels or the map has no ``l_thigh`` -> ``l_shank`` chain with a child below it.
    """
    from limbstream.skeleton import Skeleton

    index = {name: j for j, name in enumerate(clip.joints)}
    hip = index.get(segment_map.get("hip", ""), 0)
    shank = index.get(segment_map.get("l_shank", ""), -1)
    below = [j for j in range(len(clip.joints)) if clip.parents[j] == shank] if shank >= 0 else []
    if shank < 0 or not below or clip.joints[clip.parents[shank]] != segment_map.get("l_thigh"):
        return None
    leg = np.linalg.norm(clip.offsets[shank]) + np.linalg.norm(clip.offsets[below[0]])
    if not _moves(clip, hip) or not leg > 0:
        return None
    path = joint_positions(clip, [hip])[0][:, hip]
    default = Skeleton()
    return path * ((default.thigh + default.shank) / leg)
