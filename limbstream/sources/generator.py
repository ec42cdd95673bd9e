"""Synthetic full-body motion: the embedded default source of demos and tests.

Joint angles (degrees) of a few activities are cross-faded at activity changes and pushed
through a small kinematic tree to global orientations of the segments of a body layout
(``paper10``: the 10 :data:`SEGMENTS`; ``full``: its 15, :data:`limbstream.body.FULL`):

    hip (pelvis) -> l/r_thigh -> l/r_shank -> l/r_foot (full)
    hip -> trunk (full: chest) -> neck (full: head)
    trunk -> l/r_upperarm -> l/r_lowerarm -> l/r_hand (full)

``paper10``'s segments are the same in both layouts (``full`` adds the chest, the hands and the
feet, and calls the head ``head``). The activities' joint angles are :mod:`.generator_activities`',
the hands' and feet's :mod:`.generator_limbs`'.

Frames: world Y up; in the neutral standing pose (arms hanging, feet flat on the floor, subject
facing the world +Z turned by the subject's heading about Y) every segment orientation is the
heading alone, and X points to the subject's left. Every value is a pure function of time (and
of the sample index for the noise), so :meth:`GeneratorSource.chunk` gives the same samples as
:func:`generate` and a live emulator can stream forever. A seed is a subject: it sets
cadence, amplitudes, phases, posture, heading, schedule lengths and the mounting offsets. The
default motion holds the rest pose still for :data:`STILL_S` s about every 30 s.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream import quat, wire
from limbstream.body import FULL, Layout
from limbstream.kernel.tree import Tree
from limbstream.sources import SEGMENTS, Motion
from limbstream.sources import generator_limbs as limbs
from limbstream.sources.generator_activities import ACTIVITY_FUNCS as _ACTIVITY_FUNCS
from limbstream.sources.generator_activities import Subject
from limbstream.sources.generator_activities import JOINT_RANGES, JOINTS  # noqa: F401  (re-exported)

ACTIVITIES: tuple[str, ...] = ("standing", "walking", "running", "arm_circles", "jumping_jacks", "still")
"""Activity names (``still``: the rest pose, not moving at all); ``"transition"`` labels the
cross-fades between them."""

TRANSITION_S = 1.5
"""Length of the joint-angle cross-fade at the start of each activity, seconds."""
STILL_S = 3.0
"""How long the default motion holds the rest pose perfectly still, twice a loop (about every
30 s): after its cross-fade into it, seconds; not scaled with the subject's schedule."""

DEFAULT_SCHEDULE: tuple[tuple[str, float], ...] = (
    ("standing", 4.0),
    ("walking", 12.0),
    ("running", 8.0),
    ("still", TRANSITION_S + STILL_S),
    ("standing", 3.0),
    ("arm_circles", 8.0),
    ("jumping_jacks", 8.0),
    ("walking", 6.0),
    ("still", TRANSITION_S + STILL_S),
)
"""(activity, seconds) played in a loop when no activities are given: the rest pose held still
for :data:`STILL_S` s about every 30 s (a rest calibration can be made then)."""

NOISE_BLOCK = 1024
"""Samples per independently seeded block of sensor noise (keeps chunks equal to the batch)."""

_X, _Y, _Z = np.eye(3)


def _schedule(
    activities: str | Sequence[str | tuple[str, float]] | None,
) -> list[tuple[str, float]]:
    """Normalise the ``activities`` argument to (name, seconds) pairs."""
    if activities is None:
        return list(DEFAULT_SCHEDULE)
    if isinstance(activities, str):
        activities = [activities]
    out = []
    for item in activities:
        name, seconds = (item, 8.0) if isinstance(item, str) else item
        if name not in _ACTIVITY_FUNCS:
            raise ValueError(f"activities: unknown activity {name!r} (known: {', '.join(ACTIVITIES)})")
        if not seconds > TRANSITION_S:
            raise ValueError(f"activities: {name!r} lasts {seconds} s, must exceed {TRANSITION_S} s")
        out.append((name, float(seconds)))
    if not out:
        raise ValueError("activities: empty")
    return out


def _axis_index(axis: np.ndarray) -> int:
    """0, 1 or 2: which coordinate axis the unit vector ``axis`` is (ValueError for another vector)."""
    for i, unit in enumerate(np.eye(3)):
        if np.array_equal(axis, unit):
            return i
    raise ValueError(f"{axis} is no coordinate axis")


