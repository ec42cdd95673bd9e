"""Synthetic full-body motion: the embedded default source of demos and tests.

Joint angles (degrees) of a few activities are cross-faded at activity changes and pushed
through a small kinematic tree to global orientations of the 10 :data:`SEGMENTS`:

    hip (pelvis) -> l/r_thigh -> l/r_shank
    hip -> trunk (not output) -> neck
    trunk -> l/r_upperarm -> l/r_lowerarm

Frames: world Y up; in the neutral standing pose (arms hanging, subject facing the world +Z
turned by the subject's heading about Y) every segment orientation is the heading alone, and
X points to the subject's left. Every value is a pure function of time (and of the sample
index for the noise), so :meth:`GeneratorSource.chunk` gives the same samples as
:func:`generate` and a live emulator can stream forever. A seed is a subject: it sets
cadence, amplitudes, phases, posture, heading, schedule lengths and the mounting offsets. The
default motion holds the rest pose still for :data:`STILL_S` s about every 30 s.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream import quat, wire
from limbstream.sources import SEGMENTS, Motion

JOINT_RANGES: dict[str, tuple[float, float]] = {
    "pelvis_tilt": (-20, 25),
    "pelvis_obliquity": (-15, 15),
    "pelvis_yaw": (-20, 20),
    "trunk_flex": (-20, 60),
    "trunk_lat": (-25, 25),
    "trunk_rot": (-30, 30),
    "neck_flex": (-40, 50),
    "neck_lat": (-30, 30),
    "neck_rot": (-60, 60),
    "hip_flex_l": (-25, 120),
    "hip_abd_l": (-20, 40),
    "hip_rot_l": (-30, 30),
    "hip_flex_r": (-25, 120),
    "hip_abd_r": (-20, 40),
    "hip_rot_r": (-30, 30),
    "knee_flex_l": (0, 140),
    "knee_flex_r": (0, 140),
    "shoulder_flex_l": (-50, 170),
    "shoulder_abd_l": (0, 175),
    "shoulder_rot_l": (-60, 60),
    "shoulder_flex_r": (-50, 170),
    "shoulder_abd_r": (0, 175),
    "shoulder_rot_r": (-60, 60),
    "elbow_flex_l": (0, 145),
    "elbow_flex_r": (0, 145),
}
"""Human range of motion of every joint angle the generator produces, degrees (flexion,
abduction and internal rotation positive). The generator stays inside these ranges."""

JOINTS: tuple[str, ...] = tuple(JOINT_RANGES)

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


def _bump(s: np.ndarray, centre: float, kappa: float) -> np.ndarray:
    """Smooth periodic bump in [0, 1] peaking at cycle fraction ``centre`` (von Mises shape)."""
    return np.exp(kappa * (np.cos(2 * np.pi * (s - centre)) - 1.0))


def _open(s: np.ndarray) -> np.ndarray:
    """0 -> 1 -> 0 over one cycle, smooth."""
    return 0.5 * (1.0 - np.cos(2 * np.pi * s))


class _Subject:
    """Seeded per-subject parameters."""

    def __init__(self, seed: int):
        rng = np.random.default_rng([int(seed), 0x11B5])
        self.cadence = rng.uniform(0.93, 1.07)
        self.amplitude = rng.uniform(0.9, 1.1)
        self.phase = rng.uniform(0.0, 1.0, size=8)
        self.heading = rng.uniform(-20.0, 20.0)
        self.posture = {  # small constant offsets, degrees
            "trunk_flex": rng.uniform(0, 5),
            "neck_flex": rng.uniform(0, 8),
            "shoulder_abd": rng.uniform(4, 10),
            "elbow_flex": rng.uniform(8, 18),
            "knee_flex": rng.uniform(2, 6),
        }
        self.sway = rng.uniform(0.08, 0.3, size=6)  # Hz
        self.schedule_scale = rng.uniform(0.9, 1.1)
        self.mounting = Rotation.random(len(SEGMENTS), random_state=rng).as_rotvec()
        self.mounting *= (
            rng.uniform(5, 15, len(SEGMENTS)) / np.degrees(np.linalg.norm(self.mounting, axis=1))
        )[:, None]


def _standing(t: np.ndarray, p: _Subject) -> dict[str, np.ndarray]:
    """Quiet standing with slow postural sway."""
    sw = [np.sin(2 * np.pi * f * t + 2 * np.pi * ph) for f, ph in zip(p.sway, p.phase[:6])]
    a = {
        "pelvis_tilt": 2 + 1.5 * sw[0],
        "pelvis_obliquity": 1.2 * sw[1],
        "pelvis_yaw": 2 * sw[2],
        "trunk_flex": p.posture["trunk_flex"] + 1.5 * sw[3],
        "trunk_lat": 1.5 * sw[4],
        "trunk_rot": 2 * sw[5],
        "neck_flex": p.posture["neck_flex"] + 3 * sw[2],
        "neck_lat": 2 * sw[0],
        "neck_rot": 6 * sw[1],
    }
    for side, sign in (("l", 1.0), ("r", -1.0)):
        a[f"hip_flex_{side}"] = 3 + 1.0 * sw[3] * sign
        a[f"hip_abd_{side}"] = 4 + 1.0 * sw[1] * sign
        a[f"hip_rot_{side}"] = 3 + 0 * t
        a[f"knee_flex_{side}"] = p.posture["knee_flex"] + 1.0 * sw[4]
        a[f"shoulder_flex_{side}"] = 2 + 2 * sw[5] * sign
        a[f"shoulder_abd_{side}"] = p.posture["shoulder_abd"] + 1.0 * sw[0]
        a[f"shoulder_rot_{side}"] = 5 + 0 * t
        a[f"elbow_flex_{side}"] = p.posture["elbow_flex"] + 2 * sw[2]
    return a


def _still(t: np.ndarray, p: _Subject) -> dict[str, np.ndarray]:
    """The rest pose (standing, arms hanging), not moving: every joint angle 0."""
    return {j: np.zeros(len(t)) for j in JOINTS}


def _gait(t: np.ndarray, p: _Subject, step_hz: float, phase: float) -> tuple[np.ndarray, np.ndarray]:
    """Gait-cycle fractions (left, right) in [0, 1) for a step frequency (two steps per cycle)."""
    s = (0.5 * step_hz * p.cadence * t + phase) % 1.0
    return s, (s + 0.5) % 1.0


def _walking(t: np.ndarray, p: _Subject) -> dict[str, np.ndarray]:
    """Walking, ~1.8 steps/s: hip 30 deg flexion to 10 deg extension, knee to ~60 deg in swing."""
    k = p.amplitude
    sl, sr = _gait(t, p, 1.8, p.phase[0])
    two = np.sin(4 * np.pi * sl)
    a = {
        "pelvis_tilt": 4 + 2 * two,
        "pelvis_obliquity": 4 * k * np.sin(2 * np.pi * sl),
        "pelvis_yaw": 5 * k * np.cos(2 * np.pi * sl),
        "trunk_flex": p.posture["trunk_flex"] + 2 + 1.5 * two,
        "trunk_lat": -2 * np.sin(2 * np.pi * sl),
        "trunk_rot": -7 * k * np.cos(2 * np.pi * sl),
        "neck_flex": p.posture["neck_flex"] + 1.5 * two,
        "neck_lat": 1.5 * np.sin(2 * np.pi * sl),
        "neck_rot": 3 * np.cos(2 * np.pi * sl),
    }
    for side, s, other in (("l", sl, sr), ("r", sr, sl)):
        a[f"hip_flex_{side}"] = 10 + 20 * k * np.cos(2 * np.pi * s)
        a[f"hip_abd_{side}"] = 2 + 3 * np.sin(2 * np.pi * s)
        a[f"hip_rot_{side}"] = 4 * np.cos(2 * np.pi * s)
        a[f"knee_flex_{side}"] = 4 + 12 * k * _bump(s, 0.13, 5.0) + 54 * k * _bump(s, 0.72, 4.0)
        a[f"shoulder_flex_{side}"] = 3 + 16 * k * np.cos(
            2 * np.pi * other
        )  # arm swings with the other leg
        a[f"shoulder_abd_{side}"] = p.posture["shoulder_abd"] + 2 * np.sin(2 * np.pi * s)
        a[f"shoulder_rot_{side}"] = 8 + 0 * t
        a[f"elbow_flex_{side}"] = p.posture["elbow_flex"] + 8 + 10 * k * _open(other + 0.25)
    return a


def _running(t: np.ndarray, p: _Subject) -> dict[str, np.ndarray]:
    """Running on the spot, ~2.7 steps/s: knees lifted to ~55 deg hip flexion, heels kicked back."""
    k = p.amplitude
    sl, sr = _gait(t, p, 2.7, p.phase[1])
    two = np.sin(4 * np.pi * sl)
    a = {
        "pelvis_tilt": 7 + 3 * two,
        "pelvis_obliquity": 4 * np.sin(2 * np.pi * sl),
        "pelvis_yaw": 4 * np.cos(2 * np.pi * sl),
        "trunk_flex": p.posture["trunk_flex"] + 6 + 2 * two,
        "trunk_lat": -2 * np.sin(2 * np.pi * sl),
        "trunk_rot": -6 * np.cos(2 * np.pi * sl),
        "neck_flex": p.posture["neck_flex"] - 4 + 2 * two,
        "neck_lat": 2 * np.sin(2 * np.pi * sl),
        "neck_rot": 3 * np.cos(2 * np.pi * sl),
    }
    for side, s, other in (("l", sl, sr), ("r", sr, sl)):
        a[f"hip_flex_{side}"] = 5 + 48 * k * _bump(s, 0.3, 1.2)
        a[f"hip_abd_{side}"] = 3 + 2 * np.sin(2 * np.pi * s)
        a[f"hip_rot_{side}"] = 3 * np.cos(2 * np.pi * s)
        a[f"knee_flex_{side}"] = 12 + 78 * k * _bump(s, 0.22, 1.2)
        a[f"shoulder_flex_{side}"] = 8 + 30 * k * np.cos(2 * np.pi * (other - 0.3))
        a[f"shoulder_abd_{side}"] = p.posture["shoulder_abd"] + 4 + 3 * np.sin(2 * np.pi * s)
        a[f"shoulder_rot_{side}"] = 15 + 0 * t
        a[f"elbow_flex_{side}"] = 80 + 12 * np.cos(2 * np.pi * (other - 0.3))
    return a


def _arm_circles(t: np.ndarray, p: _Subject) -> dict[str, np.ndarray]:
    """Forward arm circles at ~0.8 Hz with the arms held out to the sides."""
    k = p.amplitude
    theta = 2 * np.pi * (0.8 * p.cadence * t + p.phase[2])
    a = _standing(t, p)
    for side in ("l", "r"):
        a[f"shoulder_abd_{side}"] = 80 + 25 * k * np.cos(theta)
        a[f"shoulder_flex_{side}"] = 5 + 28 * k * np.sin(theta)
        a[f"shoulder_rot_{side}"] = 10 * np.sin(theta)
        a[f"elbow_flex_{side}"] = 6 + 3 * np.cos(theta)
    a["trunk_flex"] = a["trunk_flex"] + 2 * np.sin(theta)
    return a


def _jumping_jacks(t: np.ndarray, p: _Subject) -> dict[str, np.ndarray]:
    """Jumping jacks, ~1 per second: arms 10 -> 160 deg abduction, legs apart, landing knee dips."""
    k = p.amplitude
    s = (1.0 * p.cadence * t + p.phase[3]) % 1.0
    w = _open(s)
    land = _bump(s, 0.5, 8.0) + _bump(s, 0.0, 8.0)
    a = {
        "pelvis_tilt": 3 + 3 * land,
        "pelvis_obliquity": 0 * t,
        "pelvis_yaw": 0 * t,
        "trunk_flex": p.posture["trunk_flex"] + 3 * land,
        "trunk_lat": 0 * t,
        "trunk_rot": 0 * t,
        "neck_flex": p.posture["neck_flex"] - 10 * w + 4 * land,
        "neck_lat": 0 * t,
        "neck_rot": 0 * t,
    }
    for side in ("l", "r"):
        a[f"hip_flex_{side}"] = 4 + 14 * land
        a[f"hip_abd_{side}"] = 3 + 20 * k * w
        a[f"hip_rot_{side}"] = 8 * w
        a[f"knee_flex_{side}"] = 6 + 28 * land
        a[f"shoulder_flex_{side}"] = 3 + 4 * w
        a[f"shoulder_abd_{side}"] = 8 + 150 * k * w
        a[f"shoulder_rot_{side}"] = 5 + 0 * t
        a[f"elbow_flex_{side}"] = 12 - 6 * w
    return a


_ACTIVITY_FUNCS: dict[str, Callable[[np.ndarray, _Subject], dict[str, np.ndarray]]] = {
    "standing": _standing,
    "walking": _walking,
    "running": _running,
    "arm_circles": _arm_circles,
    "jumping_jacks": _jumping_jacks,
    "still": _still,
}


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
_TREE_JOINTS = [joint for joint, _, _ in _TREE_AXES]
_TREE_SIGNS = np.array([sign for _, sign, _ in _TREE_AXES])[:, None]
_TREE_AXIS = np.stack([axis for _, _, axis in _TREE_AXES])[:, None, :]


def _elementary_all(a: dict[str, np.ndarray], heading: float) -> dict[str, np.ndarray]:
    """{joint: (n, 4)} the rotations of :data:`_TREE_AXES` by the angles ``a`` (degrees, |angle|
    < 180; the pelvis yaw plus the heading), continuous in the angle; one scipy call for all."""
    angle = _TREE_SIGNS * np.stack([a[joint] for joint in _TREE_JOINTS])
    angle[0] = heading + a["pelvis_yaw"]  # _TREE_AXES starts with it
    rotvec = np.radians(angle)[:, :, None] * _TREE_AXIS
    q = quat.from_rotation(Rotation.from_rotvec(rotvec.reshape(-1, 3))).reshape(len(_TREE_AXES), -1, 4)
    return dict(zip(_TREE_JOINTS, q))


def _chains(parent: np.ndarray, e: dict[str, np.ndarray], *steps: list[str]) -> np.ndarray:
    """(c, n, 4) ``parent`` (n, 4) times c chains of factors at once (chain i's s-th: ``e[steps[s][i]]``)."""
    out = parent[None]
    for names in steps:
        out = quat.multiply(out, np.stack([e[name] for name in names]))
    return out


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
    """

    segments: tuple[str, ...] = SEGMENTS

    def __init__(self, seed: int = 0, fs: float = wire.DEVICE_RATE_HZ, activities=None, noise_deg: float = 0.0,
                 mounting_offsets: bool = False):
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
        self._subject = _Subject(self.seed)
        scale = self._subject.schedule_scale if activities is None else 1.0
        self._schedule = [(n, s if n == "still" else s * scale) for n, s in _schedule(activities)]
        self._starts = np.cumsum([0.0] + [s for _, s in self._schedule])
        self._mount = quat.from_rotation(Rotation.from_rotvec(self._subject.mounting))

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
        t = np.atleast_1d(np.asarray(t, np.float64))
        cur, prev, w = self._blend(t)
        out = {j: np.zeros(len(t)) for j in JOINTS}
        for idx in np.unique(np.concatenate([cur, prev[w < 1.0]])):
            w_cur = np.where(prev == cur, 1.0, w)  # a one-activity loop has nothing to fade from
            weight = np.where(cur == idx, w_cur, 0.0) + np.where(
                (prev == idx) & (cur != idx), 1.0 - w, 0.0
            )
            mask = weight > 0
            if not mask.any():
                continue
            angles = _ACTIVITY_FUNCS[self._schedule[idx][0]](t[mask], self._subject)
            for j in JOINTS:
                out[j][mask] += weight[mask] * angles[j]
        return out

    def orientations(self, t: np.ndarray) -> np.ndarray:
        """(n, 10, 4) noise-free global segment orientations at times ``t`` (s), SEGMENTS order.

        Mounting offsets apply if enabled; noise does not (it belongs to sample indices).
        """
        e = _elementary_all(self.joint_angles(t), self._subject.heading)
        # each level of the tree in one product per factor: all chains of a level advance together
        pelvis = quat.multiply(quat.multiply(e["pelvis_yaw"], e["pelvis_tilt"]), e["pelvis_obliquity"])
        trunk, thigh_l, thigh_r = _chains(pelvis, e, ["trunk_rot", "hip_abd_l", "hip_abd_r"],
                                          ["trunk_flex", "hip_flex_l", "hip_flex_r"],
                                          ["trunk_lat", "hip_rot_l", "hip_rot_r"])
        neck, upper_l, upper_r = _chains(trunk, e, ["neck_rot", "shoulder_abd_l", "shoulder_abd_r"],
                                         ["neck_flex", "shoulder_flex_l", "shoulder_flex_r"],
                                         ["neck_lat", "shoulder_rot_l", "shoulder_rot_r"])
        shank_l, shank_r, lower_l, lower_r = quat.multiply(np.stack([thigh_l, thigh_r, upper_l, upper_r]), np.stack(
            [e["knee_flex_l"], e["knee_flex_r"], e["elbow_flex_l"], e["elbow_flex_r"]]))
        seg = dict(hip=pelvis, neck=neck, l_thigh=thigh_l, r_thigh=thigh_r, l_shank=shank_l, r_shank=shank_r,
                   l_upperarm=upper_l, r_upperarm=upper_r, l_lowerarm=lower_l, r_lowerarm=lower_r)
        q = np.stack([seg[s] for s in SEGMENTS], axis=1)
        if self.mounting_offsets:
            q = quat.multiply(q, self._mount[None, :, :])
        return q

    def _noise(self, start: int, count: int) -> np.ndarray:
        """(count, 10, 4) noise rotations of samples start .. start + count - 1."""
        first, last = start // NOISE_BLOCK, (start + count - 1) // NOISE_BLOCK
        sigma = np.radians(self.noise_deg) / np.sqrt(3.0)  # per axis, so the RMS angle is noise_deg
        blocks = [np.random.default_rng([self.seed, 0x4E01, b]).normal(0.0, sigma, (NOISE_BLOCK, len(SEGMENTS), 3))
                  for b in range(first, last + 1)]
        rotvec = np.concatenate(blocks)[start - first * NOISE_BLOCK :][:count]
        return quat.from_rotation(Rotation.from_rotvec(rotvec.reshape(-1, 3))).reshape(
            count, len(SEGMENTS), 4
        )

    def chunk(self, start: int, count: int) -> tuple[np.ndarray, np.ndarray]:
        """Samples ``start`` .. ``start + count - 1``.

        Returns
        -------
        t : (count,) float64 seconds (``k / fs``).
        q : (count, 10, 4) float64 scalar-first unit quaternions, SEGMENTS order.
        """
        if start < 0 or count < 1:
            raise ValueError(f"chunk needs start >= 0 and count >= 1, got {start}, {count}")
        t = np.arange(start, start + count) / self.fs
        q = self.orientations(t)
        if self.noise_deg > 0:
            q = quat.multiply(q, self._noise(start, count))
        return t, q

    def sample(self, k: int) -> np.ndarray:
        """(10, 4) orientations of sample ``k`` (same values as in :meth:`chunk`)."""
        return self.chunk(k, 1)[1][0]

    def motion(self, duration_s: float) -> Motion:
        """The first ``duration_s`` seconds as a Motion (``round(duration_s * fs)`` samples).

        Returns
        -------
        Motion with t (m,) seconds and q (m, 10, 4), named ``synthetic-seed<seed>``.
        """
        count = round(duration_s * self.fs)
        if count < 1:
            raise ValueError(f"duration_s must give at least one sample, got {duration_s}")
        t, q = self.chunk(0, count)
        return Motion(t, q, SEGMENTS, f"synthetic-seed{self.seed}")


def generate(duration_s: float = 60.0, fs: float = wire.DEVICE_RATE_HZ, seed: int = 0, activities=None,
             noise_deg: float = 0.0, mounting_offsets: bool = False) -> Motion:
    """Synthetic full-body motion of one subject (see :class:`GeneratorSource` for the arguments).

    Returns
    -------
    Motion with t (m,) = k / fs seconds and q (m, 10, 4) global segment orientations.
    """
    return GeneratorSource(seed, fs, activities, noise_deg, mounting_offsets).motion(duration_s)
