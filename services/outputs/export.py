"""Export one subject's motion to files other tools read: BVH (Blender, MotionBuilder, ...),
CSV (one row per frame), npz (``limbstream.sources.load`` reads it back), and OpenSim's joint-angle
motion file (``.mot``) and OpenSense's orientation file (``.sto``) (:mod:`.opensim`).

A recording of real sensors (IMU files) comes rest-calibrated from its loader when it starts
standing still (``Motion.orientations`` ``rest``: each sensor calibrated from its first still
second); the subject's facing, which a rest pose cannot tell, is found here from the knees' and
elbows' motion (:mod:`limbstream.joints.functional`) before anything is exported.

Sources: the exact pose frames of a subject in a recording (:mod:`.recording`), a raw sensor
recording fused as devices fuse it (:func:`limbstream.sources.raw.to_motion`), or any motion file
``limbstream.sources.load`` reads, each at its own frame rate unless ``--rate`` asks for another.
Layouts, units and the handling of gaps: docs/outputs.md. BVH: :mod:`.bvh_writer`.
"""
from __future__ import annotations

import csv
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from limbstream import joints, quat, wire
from limbstream.body import PAPER10, Body, Layout, lengths_of
from limbstream.body import layout as body_layout
from limbstream.calibration import START_STILL_S
from limbstream.skeleton import Skeleton
from limbstream.sources import Motion, MotionFileError, load, load_raw, raw
from limbstream.sources.bvh import resample
from limbstream.subject_layouts import SubjectLayouts

from .bvh_writer import BVH_JOINTS, ROTATION_CHANNELS, BvhJoint, bvh_text  # noqa: F401  (re-exported)
from .opensim import mot_text, segments_with_data, sto_text
from .recording import Recording, RecordingError

FORMATS = ("bvh", "csv", "npz", "mot", "sto")
FS = wire.DEVICE_RATE_HZ
"""Frame rate of a motion without one (a single frame), Hz; every other source keeps its own rate
unless ``--rate`` asks for another."""


class ExportError(ValueError):
    """An export that cannot be done; the message names the file or flag (one line)."""


@dataclass
class Take:
    """F frames of one subject on a uniform time grid.

    Attributes
    ----------
    name : subject (recording) or clip name (motion file).
    period_us : frame period, microseconds.
    t_us : (F,) int64 frame times, µs (device time since the Unix epoch for recordings; from the
        clip start for motion files).
    q : (F, S, 4) float64 global segment orientations, ``layout.segment_names`` order, scalar-first.
    joints : (F, J, 3) float32 joint positions, metres, ``layout.joints`` order, pelvis at the origin.
    seq, flags : (F,) int frame counters and pose-frame flags (``FRAME_GAP``, ``FRAME_MISSING``).
    filled : (F,) bool, True where no frame was recorded and the previous one is repeated.
    skeleton : the body whose rest pose the orientations refer to (its layout: :attr:`layout`).
    notes : what the export should tell its user (gaps, segments the source lacks).
    present : (F, S) bool, the segments with data in each frame (None: all).
    basis : which calibration the orientations rest on (one line).
    anatomical : the orientations are anatomical (joint angles can be taken); False: ``basis``
        says why not.
    root : (F, 3) the root's (pelvis') path, metres, world frame, Y up, its floor at height 0 (a
        recording's frames' root translation, a motion file's root path); None: not tracked.
    """

    name: str
    period_us: int
    t_us: np.ndarray
    q: np.ndarray
    joints: np.ndarray
    seq: np.ndarray
    flags: np.ndarray
    filled: np.ndarray
    skeleton: Skeleton | Sized
    notes: list[str] = field(default_factory=list)
    present: np.ndarray | None = None
    basis: str = "the source's own segment orientations"
    anatomical: bool = True
    root: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_us)

    @property
    def layout(self) -> Layout:
        """The body layout of the take's segments and joints (its skeleton's; ``paper10`` for a
        :class:`~limbstream.skeleton.Skeleton`)."""
        return self.skeleton.body.layout if isinstance(self.skeleton, Sized) else PAPER10


