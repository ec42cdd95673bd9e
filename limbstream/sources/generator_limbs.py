"""The hands and feet of the built-in generator's ``full`` body (:mod:`.generator`).

Each activity gives the wrists and ankles angles of their own (:func:`walking_feet`,
:func:`hands`, ...); after the activities are cross-faded, :func:`on_the_floor` keeps the feet on
the floor the legs stand on: the body turns about a fixed pelvis, so the floor is where the lower
leg's ankle stands (the ankle height above it), and no toe goes below it while the ankle may turn
(dorsiflexion is bounded by its range). The stance foot is so held flat; a foot whose leg rises
rolls freely; a foot near the floor is also held flat side to side by the subtalar joint. The
legs' sagittal geometry is taken planar (thigh and shank at their angles from the vertical, scaled
by the leg's sideways tilt), with Winter's proportions of body height (:mod:`limbstream.body`).

Kinematics (same frames as the generator's): foot = shank x R_X(-ankle_flex) x R_Z(-lat subtalar),
hand = lowerarm x R_Z(-lat wrist_flex) x R_X(wrist_dev), lat = +1 left, -1 right. At identity the
foot lies flat on the floor (its toe forward and down by the ankle height) and the hand hangs on
from the forearm, its palm against the thigh (thumb forward: the standing rest pose's hand,
limbstream.joints.convention): flexion turns it towards the palm (medially), ulnar deviation
backwards, as the joint angles read them (``wrist_flex``, ``wrist_dev`` of the full layout).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream.body.builtin import WINTER_HEIGHTS, WINTER_LENGTHS

RANGES: dict[str, tuple[float, float]] = {
    "ankle_flex_l": (-40, 30),
    "subtalar_l": (-15, 30),
    "ankle_flex_r": (-40, 30),
    "subtalar_r": (-15, 30),
    "wrist_flex_l": (-60, 70),
    "wrist_dev_l": (-15, 25),
    "wrist_flex_r": (-60, 70),
    "wrist_dev_r": (-15, 25),
}
"""Ranges of the hands' and feet's joint angles, degrees: ankle dorsiflexion, subtalar inversion,
wrist flexion and ulnar deviation positive (the model's signs). The ankle's dorsiflexion is a loaded foot's (a
lunge's or a landing's reaches 35-45; unloaded, 20): on the spot the stance foot stays flat under
a shank leaning over it (terminal stance, running stance, landings)."""

_X, _Y, _Z = np.eye(3)
AXES: list[tuple[str, float, np.ndarray]] = [
    (f"{joint}_{side}", sign, axis)
    for side, lat in (("l", 1.0), ("r", -1.0))
    for joint, sign, axis in (("ankle_flex", -1.0, _X), ("subtalar", -lat, _Z),
                              ("wrist_flex", -lat, _Z), ("wrist_dev", 1.0, _X))
]
"""(joint, sign, axis) of the elementary rotations of the feet and hands, as the generator's tree."""

SEGMENTS: tuple[str, ...] = ("chest", "l_hand", "r_hand", "l_foot", "r_foot")
"""The full body's segments beyond paper10's (whose ``neck`` is ``full``'s ``head``), in the order
of their own mounting offsets and noise."""

THIGH, SHANK, FOOT = WINTER_LENGTHS["thigh"], WINTER_LENGTHS["shank"], WINTER_LENGTHS["foot"]
ANKLE = WINTER_HEIGHTS["ankle"]
FOOT_DROP_DEG = float(np.degrees(np.arcsin(ANKLE / FOOT)))
"""The foot's rest direction below the horizontal (ankle to toe tip on the floor), degrees."""
FREE_LIFT = 0.02
"""A foot this far (fraction of height) above the floor is free to roll side to side."""


class LimbSubject:
    """Seeded per-subject posture of the hands and feet (a stream of its own: paper10's
    parameters stay as they are)."""

    def __init__(self, seed: int):
        rng = np.random.default_rng([int(seed), 0x11B6])
        self.wrist_flex = rng.uniform(2, 10)
        self.wrist_dev = -rng.uniform(-8, -2)  # relaxed hands rest slightly ulnar (2-8 degrees)
        self.phase = rng.uniform(-0.05, 0.05)  # the hands' lag behind the forearms, cycles
        self.mounting = Rotation.random(len(SEGMENTS), random_state=rng).as_rotvec()  # of SEGMENTS, 5-15 deg
        self.mounting *= (rng.uniform(5, 15, len(SEGMENTS)) / np.degrees(np.linalg.norm(self.mounting, axis=1)))[:, None]


