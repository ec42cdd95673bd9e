"""The activities of the built-in generator (:mod:`.generator`): each one's joint angles,
degrees, as functions of time and of the subject (:class:`Subject`, its seeded parameters)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream.sources import SEGMENTS
from limbstream.sources import generator_limbs as limbs

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
    **limbs.RANGES,
}
"""Human range of motion of every joint angle the generator produces, degrees (flexion,
abduction and internal rotation positive). The generator stays inside these ranges."""

JOINTS: tuple[str, ...] = tuple(JOINT_RANGES)


def _bump(s: np.ndarray, centre: float, kappa: float) -> np.ndarray:
    """Smooth periodic bump in [0, 1] peaking at cycle fraction ``centre`` (von Mises shape)."""
    return np.exp(kappa * (np.cos(2 * np.pi * (s - centre)) - 1.0))


def _open(s: np.ndarray) -> np.ndarray:
    """0 -> 1 -> 0 over one cycle, smooth."""
    return 0.5 * (1.0 - np.cos(2 * np.pi * s))


class Subject:
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
        self.limbs = limbs.LimbSubject(seed)  # the hands' and feet's, drawn apart


def _standing(t: np.ndarray, p: Subject) -> dict[str, np.ndarray]:
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
        limbs.add(a, side, limbs.still_feet(sw[3] * sign, sw[1]) | limbs.hands(p.limbs, 2 * sw[4], 1.5 * sw[5] * sign))
    return a


def _still(t: np.ndarray, p: Subject) -> dict[str, np.ndarray]:
    """The rest pose (standing, arms hanging), not moving: every joint angle 0."""
    return {j: np.zeros(len(t)) for j in JOINTS}


def _gait(t: np.ndarray, p: Subject, step_hz: float, phase: float) -> tuple[np.ndarray, np.ndarray]:
    """Gait-cycle fractions (left, right) in [0, 1) for a step frequency (two steps per cycle)."""
    s = (0.5 * step_hz * p.cadence * t + phase) % 1.0
    return s, (s + 0.5) % 1.0


def _cycle(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cos, sin) of the cycle fraction ``s`` as an angle, each computed once for every joint that
    reads it."""
    turn = 2 * np.pi * s
    return np.cos(turn), np.sin(turn)


def _walking(t: np.ndarray, p: Subject) -> dict[str, np.ndarray]:
    """Walking, ~1.8 steps/s: hip 30 deg flexion to 10 deg extension, knee to ~60 deg in swing."""
    k = p.amplitude
    sl, sr = _gait(t, p, 1.8, p.phase[0])
    leg = {"l": _cycle(sl), "r": _cycle(sr)}
    cos_l, sin_l = leg["l"]
    two = np.sin(4 * np.pi * sl)
    a = {
        "pelvis_tilt": 4 + 2 * two,
        "pelvis_obliquity": 4 * k * sin_l,
        "pelvis_yaw": 5 * k * cos_l,
        "trunk_flex": p.posture["trunk_flex"] + 2 + 1.5 * two,
        "trunk_lat": -2 * sin_l,
        "trunk_rot": -7 * k * cos_l,
        "neck_flex": p.posture["neck_flex"] + 1.5 * two,
        "neck_lat": 1.5 * sin_l,
        "neck_rot": 3 * cos_l,
    }
    for side, s, other in (("l", sl, sr), ("r", sr, sl)):
        cos_s, sin_s = leg[side]
        a[f"hip_flex_{side}"] = 10 + 20 * k * cos_s
        a[f"hip_abd_{side}"] = 2 + 3 * sin_s
        a[f"hip_rot_{side}"] = 4 * cos_s
        a[f"knee_flex_{side}"] = 4 + 12 * k * _bump(s, 0.13, 5.0) + 54 * k * _bump(s, 0.72, 4.0)
        a[f"shoulder_flex_{side}"] = 3 + 16 * k * leg["r" if side == "l" else "l"][0]  # arm swings with the other leg
        a[f"shoulder_abd_{side}"] = p.posture["shoulder_abd"] + 2 * sin_s
        a[f"shoulder_rot_{side}"] = 8 + 0 * t
        a[f"elbow_flex_{side}"] = p.posture["elbow_flex"] + 8 + 10 * k * _open(other + 0.25)
        swing = 2 * np.pi * (other + p.limbs.phase)  # the hand swings behind the forearm
        limbs.add(a, side, limbs.walking_feet(s, k) | limbs.hands(p.limbs, 6 * k * np.sin(swing), 3 * np.cos(swing)))
    return a