@dataclass(frozen=True)
class Sized:
    """A body of any layout (a motion's own, ``Motion.body``: a BVH file's bones; or one drawn
    from a frame's joints) drawn as a :class:`~limbstream.skeleton.Skeleton` is, on ``rest_pose``."""

    body: Body
    rest_pose: str

    def positions(self, q: np.ndarray, tpose: np.ndarray | bool | None = None, dtype: type = np.float32) -> np.ndarray:
        """(..., J, 3) joint positions of orientations (..., S, 4) (``Skeleton.positions``)."""
        return self.body.positions(q, self.rest_pose == "tpose" if tpose is None else tpose, dtype)


# ----------------------------------------------------------------------------- sources


def skeleton_of(frame: wire.PoseFrame, rest_pose: str | None = None) -> Skeleton | Sized:
    """The body an aggregator used for ``frame``, in the frame's layout: bone lengths from its
    joint positions (``paper10``: ``Skeleton.of_joints``), rest pose from its flags (``rest_pose``:
    an override)."""
    pose = rest_pose or wire.frame_rest_pose(frame.flags)
    layout = frame.layout or PAPER10
    if layout == PAPER10:
        return Skeleton.of_joints(frame.joints, pose)
    return Sized(Body(layout, lengths_of(layout, frame.joints), pose), pose)


def from_recording(recording: Recording, subject: str | None, rest_pose: str | None = None) -> Take:
    """The exact pose frames of ``subject`` in ``recording`` on their frame grid (the median step);
    a grid point without a recorded frame repeats the frame before (``filled``). A layout file's
    frames are read with the layout its devices' recorded statuses announce.

    ExportError naming the subject and the subjects there are if it has no exact frames;
    ``subject`` None: the only subject."""
    frames: dict[str, dict[int, wire.PoseFrame]] = {}
    bad = 0
    layouts = SubjectLayouts()  # a layout file's frames are read with the layout its devices' statuses announce
    for entry in recording.entries(["config"]):
        layouts.learn_reply(entry.key, entry.payload)
    for entry in recording.entries(["pose"]):
        try:
            name, _ = wire.parse_subject_key(entry.key)
            frame = layouts.decode_pose(name, entry.payload)
        except wire.WireError:
            bad += 1
            continue
        if frame.kind == wire.KIND_EXACT:
            frames.setdefault(name, {})[frame.t_us] = frame
    subjects = sorted(frames)
    if subject is None:
        if len(subjects) != 1:
            raise ExportError(f"--subject: {recording.path} holds exact frames of "
                              f"{', '.join(subjects) if subjects else 'no subject'}; name one")
        subject = subjects[0]
    if subject not in frames:
        raise ExportError(f"--subject {subject}: no exact pose frames of it in {recording.path} "
                          f"(subjects: {', '.join(subjects) if subjects else 'none'})")
    mine = frames[subject]
    layout = mine[max(mine)].layout  # the subject's layout now (its latest frame's)
    other = [t for t, f in mine.items() if f.layout != layout]
    mine = {t: f for t, f in mine.items() if f.layout == layout}
    times = np.array(sorted(mine), np.int64)
    period = int(np.median(np.diff(times))) if len(times) > 1 else int(1e6 / FS)
    if period <= 0:
        raise ExportError(f"{recording.path}: exact frames of {subject} have no frame period")
    slots = np.round((times - times[0]) / period).astype(np.int64)
    grid = np.arange(slots[-1] + 1)
    taken = np.searchsorted(slots, grid, side="right") - 1  # the last recorded frame at or before each slot
    chosen = [mine[int(times[i])] for i in taken]
    filled = slots[taken] != grid
    take = Take(subject, period, times[0] + grid * period, np.stack([f.q for f in chosen]).astype(np.float64),
                np.stack([f.joints for f in chosen]), np.array([f.seq for f in chosen]),
                np.array([f.flags for f in chosen]) | np.where(filled, wire.FRAME_GAP, 0), filled,
                skeleton_of(chosen[-1], rest_pose), basis="the aggregator's segments (its device calibrations)")
    take.present = ~((take.flags & wire.FRAME_MISSING != 0)[:, None] & (take.q == _IDENTITY).all(axis=-1))
    root = np.stack([f.root for f in chosen]).astype(np.float64)
    take.root = root if root.any() else None  # frames of an aggregator that tracks no root carry zeros
    if filled.any():
        take.notes.append(f"{int(filled.sum())} of {len(grid)} frames were not recorded: each repeats the frame "
                          f"before (flag GAP; npz 'filled')")
    if other:
        take.notes.append(f"{len(other)} exact frames of {subject} in another layout than its latest ({layout.name}) "
                          f"skipped")
    if bad:
        take.notes.append(f"{bad} undecodable pose frames skipped")
    if recording.truncated:
        take.notes.append(f"{recording.path}: {recording.truncated}; exported what it holds")
    return take


