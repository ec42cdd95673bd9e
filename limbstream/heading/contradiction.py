"""Contradicted constraints: a source whose rest pose is not what it says.

The joints hold the headings only if each segment's frame is the anatomical one the layout
assumes, which calibration gives when the source's rest pose is what it says. When it is not
(its segments' axes are off by a constant turn each: a BVH file whose zero pose has every bone
along +X, read as a T-pose), no heading satisfies the joints, and following them turns the
segments round (on the CMU clips looped, the hips' error grows from 2.6 deg in the first minute to
45 deg in the tenth; docs/evaluation.md). Two signs of it, one sample per block and joint:

- a **hinge** (knee, elbow) whose learnt axis is trusted (:class:`.hinge.HingeAxes`, ``ready``
  over 1/2) bends about an axis more than ``hinge_off_deg`` out of the plane across its child's
  bone: a knee or an elbow flexes across the bone, never about it;
- a **ball joint with a range** (:mod:`.rom`: hips, neck; lumbar spine, ankles, wrists) is out of
  it at every heading offset tried (:data:`.rom.TRIALS_DEG`, up to 110 deg either way): no
  heading drift puts a joint there.

Each joint's share of contradicted samples is kept over the last ``memory_s`` (exponentially,
seconds of samples where both its segments are present). A subject one of whose joints has been
seen for ``min_s`` and contradicted for more than ``share`` of it is contradicted: its heading
correction stops (:class:`.estimator.HeadingCorrection` drops its corrections to none and keeps
them there; without correction the joints drift as their sensors do, slowly, instead of being
turned round). A healthy subject never comes near: a knee's learnt axis lies within about 20 deg
of the plane across the shank (the CMU clips'), and a hip is out of its range at every heading
only in a glitch.
"""
from __future__ import annotations

import numpy as np

EPS = 1e-9


def hinge_off(axis: np.ndarray, bone: np.ndarray, ready: np.ndarray, off_deg: float) -> np.ndarray:
    """(..., H) bool: hinges whose learnt ``axis`` (..., H, 3) is trusted (``ready`` (..., H) over
    1/2) and more than ``off_deg`` out of the plane across their child's ``bone`` (H, 3) (unit)."""
    return (ready > 0.5) & (np.abs(np.sum(axis * bone, axis=-1)) > np.sin(np.radians(off_deg)))


class Contradictions:
    """How contradicted each of ``shape`` joints (subjects, joints) is: its share of contradicted
    samples over the last ``memory_s`` s (exponentially), the joints beyond ``share`` after at
    least ``min_s`` s of samples, and the subjects found so."""

    def __init__(self, shape: tuple[int, int], memory_s: float, min_s: float, share: float):
        self.memory_s, self.min_s, self.share = memory_s, min_s, share
        self.out = np.zeros(shape)
        self.seen = np.zeros(shape)
        self.contradicted = np.zeros(shape[0], bool)
        """(subjects,) found contradicted (for good)."""
        self.stopped_s = np.full(shape[0], np.nan)
        """(subjects,) when, s of samples since the start (NaN: not)."""
        self.elapsed_s = np.zeros(shape[0])
        """(subjects,) s of samples since the start."""
        self.which = np.zeros(shape, bool)
        """(subjects, joints) the joints beyond the bound when their subject was found so."""

    def add(self, contradicted: np.ndarray, mask: np.ndarray, dt: float) -> np.ndarray:
        """One sample (subjects, joints) standing for ``dt`` s, where ``mask``; returns the rows
        of the subjects found contradicted now."""
        keep = np.exp(-dt / self.memory_s)
        self.out = keep * self.out + dt * (contradicted & mask)
        self.seen = keep * self.seen + dt * mask
        self.elapsed_s = self.elapsed_s + dt
        found = self.beyond().any(axis=-1) & ~self.contradicted
        self.contradicted = self.contradicted | found
        self.which = np.where(found[:, None], self.beyond(), self.which)
        self.stopped_s = np.where(found, self.elapsed_s, self.stopped_s)
        return np.flatnonzero(found)

    def shares(self) -> np.ndarray:
        """(subjects, joints) each joint's share of contradicted samples (0 where none were seen)."""
        return self.out / np.maximum(self.seen, EPS)

    def beyond(self) -> np.ndarray:
        """(subjects, joints) bool: seen for at least ``min_s`` and contradicted for more than
        ``share`` of it."""
        return (self.seen >= self.min_s) & (self.shares() > self.share)

    def joints(self, row: int, names) -> dict[str, float]:
        """Joint name (of ``names``) -> its share now, of the joints of subject ``row`` that were
        beyond the bound when it was found contradicted (empty: not found so)."""
        shares = self.shares()[row]
        return {names[j]: round(float(shares[j]), 3) for j in np.flatnonzero(self.which[row]).tolist()}
