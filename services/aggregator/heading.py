"""Heading correction in the aggregator (:mod:`limbstream.heading`): per subject, each device's
heading offset, held by the body's joints, applied to the device before fusion like a
calibration (docs/evaluation.md, "Heading without resets").

Which devices: when it is on (``aggregate --heading-correction joints``, the default), the calibrated devices whose heading drifts, i.e. whose
fusion has no magnetometer (raw 6D sensors; devices that do not say their fusion are taken as
such). A device is corrected only once calibrated: before, its readings are in its sensor's
frame and no joint can be formed with it. Its correction starts again from none whenever its
calibration changes or its stream restarts (a restarted filter's heading is anywhere), and is
learnt afresh: never applied stale.

What is learnt: each subject's exact frames, as they are built, go to the estimator (one per body
layout and rest pose, over the layout's joints, :func:`.layouts.joints_of`; a row per subject; its subjects' steps spread over the ticks) with the correction taken off
again. Each device's correction is then a line in device time, ``c(t) = offset + rate * (t -
t_ref)``, as the estimator's last step left it (:meth:`HeadingCorrection.lines`).

Where it is applied: wherever the stored points are read for what the aggregator shows. Every
frame's segment (exact and live) is turned about the vertical by its device's ``c(t)`` right after
its SLERP reconstruction (:meth:`HeadingStage.correct`), and the truth comparison of each device is
made against the reconstruction so turned (:meth:`HeadingStage.turns`). The stored points stay as
calibrated: the estimator gets its input back exactly (the turn was put on after SLERP, so taking
it off gives the calibrated reconstruction), and a calibration made later reads the points it
always read.

A subject whose joints contradict their constraints (its source's rest pose is not what it says;
:mod:`limbstream.heading.contradiction`) is no longer corrected: its estimator drops its devices'
corrections to none; its stats say which joints (``heading_contradicted``,
:meth:`HeadingStage.contradicted`) and the log says so once.
"""
from __future__ import annotations

import logging

import numpy as np

from limbstream import quat
from limbstream.body import PAPER10, Layout
from limbstream.calibration import yaw
from limbstream.heading import HeadingCorrection
from limbstream.services.aggregator.layouts import joints_of

log = logging.getLogger("limbstream.aggregator")