def from_motion(motions: list[Motion], subject: str | None, path: Path, rest_pose: str | None,
                rate: float | None = None) -> Take:
    """One clip of a motion file at its own rate, or SLERP-resampled to ``rate`` Hz. ``subject``: its
    name, or ``s01``, ``s02``, ... as ``limbstream emulate`` numbers them; None: the only clip.
    Segments the clip lacks follow their parent (hip: identity)."""
    names = [m.name for m in motions]
    if subject is None:
        if len(motions) != 1:
            raise ExportError(f"--subject: {path} holds {len(motions)} clips ({', '.join(names[:8])}); name one")
        motion = motions[0]
    elif subject in names:
        motion = motions[names.index(subject)]
    elif subject[:1] == "s" and subject[1:].isdigit() and 1 <= int(subject[1:]) <= len(motions):
        motion = motions[int(subject[1:]) - 1]
    else:
        raise ExportError(f"--subject {subject}: no such clip in {path} "
                          f"(clips: {', '.join(names[:8])}{', ...' if len(names) > 8 else ''}; or s01..s{len(names):02d})")
    basis, anatomical, segments, q_in = _segments_of(motion)
    try:
        layout = motion.layout if segments is motion.segments else PAPER10
    except ValueError as exc:
        raise ExportError(f"{path}: {exc}") from None
    t = motion.t
    # the root's path: a BVH file's in its own metres (its positions', as the body it is drawn
    # with) where the file moves it, else the motion's own (an npz clip's)
    source = motion.positions
    root = (motion.root if source is None else
            source.root_at(t - t[0] + source.start_s, layout) if source.travels(layout) else None)
    if root is not None and np.ptp(root, axis=0).max() < 1e-6:
        root = None  # a root that stays put (position channels of a file that tracks none) is no path
    have = [k for k in range(len(segments)) if np.isfinite(q_in[:, k]).all()]
    fs = rate or (motion.fs if len(t) > 1 else FS)
    if len(t) > 1 and (rate is not None or np.ptp(np.diff(t)) > 1e-6 / fs):
        t_in = t
        t, q_have = resample(t, q_in[:, have], fs)
        q_in = np.full((len(t), len(segments), 4), np.nan)
        q_in[:, have] = q_have
        if root is not None:
            root = np.stack([np.interp(t, t_in - t_in[0], root[:, k]) for k in range(3)], axis=1)
    index = layout.segment_index
    q = np.zeros((len(t), len(layout.segments), 4))
    q[..., 0] = 1.0
    present = np.zeros(len(layout.segments), bool)
    lacking = []
    for bone in layout.bones:  # parents first
        if bone.name != bone.segment:
            continue  # an offset: placed by its segment's orientation
        seg, i = bone.segment, index[bone.segment]
        k = segments.index(seg) if seg in segments else -1
        if k in have:
            q[:, i] = quat.normalize(q_in[:, k])
            present[i] = True
        else:
            lacking.append(seg)
            parent = layout.segment(seg).parent
            if parent is not None:
                q[:, i] = q[:, index[parent]]
    pose = rest_pose or motion.rest_pose
    skeleton: Skeleton | Sized = (Sized(motion.body, pose) if motion.body is not None
                                  else Skeleton(rest_pose=pose) if layout == PAPER10 else Sized(Body.default(layout), pose))
    n = len(t)
    take = Take(motion.name or path.stem, int(round(1e6 / fs)), np.round((t - t[0]) * 1e6).astype(np.int64), q,
                skeleton.positions(q), np.arange(n), np.full(n, wire.FRAME_MISSING if lacking else 0),
                np.zeros(n, bool), skeleton, present=np.broadcast_to(present, (n, len(present))).copy(), basis=basis,
                anatomical=anatomical, root=None if root is None else np.asarray(root, np.float64))
    if lacking:
        take.notes.append(f"{path} has no {', '.join(lacking)}: each follows its parent segment (flag MISSING)")
    return take