def _bump(s: np.ndarray, centre: float, kappa: float) -> np.ndarray:
    return np.exp(kappa * (np.cos(2 * np.pi * (s - centre)) - 1.0))


def walking_feet(s: np.ndarray, k: float) -> dict[str, np.ndarray]:
    """Ankle and subtalar angles over the gait cycle ``s`` (0: heel strike): slight dorsiflexion at
    heel strike, plantarflexion in loading and at push-off (where the floor allows: the toe stays
    on it), dorsiflexed through swing; inversion at heel strike and push-off, eversion in stance."""
    return {"ankle_flex": 5 * _bump(s, 0.9, 4) - 6 * _bump(s, 0.08, 30) - 16 * k * _bump(s, 0.6, 20),
            "subtalar": 2 + 3 * _bump(s, 0.0, 8) - 5 * _bump(s, 0.3, 6) + 3 * _bump(s, 0.6, 10)}


def running_feet(s: np.ndarray, k: float) -> dict[str, np.ndarray]:
    """Ankle and subtalar angles running on the spot (``s``: the leg's cycle, knee lift near 0.3):
    plantarflexed pushing off, dorsiflexed as the knee lifts."""
    return {"ankle_flex": -4 + 10 * _bump(s, 0.35, 3) - 12 * k * _bump(s, 0.05, 8),
            "subtalar": 2 + 3 * np.sin(2 * np.pi * s)}


def still_feet(sway: np.ndarray, sway2: np.ndarray) -> dict[str, np.ndarray]:
    """Standing: the ankles sway a little (the floor keeps the feet flat)."""
    return {"ankle_flex": 1.5 * sway, "subtalar": 1.0 * sway2}


def hands(p: LimbSubject, flex: np.ndarray, radial: np.ndarray) -> dict[str, np.ndarray]:
    """Wrist angles: the subject's relaxed posture plus ``flex`` (degrees, towards the palm) and
    ``radial`` deviation (degrees, towards the thumb: ulnar deviation less it)."""
    return {"wrist_flex": p.wrist_flex + flex, "wrist_dev": p.wrist_dev - radial}


def add(a: dict[str, np.ndarray], side: str, angles: dict[str, np.ndarray]) -> None:
    """Put one side's angles (``ankle_flex``, ...) into ``a`` as ``ankle_flex_l``, ..."""
    for name, value in angles.items():
        a[f"{name}_{side}"] = value


def on_the_floor(a: dict[str, np.ndarray]) -> None:
    """Keep the feet on the floor (module docstring), in place: each ankle at least as dorsiflexed
    as keeps its toe at or above the floor (at most its range allows), each subtalar joint turned
    to hold a foot near the floor flat side to side. The rest pose stays exactly the rest pose."""
    legs = {}
    for side, lat in (("l", 1.0), ("r", -1.0)):
        thigh = a[f"hip_flex_{side}"] - a["pelvis_tilt"]  # forward from the vertical, degrees
        shank = thigh - a[f"knee_flex_{side}"]
        tilt = a[f"hip_abd_{side}"] + lat * a["pelvis_obliquity"]  # the leg out to its side
        drop = (THIGH * np.cos(np.radians(thigh)) + SHANK * np.cos(np.radians(shank))) * np.cos(np.radians(tilt))
        legs[side] = shank, tilt, drop
    floor = np.maximum(legs["l"][2], legs["r"][2])
    for side, (shank, tilt, drop) in legs.items():
        lift = floor - drop  # the ankle above the lower one, fraction of height
        lowest = FOOT_DROP_DEG - np.degrees(np.arcsin(np.minimum((ANKLE + lift) / FOOT, 1.0)))  # foot pitch, toe up
        lo, hi = RANGES[f"ankle_flex_{side}"]
        a[f"ankle_flex_{side}"] = np.minimum(np.maximum(a[f"ankle_flex_{side}"], lowest - shank), hi)
        u = np.clip(1.0 - lift / FREE_LIFT, 0.0, 1.0)
        lo, hi = RANGES[f"subtalar_{side}"]
        a[f"subtalar_{side}"] = np.clip(a[f"subtalar_{side}"] + u * u * (3 - 2 * u) * tilt, lo, hi)