class HeadingStage:
    """The heading corrections of an aggregator's devices (by slot) and subjects (by index); an
    estimator per body layout and rest pose, over the layout's segments and joints
    (:func:`.layouts.joints_of`).

    Parameters
    ----------
    on : whether devices are corrected at all.
    rate : the exact frame rate, Hz (the estimator's tick rate).
    """

    def __init__(self, on: bool, rate: float):
        self.enabled, self.rate = on, rate
        self.estimators: dict[tuple[int, str], HeadingCorrection] = {}  # by (layout code, rest pose)
        self.place: list[tuple[tuple[int, str], int] | None] = []  # by subject index: (its estimator's key, row)
        self.layouts: list[tuple[Layout, np.ndarray]] = [(PAPER10, np.arange(len(PAPER10.segments)))]
        self.code = np.zeros(0, np.int64)    # by subject: its layout (an index of ``layouts``: the layout, its table columns)
        self.on = np.zeros(0, bool)          # by slot: corrected (calibrated, heading drifting)
        self.offset = np.zeros(0)            # by slot: c(t_ref), rad
        self.slope = np.zeros(0)             # by slot: dc/dt, rad/s
        self.t_ref = np.zeros(0, np.int64)   # by slot: us
        self.taken = np.zeros(0, np.int64)   # by subject: exact frames learnt from
        self.told: set[int] = set()          # subjects whose contradicted constraints the log has said

    @property
    def active(self) -> bool:
        """Whether any device is corrected."""
        return bool(self.on.any())

    def add_subject(self) -> None:
        self.place.append(None)
        self.code = np.append(self.code, 0)
        self.taken = np.append(self.taken, 0)

    def set_layout(self, subject: int, layout: Layout, cols: np.ndarray) -> None:
        """The subject's layout, its segments the table's columns ``cols`` (S,): a new one is learnt
        from nothing (in the estimator of that layout)."""
        known = [lay for lay, _ in self.layouts]
        if layout not in known:
            self.layouts.append((layout, cols))
        self.code[subject] = known.index(layout) if layout in known else len(known)

    def add_device(self) -> None:
        for name, value in (("on", False), ("offset", 0.0), ("slope", 0.0), ("t_ref", 0)):
            setattr(self, name, np.append(getattr(self, name), value))

    def reset(self, subject: int, segment: str, slot: int, on: bool, calibrated_s_ago: float | None) -> None:
        """Device ``slot`` (``segment`` of subject ``subject``) got a new calibration or stream:
        corrected from now on if ``on`` (and the stage is), starting from none; its joints are
        learnt afresh, its heading known as at a calibration made ``calibrated_s_ago`` seconds
        ago (0: just made; more: one kept from before, the heading's drift since widening what
        is known), or anywhere (None: a stream restarted)."""
        self.on[slot] = on and self.enabled
        self.offset[slot] = self.slope[slot] = 0.0
        where = self.place[subject]
        index = None if where is None else self.layouts[where[0][0]][0].segment_index
        if where is not None and segment in index:  # type: ignore[operator]
            self.estimators[where[0]].restart(where[1], index[segment], calibrated_s_ago)  # type: ignore[index]

    # ------------------------------------------------------------------ applying

    def turns(self, slots: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(Q,) each device's correction (rad; 0 where it has none) at device times ``t_us``
        (Q,) us, of devices ``slots`` (Q,)."""
        return np.where(self.on[slots], self.offset[slots] + self.slope[slots] * ((t_us - self.t_ref[slots]) * 1e-6),
                        0.0)

    def correct(self, slots: np.ndarray, t_us: np.ndarray, q: np.ndarray) -> None:
        """Turn orientations ``q`` (Q, 4) float64 of devices ``slots`` (Q,) at ``t_us`` (Q,) us
        by their corrections, in place."""
        mine = np.flatnonzero(self.on[slots])
        if len(mine):
            q[mine] = quat.multiply(yaw(self.turns(slots[mine], t_us[mine])), q[mine])

    # ------------------------------------------------------------------ learning

    def take_frames(self, owner: np.ndarray, t_us: np.ndarray, q: np.ndarray, seg_slots: np.ndarray,
                    stale: np.ndarray, rest_flag: np.ndarray) -> None:
        """The exact frames of a tick, corrected (per subject oldest first: subject ``owner``
        (E,), time ``t_us`` (E,) us, orientations ``q`` (E, C, 4) over the device table's segment
        columns), with ``seg_slots`` (subjects, C) each segment's device slot, ``stale`` (subjects, C) its device held,
        ``rest_flag`` (subjects,) each subject's rest pose flag: their corrected devices' calibrated
        orientations go to the estimators, a tick per frame, and the lines of these subjects'
        devices are renewed."""
        slots = seg_slots[owner]
        present = (slots >= 0) & self.on[np.maximum(slots, 0)] & ~stale[owner]
        keep = present.any(axis=1)
        if not keep.any():
            return
        owner, t_us, q, slots, present = owner[keep], t_us[keep], q[keep], slots[keep], present[keep]
        times = np.broadcast_to(t_us[:, None], slots.shape)
        calibrated = quat.multiply(yaw(-self.turns(np.maximum(slots, 0), times) * present), q)
        for est, frames, rows, cols in self._by_estimator(owner, rest_flag):
            est.take(rows, calibrated[frames][:, cols], present[frames][:, cols])
            newest = np.r_[owner[frames][1:] != owner[frames][:-1], True]  # each subject's newest frame
            self._renew(est, rows[newest], slots[frames[newest]][:, cols], t_us[frames[newest]])
        np.add.at(self.taken, owner, 1)

    def _by_estimator(self, subjects: np.ndarray, rest_flag: np.ndarray):
        """(estimator, positions in ``subjects``, their rows, the table's columns of its segments)
        per layout and rest pose, each subject placed (a row in the estimator of its layout and rest
        pose) on first sight or when either changed."""
        kinds = 2 * self.code[subjects] + (rest_flag[subjects] != 0)
        for kind in np.unique(kinds).tolist():
            key = (kind // 2, "tpose" if kind % 2 else "standing")
            mine = np.flatnonzero(kinds == kind)
            each, index = np.unique(subjects[mine], return_inverse=True)
            rows = np.array([self._row(s, key) for s in each.tolist()], np.int64)[index]
            yield self.estimators[key], mine, rows, self.layouts[key[0]][1]

    def _row(self, subject: int, key: tuple[int, str]) -> int:
        """The subject's row in the estimator of ``key`` (layout, rest pose) (a new one on first
        sight, or when its layout or rest pose changed: learnt from nothing)."""
        where = self.place[subject]
        if where is None or where[0] != key:
            if key not in self.estimators:
                self.estimators[key] = HeadingCorrection(joints_of(self.layouts[key[0]][0], rest_pose=key[1]), 0,
                                                         self.rate)
            where = self.place[subject] = (key, int(self.estimators[key].add_subjects(1)[0]))
        return where[1]

    def _renew(self, est: HeadingCorrection, rows: np.ndarray, slots: np.ndarray, t_us: np.ndarray) -> None:
        """The lines of the devices ``slots`` (R, S) of estimator rows ``rows`` (R,) that just
        took a frame at ``t_us`` (R,) us: ``t_ref`` is the time the estimator's last step stands
        for."""
        offset, slope = est.lines(rows)
        have = slots >= 0
        s = slots[have]
        self.offset[s], self.slope[s] = offset[have], slope[have]
        self.t_ref[s] = np.broadcast_to((t_us - np.round(est.pending[rows] * 1e6 / est.fs).astype(np.int64))[:, None],
                                        slots.shape)[have]

    # ------------------------------------------------------------------ figures

    def contradicted(self, subject: int, name: str) -> dict[str, float] | None:
        """The subject's ``heading_contradicted`` stats field: joint -> its share of the last
        minute contradicted, once its estimator found its constraints contradicted and stopped
        correcting it; None while it has not. The first time, a log line names the subject
        (``name``) and those joints."""
        where = self.place[subject]
        if where is None or not self.estimators[where[0]].contradicted[where[1]]:
            return None
        joints = self.estimators[where[0]].contradicted_joints(where[1])
        if subject not in self.told:
            self.told.add(subject)
            log.warning("subject %s: its joints contradict their constraints (%s: share of the last minute): its "
                        "rest pose is not what it says; its heading is no longer corrected", name,
                        ", ".join(f"{j} {v:.2f}" for j, v in joints.items()))
        return joints

    def figures(self, slots: np.ndarray, owner: np.ndarray, segments: list[str]) -> dict[str, np.ndarray]:
        """The heading fields of the stats entries of devices ``slots`` (k,) of subjects ``owner``
        (k,) on ``segments`` (k names), each (k,) (NaN where a device is not corrected): the
        correction applied now, its rate and its confidence (:meth:`HeadingCorrection.status`)."""
        out = {name: np.full(len(slots), np.nan) for name in FIELDS.values()}
        places = [self.place[s] for s in owner.tolist()]
        for key, est in self.estimators.items():
            index = self.layouts[key[0]][0].segment_index
            seg_index = np.array([index.get(name, -1) for name in segments], np.int64)
            mine = np.flatnonzero(self.on[slots] & (seg_index >= 0)
                                  & np.array([p is not None and p[0] == key for p in places], bool))
            if len(mine):
                rows = np.array([places[k][1] for k in mine.tolist()], np.int64)  # type: ignore[index]
                status = est.status(rows)
                for key, name in FIELDS.items():
                    out[name][mine] = status[key][np.arange(len(mine)), seg_index[mine]]
        return out


FIELDS = {"offset_deg": "heading_offset_deg", "rate_dpm": "heading_rate_dpm", "confidence": "heading_confidence"}
"""The stats fields of :meth:`HeadingStage.figures`, by :meth:`HeadingCorrection.status` key."""