def _segments_of(motion: Motion) -> tuple[str, bool, tuple[str, ...], np.ndarray]:
    """(basis, anatomical, segment names, (m, S, 4) orientations) of a motion: its own segments,
    or for real sensors rest-calibrated by the loader, the facing found from the hinges
    (:mod:`limbstream.joints.functional`) and undone; what was left undone is said."""
    if motion.orientations == "segments":
        return "the source's own segment orientations", True, motion.segments, motion.q
    if motion.orientations == "sensors":
        return ("the sensors' raw orientations: no rest calibration (the recording does not start standing still)",
                False, motion.segments, motion.q)
    rest, present = joints.in_layout(motion)
    stats = joints.HingeStats.empty()
    stats.add(rest, present)
    facing = stats.facing()
    where = f"rest pose from the first {START_STILL_S:g} s standing still"
    if not facing.found:
        return f"{where}; {facing.describe()}", False, wire.SEGMENTS, rest
    return f"{where}, functional {facing.describe()}", True, wire.SEGMENTS, joints.face(rest, facing.heading)


_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def at_rate(take: Take, rate: float) -> Take:
    """``take`` on a grid of ``rate`` Hz from its first frame: orientations SLERP-interpolated, joint
    positions drawn from them, frame counters, flags, ``filled`` and ``present`` those of the frame
    at or before each new one."""
    period = int(round(1e6 / rate))
    if period == take.period_us or len(take) < 2:
        return take
    t_us = take.t_us[0] + np.arange((take.t_us[-1] - take.t_us[0]) // period + 1) * period
    t_in, t_out = (take.t_us - take.t_us[0]) / 1e6, (t_us - take.t_us[0]) / 1e6
    q = np.stack([quat.interpolate(t_in, quat.continuous(take.q[:, s]), t_out) for s in range(take.q.shape[1])], axis=1)
    before = np.clip(np.searchsorted(take.t_us, t_us, side="right") - 1, 0, len(take) - 1)
    return Take(take.name, period, t_us, q, take.skeleton.positions(q), take.seq[before], take.flags[before],
                take.filled[before], take.skeleton, list(take.notes),
                None if take.present is None else take.present[before], take.basis, take.anatomical,
                None if take.root is None else np.stack([np.interp(t_out, t_in, take.root[:, k]) for k in range(3)], 1))


def read_take(path: str | Path, subject: str | None, rest_pose: str | None = None,
              names: Mapping[str, str] | None = None, rate: float | None = None,
              layout: str | Layout | None = None) -> Take:
    """A recording (``.mcap``), a raw sensor recording (``.mat``: fused as devices fuse it,
    :func:`limbstream.sources.raw.to_motion`) or a motion file (``names``: its sensors' or joints'
    segments, :mod:`limbstream.sources.names`; ``layout``: the body layout it is read onto,
    :func:`limbstream.sources.load`; a recording's frames carry theirs), as a :class:`Take` at its
    own rate or ``rate`` Hz; ExportError naming the problem."""
    path = Path(path)
    if rate is not None and not 0 < rate <= 10_000:
        raise ExportError(f"--rate must be in (0, 10000] Hz, got {rate:g}")
    try:
        if path.suffix.lower() == ".mcap":
            if names is not None:
                raise ExportError(f"{path}: --names maps the sensors of IMU recordings; a recording's devices "
                                  "are named by segment already")
            take = from_recording(Recording(path), subject, rest_pose)
            return take if rate is None else at_rate(take, rate)
        if path.suffix.lower() == ".mat" or raw.raw_files(path):
            shape = body_layout(layout) if isinstance(layout, str | Path) else layout
            motions = [raw.to_motion(load_raw(p, shape), names, shape)
                       for p in ([path] if path.is_file() else raw.raw_files(path))]
        else:
            motions = load(path, names, fs=None, layout=layout)
        return from_motion(motions, subject, path, rest_pose, rate)
    except (RecordingError, MotionFileError, ValueError) as exc:
        raise ExportError(str(exc)) from None


# ----------------------------------------------------------------------------- CSV and npz


def csv_header(layout: Layout = PAPER10) -> list[str]:
    """Columns of the CSV export of a take of ``layout`` (docs/outputs.md)."""
    return (["t_s", "t_us", "seq", "flags"]
            + [f"{s}_{c}" for s in layout.segment_names for c in ("qw", "qx", "qy", "qz")]
            + [f"{j}_{c}" for j in layout.joints for c in ("x", "y", "z")])


def write_csv(take: Take, path: Path) -> None:
    """One row per recorded frame (repeated frames of gaps left out)."""
    keep = ~take.filled
    t = take.t_us[keep]
    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(csv_header(take.layout))
        q = take.q[keep].reshape(len(t), -1)
        joints = take.joints[keep].reshape(len(t), -1)
        for k in range(len(t)):
            out.writerow([f"{(t[k] - t[0]) / 1e6:.6f}", int(t[k]), int(take.seq[keep][k]), int(take.flags[keep][k])]
                         + [f"{v:.7f}" for v in q[k]] + [f"{v:.5f}" for v in joints[k]])


def write_npz(take: Take, path: Path) -> None:
    """``clip_<name>`` (F, S, 4), ``fs``, ``segment_names`` (the take's layout's), ``rest_pose`` (what
    ``load_npz`` reads; ``root_<name>`` (F, 3) m, the root's path, where the take has one) and the
    frame details: ``layout`` (its name), ``joint_names``, ``t_us``, ``joints``, ``seq``, ``flags``,
    ``filled``."""
    root = {} if take.root is None else {f"root_{take.name}": take.root}
    with open(path, "wb") as f:
        np.savez_compressed(f, **{f"clip_{take.name}": take.q}, fs=np.float64(1e6 / take.period_us),
                            segment_names=np.array(take.layout.segment_names), layout=np.array(take.layout.name),
                            joint_names=np.array(take.layout.joints), rest_pose=np.array(take.skeleton.rest_pose),
                            t_us=take.t_us, joints=take.joints,
                            seq=take.seq, flags=take.flags, filled=take.filled, **root)


def _paper10_only(take: Take, what: str) -> None:
    """ExportError unless ``take`` is of ``paper10``: the anatomical frames' OpenSense columns are
    ``paper10``'s."""
    if take.layout != PAPER10:
        raise ExportError(f"{take.name}: no {what} of the {take.layout.name} layout: .mot and .sto are written "
                          f"for paper10 subjects (bvh, csv, npz and .mot take any layout)")


def take_angles(take: Take) -> tuple[np.ndarray, np.ndarray]:
    """(F, A) joint angles (degrees, its layout's: ``joints.angle_names(take.layout)``) and flags
    of ``take``; ExportError saying why if its orientations are not anatomical."""
    if not take.anatomical:
        raise ExportError(f"{take.name}: no joint angles: {take.basis}")
    return joints.joint_angles(take.q, take.present, take.skeleton.rest_pose, layout=take.layout)


def _complete_rows(take: Take, valid: np.ndarray, what: str) -> np.ndarray:
    """(F,) bool, the recorded frames in which every written column has data (OpenSim's readers
    take no NaN); a note says how many were left out."""
    rows = valid.all(axis=1) & ~take.filled
    if not rows.any():
        raise ExportError(f"{take.name}: no frame has every {what} written")
    if (~rows & ~take.filled).any():
        take.notes.append(f"{int((~rows & ~take.filled).sum())} frames lack a segment's data: left out of the file")
    return rows


PELVIS_TRANSLATION = ("pelvis_tx", "pelvis_ty", "pelvis_tz")
"""The Rajagopal model's pelvis translation coordinates: a take's root path in a .mot, metres."""


def write_mot(take: Take, path: Path) -> None:
    """The joint angles the take has (columns without any valid frame left out) as an OpenSim
    motion file, time 0 at its first frame (:func:`.opensim.mot_text`)."""
    angles, flags = take_angles(take)
    valid = np.isfinite(angles)
    columns = np.flatnonzero(valid.any(axis=0))
    if not len(columns):
        raise ExportError(f"{take.name}: no joint has both of its segments")
    rows = _complete_rows(take, valid[:, columns], "joint angle")
    names = joints.angle_names(take.layout)
    gimbal = [f"{names[k]} {int(n)}" for k, n in zip(columns, (flags[rows][:, columns] & joints.GIMBAL != 0).sum(0)) if n]
    if gimbal:
        take.notes.append(f"frames near gimbal lock (ill-conditioned, docs/evaluation.md): {', '.join(gimbal)}")
    t = (take.t_us[rows] - take.t_us[0]) / 1e6
    values, titles = angles[rows][:, columns], tuple(names[k] for k in columns)
    if take.root is not None:  # OpenSim's pelvis translation: metres, X forward, Y up, Z right
        x, y, z = take.root[rows].T
        values, titles = np.column_stack([values, z, y, -x]), (*titles, *PELVIS_TRANSLATION)
    path.write_text(mot_text(take.name, t, values, titles, f"calibration: {take.basis}"))


def write_sto(take: Take, path: Path) -> None:
    """The segments' anatomical frames as OpenSense's orientation file (:func:`.opensim.sto_text`)."""
    _paper10_only(take, "anatomical frames")
    if not take.anatomical:
        raise ExportError(f"{take.name}: no anatomical frames: {take.basis}")
    present = np.ones((len(take), len(wire.SEGMENTS)), bool) if take.present is None else take.present
    names = segments_with_data(present)
    index = [wire.SEGMENTS.index(s) for s in names]
    rows = _complete_rows(take, present[:, index], "segment")
    frames = joints.anatomical(take.q[rows], take.skeleton.rest_pose)[:, index]
    path.write_text(sto_text((take.t_us[rows] - take.t_us[0]) / 1e6, frames, names, 1e6 / take.period_us))


def export(take: Take, fmt: str, path: str | Path) -> None:
    """Write ``take`` as ``fmt`` (:data:`FORMATS`) to ``path``; ExportError naming it if it cannot."""
    path = Path(path)
    try:
        if fmt == "bvh":
            path.write_text(bvh_text(take))
        elif fmt == "csv":
            write_csv(take, path)
        elif fmt == "npz":
            write_npz(take, path)
        elif fmt == "mot":
            write_mot(take, path)
        elif fmt == "sto":
            write_sto(take, path)
        else:
            raise ExportError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    except OSError as exc:
        raise ExportError(f"-o {path}: cannot write ({exc.strerror or exc})") from None