# The elementary rotations of the kinematic tree: (joint, sign, axis), the rotation by sign * the
# joint's angle about the axis. Each segment's orientation is its parent's times its own factors,
# left to right (orientations()).
_TREE_AXES: list[tuple[str, float, np.ndarray]] = [
    ("pelvis_yaw", 1.0, _Y), ("pelvis_tilt", 1.0, _X), ("pelvis_obliquity", 1.0, _Z),
    ("trunk_rot", 1.0, _Y), ("trunk_flex", 1.0, _X), ("trunk_lat", 1.0, _Z),
    ("neck_rot", 1.0, _Y), ("neck_flex", 1.0, _X), ("neck_lat", 1.0, _Z),
] + [
    (f"{joint}_{side}", sign, axis)
    for side, lat in (("l", 1.0), ("r", -1.0))
    # abduction moves a hanging limb away from the midline (+X is the subject's left): the
    # abductions and rotations take the side's sign (lat)
    for joint, sign, axis in (
        ("hip_abd", lat, _Z), ("hip_flex", -1.0, _X), ("hip_rot", -lat, _Y), ("knee_flex", 1.0, _X),
        ("shoulder_abd", lat, _Z), ("shoulder_flex", -1.0, _X), ("shoulder_rot", -lat, _Y), ("elbow_flex", -1.0, _X),
    )
]
SIDE = 9
"""The first of the sides' joints in :data:`_TREE_AXES` (the left's, then as many of the right's)."""
_LIMB_NODE = len(_TREE_AXES)
"""The first of the hands' and feet's nodes (:data:`limbs.AXES`, the left's then the right's)."""


def _tree_parents() -> list[int]:
    """The parent node of each elementary rotation of :data:`_TREE_AXES` then :data:`limbs.AXES`
    (-1: the first, the pelvis's yaw from the identity): each segment's factors left to right,
    from its parent segment's last."""
    parents = [-1, 0, 1, 2, 3, 4, 5, 6, 7]  # pelvis, trunk, neck
    for side in range(2):
        b = SIDE + 8 * side  # hip_abd, hip_flex, hip_rot, knee_flex, shoulder_abd, ..., elbow_flex
        parents += [2, b, b + 1, b + 2, 5, b + 4, b + 5, b + 6]
    for side in range(2):
        b, limb = SIDE + 8 * side, _LIMB_NODE + 4 * side  # ankle_flex, subtalar, wrist_flex, wrist_dev
        parents += [b + 3, limb, b + 7, limb + 2]
    return parents


def _segment_nodes() -> dict[str, int]:
    """The node whose orientation is each segment's."""
    nodes = {"hip": 2, "chest": 5, "neck": 8, "head": 8}
    for i, side in enumerate("lr"):
        b, limb = SIDE + 8 * i, _LIMB_NODE + 4 * i
        nodes.update({f"{side}_thigh": b + 2, f"{side}_shank": b + 3, f"{side}_upperarm": b + 6,
                      f"{side}_lowerarm": b + 7, f"{side}_foot": limb + 1, f"{side}_hand": limb + 3})
    return nodes


_NODE_ANGLES = [(joint, sign) for joint, sign, _ in _TREE_AXES + limbs.AXES]
"""Each node's joint angle and its sign."""
_NODE_AXIS = [_axis_index(axis) for _, _, axis in _TREE_AXES + limbs.AXES]
_NODE_PARENT = _tree_parents()
_SEGMENT_NODE = _segment_nodes()