def _running(t: np.ndarray, p: Subject) -> dict[str, np.ndarray]:
    """Running on the spot, ~2.7 steps/s: knees lifted to ~55 deg hip flexion, heels kicked back."""
    k = p.amplitude
    sl, sr = _gait(t, p, 2.7, p.phase[1])
    leg = {"l": _cycle(sl), "r": _cycle(sr)}
    cos_l, sin_l = leg["l"]
    two = np.sin(4 * np.pi * sl)
    a = {
        "pelvis_tilt": 7 + 3 * two,
        "pelvis_obliquity": 4 * sin_l,
        "pelvis_yaw": 4 * cos_l,
        "trunk_flex": p.posture["trunk_flex"] + 6 + 2 * two,
        "trunk_lat": -2 * sin_l,
        "trunk_rot": -6 * cos_l,
        "neck_flex": p.posture["neck_flex"] - 4 + 2 * two,
        "neck_lat": 2 * sin_l,
        "neck_rot": 3 * cos_l,
    }
    for side, s, other in (("l", sl, sr), ("r", sr, sl)):
        cos_s, sin_s = leg[side]
        a[f"hip_flex_{side}"] = 5 + 48 * k * _bump(s, 0.3, 1.2)
        a[f"hip_abd_{side}"] = 3 + 2 * sin_s
        a[f"hip_rot_{side}"] = 3 * cos_s
        a[f"knee_flex_{side}"] = 12 + 78 * k * _bump(s, 0.22, 1.2)
        a[f"shoulder_flex_{side}"] = 8 + 30 * k * np.cos(2 * np.pi * (other - 0.3))
        a[f"shoulder_abd_{side}"] = p.posture["shoulder_abd"] + 4 + 3 * sin_s
        a[f"shoulder_rot_{side}"] = 15 + 0 * t
        a[f"elbow_flex_{side}"] = 80 + 12 * np.cos(2 * np.pi * (other - 0.3))
        pump = np.cos(2 * np.pi * (other - 0.3 + p.limbs.phase))
        limbs.add(a, side, limbs.running_feet(s, k) | limbs.hands(p.limbs, -5 + 5 * pump, 2 * pump))
    return a


def _arm_circles(t: np.ndarray, p: Subject) -> dict[str, np.ndarray]:
    """Forward arm circles at ~0.8 Hz with the arms held out to the sides."""
    k = p.amplitude
    theta = 2 * np.pi * (0.8 * p.cadence * t + p.phase[2])
    a = _standing(t, p)
    for side in ("l", "r"):
        a[f"shoulder_abd_{side}"] = 80 + 25 * k * np.cos(theta)
        a[f"shoulder_flex_{side}"] = 5 + 28 * k * np.sin(theta)
        a[f"shoulder_rot_{side}"] = 10 * np.sin(theta)
        a[f"elbow_flex_{side}"] = 6 + 3 * np.cos(theta)
        lag = theta - 2 * np.pi * (0.1 + p.limbs.phase)  # the hands circle behind the arms
        limbs.add(a, side, limbs.hands(p.limbs, 12 * k * np.sin(lag), 8 * k * np.cos(lag)))
    a["trunk_flex"] = a["trunk_flex"] + 2 * np.sin(theta)
    return a


def _jumping_jacks(t: np.ndarray, p: Subject) -> dict[str, np.ndarray]:
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
        # the feet: flat on the floor (generator_limbs.on_the_floor); the wrists extend as the arms rise
        limbs.add(a, side, limbs.still_feet(-land, 0 * t) | limbs.hands(p.limbs, -15 * w, -10 * k * w))
    return a


ACTIVITY_FUNCS: dict[str, Callable[[np.ndarray, Subject], dict[str, np.ndarray]]] = {
    "standing": _standing,
    "walking": _walking,
    "running": _running,
    "arm_circles": _arm_circles,
    "jumping_jacks": _jumping_jacks,
    "still": _still,
}
