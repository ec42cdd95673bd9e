"""Stillness: a still joint keeps its relative heading, and a subject standing still in the rest
pose is a known pose.

- **Still joint** (SlimeVR's locked trackers; qmt's stillness correction): when both segments of a
  joint have been still for a while, the joint does not turn, so any change of its twist about
  the vertical is drift: the twist is held at its value when the joint came to rest.
- **Relaxed pose** (SlimeVR's Stay Aligned): when every segment of the subject is still and each
  joint's two segments lean as in the rest pose (same vertical in both frames), the subject
  stands as at calibration, and each joint's twist is taken back to the rest pose's (0) --
  unless it is far from it (a head turned aside, a joint held at its limit): those joints are
  held as still joints instead.
"""
from __future__ import annotations

import numpy as np


class Stillness:
    """How long each of ``shape`` segments (e.g. (subjects, segments)) has been still: its angular
    speed stayed below ``threshold_dps``."""

    def __init__(self, shape: tuple[int, ...], threshold_dps: float):
        self.threshold = np.radians(threshold_dps)
        self.still_s = np.zeros(shape)

    def add(self, speed: np.ndarray, present: np.ndarray, dt: float) -> None:
        """Angular speeds ``speed`` (T, ...) rad/s of one block of ticks ``dt`` s apart, where
        ``present`` (T, ...)."""
        still = np.all((speed < self.threshold) & present, axis=0)
        self.still_s = np.where(still, self.still_s + len(speed) * dt, 0.0)

    def forget(self, mask: np.ndarray) -> None:
        """Segments of ``mask`` (...) start again (a restarted device)."""
        self.still_s = np.where(mask, 0.0, self.still_s)


def leaning_alike(g_parent: np.ndarray, g_child: np.ndarray, tolerance_deg: float) -> np.ndarray:
    """(...) True where the vertical has the same direction, within ``tolerance_deg``, in a
    joint's parent and child frames (``g_parent``, ``g_child`` (..., 3)): both segments lean as
    they did in the rest pose."""
    return np.sum(g_parent * g_child, axis=-1) > np.cos(np.radians(tolerance_deg))