class GeneratorSource:
    """Seeded synthetic subject, sample by sample or in chunks, forever.

    Parameters
    ----------
    seed : int >= 0, the subject (cadence, amplitudes, phases, posture, heading, mounting offsets).
    fs : sample rate, Hz; sample k is at ``k / fs`` s.
    activities : None (the :data:`DEFAULT_SCHEDULE` loop), one activity name, or a sequence of
        names (8 s each) or (name, seconds) pairs, played in a loop with cross-fades.
    noise_deg : RMS angle of white sensor noise added to every sample, degrees.
    mounting_offsets : apply a fixed 5-15 deg sensor-to-segment rotation per segment.
    layout : the body whose segments it outputs, in its order: ``"paper10"`` (:data:`SEGMENTS`),
        ``"full"`` (:data:`limbstream.body.FULL`, 15 segments) or a Layout whose segments are all
        among :data:`KNOWN_SEGMENTS`. A segment's motion, mounting offset and noise are the same in
        every layout that has it (``full``'s head is paper10's neck).
    """

    segments: tuple[str, ...] = SEGMENTS

    def __init__(self, seed: int = 0, fs: float = wire.DEVICE_RATE_HZ, activities=None, noise_deg: float = 0.0,
                 mounting_offsets: bool = False, layout: str | Layout = "paper10"):
        if int(seed) < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        if not fs > 0:
            raise ValueError(f"fs must be > 0 Hz, got {fs}")
        if not noise_deg >= 0:
            raise ValueError(f"noise_deg must be >= 0, got {noise_deg}")
        self.seed = int(seed)
        self.fs = float(fs)
        self.noise_deg = float(noise_deg)
        self.mounting_offsets = bool(mounting_offsets)
        self._subject = Subject(self.seed)
        scale = self._subject.schedule_scale if activities is None else 1.0
        self._schedule = [(n, s if n == "still" else s * scale) for n, s in _schedule(activities)]
        self._starts = np.cumsum([0.0] + [s for _, s in self._schedule])
        self.segments = _segments_of(layout)
        self._limbs = self.segments != SEGMENTS  # paper10 alone computes neither hands nor feet
        nodes = len(_NODE_AXIS) if self._limbs else _LIMB_NODE
        self._tree = Tree(_NODE_AXIS[:nodes], _NODE_PARENT[:nodes], [_SEGMENT_NODE[s] for s in self.segments])
        mounting = dict(zip(SEGMENTS + limbs.SEGMENTS, np.concatenate([self._subject.mounting,
                                                                       self._subject.limbs.mounting])))
        mounting["head"] = mounting["neck"]
        self._mount = quat.from_rotation(Rotation.from_rotvec(np.stack([mounting[s] for s in self.segments])))

    @property
    def period_s(self) -> float:
        """Length of one loop of the activity schedule, seconds."""
        return float(self._starts[-1])

    def _blend(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Index of the current and previous activity and the current one's weight, per time."""
        tc = np.mod(t, self.period_s)
        i = np.clip(np.searchsorted(self._starts, tc, side="right") - 1, 0, len(self._schedule) - 1)
        u = np.clip((tc - self._starts[i]) / TRANSITION_S, 0.0, 1.0)
        w = u * u * (3.0 - 2.0 * u)  # smoothstep
        w = np.where(t < TRANSITION_S, 1.0, w)  # the very first activity starts without a fade
        return i, (i - 1) % len(self._schedule), w

    def activity_at(self, t: np.ndarray) -> np.ndarray:
        """(n,) activity names at times ``t`` (s); ``"transition"`` inside cross-fades."""
        t = np.atleast_1d(np.asarray(t, np.float64))
        i, prev, w = self._blend(t)
        names = np.array([n for n, _ in self._schedule], dtype=object)[i]
        return np.where((w < 1.0) & (i != prev), "transition", names)

    def joint_angles(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """Joint angles at times ``t``.

        Parameters
        ----------
        t : (n,) seconds.

        Returns
        -------
        dict joint -> (n,) float64 degrees, for every name in :data:`JOINTS`.
        """
        return self._joint_angles(t, feet=True)

    def _joint_angles(self, t: np.ndarray, feet: bool) -> dict[str, np.ndarray]:
        """:meth:`joint_angles`; without ``feet`` the ankles and subtalar joints are left as the
        activities give them, not kept to the floor (paper10's segments do not depend on them)."""
        t = np.atleast_1d(np.asarray(t, np.float64))
        cur, prev, w = self._blend(t)
        out = np.zeros((len(JOINTS), len(t)))
        for idx in np.unique(np.concatenate([cur, prev[w < 1.0]])):
            w_cur = np.where(prev == cur, 1.0, w)  # a one-activity loop has nothing to fade from
            weight = np.where(cur == idx, w_cur, 0.0) + np.where(
                (prev == idx) & (cur != idx), 1.0 - w, 0.0
            )
            mask = weight > 0
            if not mask.any():
                continue
            angles = _ACTIVITY_FUNCS[self._schedule[idx][0]](t[mask], self._subject)
            every = mask.all()
            activity = np.empty((len(JOINTS), len(t) if every else int(mask.sum())))
            for row, j in zip(activity, JOINTS):
                row[:] = angles[j]
            if every:
                out += weight * activity
            else:
                out[:, mask] += weight[mask] * activity
        angles = dict(zip(JOINTS, out))
        if feet:
            limbs.on_the_floor(angles)  # after the cross-fades: the feet keep to the floor through them too
        return angles

    def orientations(self, t: np.ndarray) -> np.ndarray:
        """(n, S, 4) noise-free global orientations of :attr:`segments` at times ``t`` (s).

        Mounting offsets apply if enabled; noise does not (it belongs to sample indices).
        """
        a = self._joint_angles(t, feet=self._limbs)
        deg = np.empty((len(self._tree.axis), len(t)))
        for row, (joint, sign) in zip(deg, _NODE_ANGLES):
            np.multiply(sign, a[joint], out=row)
        deg[0] = self._subject.heading + a["pelvis_yaw"]  # the first node
        q = self._tree.turn(deg)
        if self.mounting_offsets:
            q = quat.multiply(q, self._mount[None, :, :])
        return q

    def _noise(self, start: int, count: int) -> np.ndarray:
        """(count, S, 4) noise rotations of samples start .. start + count - 1 (paper10's segments
        from one stream, the others from a second one: a segment's noise is the same in every layout)."""
        rotvec = self._noise_rotvec(start, count, 0x4E01, len(SEGMENTS))
        if self._limbs:
            by_name = dict(zip(SEGMENTS + limbs.SEGMENTS, np.concatenate(
                [rotvec, self._noise_rotvec(start, count, 0x4E02, len(limbs.SEGMENTS))], axis=1).swapaxes(0, 1)))
            by_name["head"] = by_name["neck"]
            rotvec = np.stack([by_name[s] for s in self.segments], axis=1)
        return quat.from_rotation(Rotation.from_rotvec(rotvec.reshape(-1, 3))).reshape(count, len(self.segments), 4)

    def _noise_rotvec(self, start: int, count: int, stream: int, width: int) -> np.ndarray:
        """(count, width, 3) white noise rotation vectors, rad, of samples start .. start + count - 1."""
        first, last = start // NOISE_BLOCK, (start + count - 1) // NOISE_BLOCK
        sigma = np.radians(self.noise_deg) / np.sqrt(3.0)  # per axis, so the RMS angle is noise_deg
        blocks = [np.random.default_rng([self.seed, stream, b]).normal(0.0, sigma, (NOISE_BLOCK, width, 3))
                  for b in range(first, last + 1)]
        return np.concatenate(blocks)[start - first * NOISE_BLOCK :][:count]

    def chunk(self, start: int, count: int) -> tuple[np.ndarray, np.ndarray]:
        """Samples ``start`` .. ``start + count - 1``.

        Returns
        -------
        t : (count,) float64 seconds (``k / fs``).
        q : (count, S, 4) float64 scalar-first unit quaternions, :attr:`segments` order.
        """
        if start < 0 or count < 1:
            raise ValueError(f"chunk needs start >= 0 and count >= 1, got {start}, {count}")
        t = np.arange(start, start + count) / self.fs
        q = self.orientations(t)
        if self.noise_deg > 0:
            q = quat.multiply(q, self._noise(start, count))
        return t, q

    def sample(self, k: int) -> np.ndarray:
        """(S, 4) orientations of sample ``k`` (same values as in :meth:`chunk`)."""
        return self.chunk(k, 1)[1][0]

    def motion(self, duration_s: float) -> Motion:
        """The first ``duration_s`` seconds as a Motion (``round(duration_s * fs)`` samples).

        Returns
        -------
        Motion with t (m,) seconds and q (m, S, 4) of :attr:`segments`, named ``synthetic-seed<seed>``.
        """
        count = round(duration_s * self.fs)
        if count < 1:
            raise ValueError(f"duration_s must give at least one sample, got {duration_s}")
        t, q = self.chunk(0, count)
        return Motion(t, q, self.segments, f"synthetic-seed{self.seed}")


KNOWN_SEGMENTS: tuple[str, ...] = FULL.segment_names + ("neck",)
"""The segments the generator moves: ``full``'s and paper10's ``neck`` (the same as ``head``)."""


def _segments_of(layout: str | Layout) -> tuple[str, ...]:
    """The segments of a layout (a built-in's name or a Layout); ValueError naming those the
    generator does not move."""
    from limbstream.body import builtin_layout
    lay = builtin_layout(layout) if isinstance(layout, str) else layout
    unknown = [s for s in lay.segment_names if s not in KNOWN_SEGMENTS]
    if unknown:
        raise ValueError(f"layout {lay.name}: the generator moves no segment {', '.join(map(repr, unknown))} "
                         f"(it moves {', '.join(KNOWN_SEGMENTS)})")
    return lay.segment_names


def generate(duration_s: float = 60.0, fs: float = wire.DEVICE_RATE_HZ, seed: int = 0, activities=None,
             noise_deg: float = 0.0, mounting_offsets: bool = False, layout: str | Layout = "paper10") -> Motion:
    """Synthetic full-body motion of one subject (see :class:`GeneratorSource` for the arguments).

    Returns
    -------
    Motion with t (m,) = k / fs seconds and q (m, S, 4) global orientations of the layout's segments.
    """
    return GeneratorSource(seed, fs, activities, noise_deg, mounting_offsets, layout).motion(duration_s)
