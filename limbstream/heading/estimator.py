"""Heading correction: per subject, each segment's heading offset, held by the body's joints.

Input per tick: every device's calibrated orientation (its heading still drifting), as arrays
(subjects, segments, 4), with which devices are present. Output: per device a turn about the
vertical ``c`` (rad) to apply before fusion, like a calibration: ``yaw(c) * q``
(:meth:`HeadingCorrection.apply`). Only relative headings are observable, joint by joint
(:mod:`.filter`); each subject's corrections are built down its tree of joints and then shifted
so that they average 0 over its present devices (the body faces the mean of its sensors'
headings: which way it faces is not observable).

Ticks are gathered per subject in blocks of ``Settings.update_s``; each full block is measured
at once (vectorised over its ticks, the subjects whose blocks are full and their joints) and moves
their filters one step. Between steps a correction follows its learnt rate. The subjects' first
blocks are shortened by their row's place in the block (row ``b`` by ``b % block`` ticks), so
that their steps fall on different ticks and no tick carries them all. A subject's ticks may come
on their own (:meth:`HeadingCorrection.take`: the aggregator's subjects finish their frames at
different times) or all subjects' together (:meth:`HeadingCorrection.update`).
:meth:`HeadingCorrection.batch` runs the same blocks over a recording, so the offline form gives
what the live one gives.

A subject whose joints contradict their constraints (:mod:`.contradiction`: its source's rest pose
is not what it says) is no longer corrected: its corrections drop to none and stay there
(:attr:`HeadingCorrection.contradicted`, :meth:`HeadingCorrection.contradicted_joints`: its
callers say so).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from limbstream import quat
from limbstream.calibration import axis_angle, yaw
from limbstream.heading import hinge, rom
from limbstream.heading.contradiction import Contradictions, hinge_off
from limbstream.heading.filter import ABSOLUTE, GATE as filter_gate, MEAN_REFERENCED, JointFilters, wrap
from limbstream.heading.joints import Layout, kind, relative, twist, vertical_in
from limbstream.heading.settings import DEFAULTS, Settings
from limbstream.heading.still import Stillness, leaning_alike


class HeadingCorrection:
    """The heading correction of ``subjects`` subjects wearing the segments of ``layout``.

    Parameters
    ----------
    layout : the segments (and so the joints) every subject may have.
    subjects : how many subjects (rows of the arrays).
    fs : the tick rate, Hz.
    settings : the tunables.
    """

    def __init__(self, layout: Layout, subjects: int = 1, fs: float = 50.0, settings: Settings = DEFAULTS):
        self.layout, self.fs, self.settings = layout, fs, settings
        self.block = max(1, round(settings.update_s * fs))
        n_joints = len(layout.joints)
        rad = np.radians
        twists = {name: (mean, spread) for name, mean, spread in settings.twist_deg}
        kinds = [kind(name) for name in layout.joints]
        sd0 = np.array([[settings.delta0_deg, settings.hinge_rate0_dps, settings.hinge_mean0_deg] if hinged else
                        [settings.delta0_deg, settings.rate0_dps, twists[name][0]]
                        for name, hinged in zip(kinds, layout.hinge)]).reshape(-1, 3)
        self.filters = JointFilters((subjects, n_joints), rad(sd0),
                                    rad([settings.delta_walk, settings.rate_walk, settings.mean_walk]))
        self.hinges = np.flatnonzero(layout.hinge)
        self.balls = np.flatnonzero(~layout.hinge)
        self.axes = hinge.HingeAxes((subjects, len(self.hinges)), settings.axis_memory_s,
                                    settings.axis_min_amount, settings.axis_min_share)
        bones = layout.bone_axes()
        self.bones = bones[self.hinges]
        self.spread = rad(np.array([settings.knee_spread_deg if "knee" in layout.joints[j] else settings.elbow_spread_deg
                                    for j in self.hinges]).reshape(-1, 2)) ** 2
        self.twist_var = rad(np.array([twists[kinds[j]][1] for j in self.balls])) ** 2
        self.box = rom.limits([layout.joints[j] for j in self.balls])
        before, after = layout.to_standing()
        self.to_standing = before[self.balls], after[self.balls]
        self.ranges = rom.RangeCounts((subjects, len(self.balls)), settings.rom_memory_s, settings.rom_min_share)
        self.contradictions = Contradictions((subjects, n_joints), settings.contradiction_memory_s,
                                             settings.contradiction_min_s, settings.contradiction_share)
        n_segments = len(layout.segments)
        self.still = Stillness((subjects, n_segments), settings.still_dps)
        self.last = np.tile([1.0, 0.0, 0.0, 0.0], (subjects, n_segments, 1))
        self.had = np.zeros((subjects, n_segments), bool)
        self.locked = np.zeros((subjects, n_joints), bool)
        self.lock_ref = np.zeros((subjects, n_joints))
        self.lock_p = np.zeros((subjects, n_joints, 3, 3))
        self.was_still = np.zeros((subjects, n_joints), bool)
        self.relaxed_left = np.zeros((subjects, n_joints))
        self.order = sorted(range(n_joints), key=lambda j: self._depth(layout.segments[layout.child[j]]))
        self._ticks = np.zeros((self.block, subjects, n_segments, 4))  # each subject's ticks since its step
        self._ticks_present = np.zeros((self.block, subjects, n_segments), bool)
        self.pending = np.zeros(subjects, np.int64)
        """(subjects,) ticks taken since each subject's last step."""
        self.due = self.block - np.arange(subjects) % self.block
        """(subjects,) ticks of each subject's next block (its first one staggered by its row)."""
        self.dropped = 0
        """Orientations given as present that were not finite unit quaternions (taken as absent)."""

    @property
    def subjects(self) -> int:
        return len(self.had)

    def _state(self) -> list[tuple[object, str, int]]:
        """Every array of per-subject state the filter steps read and write: (owner, attribute,
        the subjects' axis)."""
        return [(self.filters, "x", 0), (self.filters, "p", 0), (self.axes, "sums", 1), (self.axes, "axis", 0),
                (self.axes, "ready", 0), (self.axes, "error", 0), (self.ranges, "out", 0), (self.ranges, "seen", 0),
                (self.still, "still_s", 0), (self, "last", 0), (self, "had", 0), (self, "locked", 0),
                (self, "lock_ref", 0), (self, "lock_p", 0), (self, "was_still", 0), (self, "relaxed_left", 0),
                (self.contradictions, "out", 0), (self.contradictions, "seen", 0),
                (self.contradictions, "contradicted", 0), (self.contradictions, "stopped_s", 0),
                (self.contradictions, "elapsed_s", 0), (self.contradictions, "which", 0)]

    def add_subjects(self, n: int) -> np.ndarray:
        """Room for ``n`` more subjects, learnt from nothing; returns their rows."""
        fresh = HeadingCorrection(self.layout, n, self.fs, self.settings)
        rows = np.arange(self.subjects, self.subjects + n)
        for (owner, name, axis), (new, _, _) in zip(self._state(), fresh._state()):
            setattr(owner, name, np.concatenate([getattr(owner, name), getattr(new, name)], axis=axis))
        room = len(self._ticks)  # widened by a burst, perhaps: the new rows get as much
        self._ticks = np.concatenate([self._ticks, np.zeros((room, n) + self._ticks.shape[2:])], axis=1)
        self._ticks_present = np.concatenate([self._ticks_present, np.zeros((room, n) + self._ticks_present.shape[2:],
                                                                            bool)], axis=1)
        self.pending = np.concatenate([self.pending, fresh.pending])
        self.due = np.concatenate([self.due, self.block - rows % self.block])
        return rows

    def _depth(self, segment: str) -> int:
        """How many joints lie between ``segment`` and the root of its tree."""
        index = {self.layout.segments[c]: j for j, c in enumerate(self.layout.child)}
        return 0 if segment not in index else 1 + self._depth(self.layout.segments[self.layout.parent[index[segment]]])

    # -- per tick -------------------------------------------------------------------------------

    def update(self, q: np.ndarray, present: np.ndarray | None = None) -> np.ndarray:
        """Take one tick of every subject: ``q`` (subjects, segments, 4) calibrated orientations,
        ``present`` (subjects, segments) bool (default all). Returns (subjects, segments) the
        corrections (rad) to apply to this tick's ``q``."""
        rows = np.arange(self.subjects)
        present = self._checked(rows, np.asarray(q, np.float64), present)[1]
        out = self._down_the_tree(self.joint_offsets(self.pending + 1), present)
        self.take(rows, q, present)
        return out

    def take(self, rows: np.ndarray, q: np.ndarray, present: np.ndarray | None = None) -> None:
        """Take ticks of subjects ``rows`` (R,) (a subject's in time order; it may come several
        times): ``q`` (R, segments, 4) calibrated orientations, ``present`` (R, segments) bool
        (default all). Then every subject with a full block moves its filters one step (all of
        them in one go, and again while some have another block full)."""
        rows = np.asarray(rows, np.int64)
        q, present = self._checked(rows, np.asarray(q, np.float64), present)
        q = np.where(present[..., None], q, np.array([1.0, 0.0, 0.0, 0.0]))
        order = np.argsort(rows, kind="stable")
        first = np.searchsorted(rows[order], rows[order])
        rank = np.empty(len(rows), np.int64)
        rank[order] = np.arange(len(rows)) - first  # each tick's place among its subject's in this call
        at = self.pending[rows] + rank
        if len(at) and at.max() >= len(self._ticks):
            self._widen(int(at.max()) + 1)
        self._ticks[at, rows], self._ticks_present[at, rows] = q, present
        np.add.at(self.pending, rows, 1)
        while (full := np.flatnonzero(self.pending >= self.due)).size:
            for length in np.unique(self.due[full]).tolist():  # (first, short blocks: apart)
                self._step(full[self.due[full] == length], length)

    def _checked(self, rows: np.ndarray, q: np.ndarray, present: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``q`` and ``present`` (default all) of ticks of ``rows``, their shapes checked
        (ValueError); orientations that are not finite unit quaternions counted and taken as
        absent."""
        shape = (len(rows), self.had.shape[1])
        if q.shape != shape + (4,):
            raise ValueError(f"q must have shape {shape + (4,)} (subjects, segments, 4), got {q.shape}")
        present = np.ones(shape, bool) if present is None else np.asarray(present, bool)
        if present.shape != shape:
            raise ValueError(f"present must have shape {shape}, got {present.shape}")
        unit = np.all(np.isfinite(q), axis=-1) & (np.abs(np.sum(q * q, axis=-1) - 1.0) < 1e-2)
        self.dropped += int(np.sum(present & ~unit))
        return q, present & unit

    def _widen(self, ticks: int) -> None:
        """Room for ``ticks`` ticks per subject between steps."""
        extra = ticks - len(self._ticks)
        self._ticks = np.concatenate([self._ticks, np.zeros((extra,) + self._ticks.shape[1:])])
        self._ticks_present = np.concatenate([self._ticks_present, np.zeros((extra,) + self._ticks_present.shape[1:], bool)])

    def _step(self, rows: np.ndarray, length: int) -> None:
        """Move the filters of subjects ``rows`` one step with their first ``length`` ticks."""
        q, present = self._ticks[:length, rows], self._ticks_present[:length, rows]
        left = self.pending[rows] - length
        if left.any():  # ticks beyond the block: to the front
            self._ticks[:, rows] = np.roll(self._ticks[:, rows], -length, axis=0)
            self._ticks_present[:, rows] = np.roll(self._ticks_present[:, rows], -length, axis=0)
        self.pending[rows], self.due[rows] = left, self.block
        if len(rows) == self.subjects and np.array_equal(rows, np.arange(self.subjects)):
            self.process(q, present)
            return
        whole = [(owner, name, axis, getattr(owner, name)) for owner, name, axis in self._state()]
        for owner, name, axis, full in whole:  # the rows' state alone, stepped, then put back
            setattr(owner, name, np.take(full, rows, axis=axis))
        self.process(q, present)
        for owner, name, axis, full in whole:
            full[(slice(None),) * axis + (rows,)] = getattr(owner, name)
            setattr(owner, name, full)

    def restart(self, subject: int, segment: int, calibrated_s_ago: float | None = None) -> None:
        """Device ``segment`` of ``subject`` restarted: its joints are learnt afresh, their
        corrections start from none; its heading is anywhere (None), or known as at a calibration
        made ``calibrated_s_ago`` seconds ago: :attr:`Settings.delta0_deg`, widened by the
        heading's drift since (:attr:`Settings.rate0_dps` per second). Its ticks taken since the
        last step are left out."""
        mask = np.zeros(self.locked.shape, bool)
        mask[subject] = (self.layout.parent == segment) | (self.layout.child == segment)
        self.filters.forget(mask, delta_sd=self.settings.heading_sd(calibrated_s_ago))
        self.ranges.forget(mask[:, self.balls])
        self.locked &= ~mask
        self.was_still &= ~mask
        seg = np.zeros(self.still.still_s.shape, bool)
        seg[subject, segment] = True
        self.still.forget(seg)
        self.had[subject, segment] = False
        self._ticks_present[:, subject, segment] = False

    @staticmethod
    def apply(q: np.ndarray, corrections: np.ndarray) -> np.ndarray:
        """(..., 4) orientations ``q`` turned about the vertical by ``corrections`` (...) rad."""
        return quat.multiply(yaw(corrections), q)

    # -- per block ------------------------------------------------------------------------------

    def process(self, q: np.ndarray, present: np.ndarray) -> None:
        """Measure one block of ticks, ``q`` (T, subjects, segments, 4) and ``present`` (T,
        subjects, segments), and move every filter one step."""
        lay, dt = self.layout, 1.0 / self.fs
        x = self.filters.x
        r = relative(q, lay)  # (T, B, J, 4)
        b = _Block(r=r, g_parent=vertical_in(q[..., lay.parent, :]), g_child=vertical_in(q[..., lay.child, :]),
                   joined=present[..., lay.parent] & present[..., lay.child],
                   applied=x[..., 0] + x[..., 1] * (np.arange(1, len(q) + 1)[:, None, None] * dt),
                   absolute=(np.zeros(r.shape[:-1], complex), np.zeros(r.shape[:-1])),
                   referenced=(np.zeros(r.shape[:-1], complex), np.zeros(r.shape[:-1])))
        b.turn = twist(r, b.g_parent)
        rates, steady = self._rates(q, present)
        self._hinges(b)
        self._twists(b)
        ball_off = self._range(b)
        self._stillness(b, np.linalg.norm(rates, axis=-1), steady)
        free = ~self.locked
        self.filters.predict(len(q) * dt)
        self.filters.update(ABSOLUTE, np.angle(b.absolute[0].sum(axis=0)), b.absolute[1].sum(axis=0) * free)
        self.filters.update(MEAN_REFERENCED, np.angle(b.referenced[0].sum(axis=0)), b.referenced[1].sum(axis=0) * free)
        self.filters.hold(self.locked, self.lock_ref - b.turn[-1], self.lock_p)
        h = self.hinges
        held = axis_angle(b.g_parent[..., h, :], b.applied[..., h])
        self.axes.add(quat.multiply(held, r[..., h, :]), b.g_parent[..., h, :], b.joined[..., h], dt)
        self._contradicted(b, ball_off, len(q) * dt)

    def _contradicted(self, b: _Block, ball_off: np.ndarray, dt: float) -> None:
        """Count one block's contradicted joints (:mod:`.contradiction`; ``ball_off`` (B, balls):
        the ball joints out of range at every heading tried); the subjects found contradicted stay
        at no correction."""
        off = np.zeros(self.locked.shape, bool)
        off[:, self.hinges] = hinge_off(self.axes.axis, self.bones, self.axes.ready, self.settings.hinge_off_deg)
        off[:, self.balls] = ball_off
        self.contradictions.add(off, b.joined[-1], dt)
        if self.contradicted.any():
            stopped = np.broadcast_to(self.contradicted[:, None], self.locked.shape)
            self.filters.forget(stopped, keep_mean=False)
            self.locked &= ~stopped

    def _hinges(self, b: _Block) -> None:
        """The hinge measure of every hinge (:mod:`.hinge`), where its axis is known."""
        h, dt = self.hinges, 1.0 / self.fs
        y, info = hinge.measure(b.r[..., h, :], b.g_parent[..., h, :], self.axes.axis, self.bones, self.spread)
        info *= dt / self.settings.hinge_corr_s * self.axes.ready * b.joined[..., h]
        _add(b.referenced, (Ellipsis, h), y, info)

    def _twists(self, b: _Block) -> None:
        """The twist every ball joint shows about the vertical, against its mean; samples further
        from what the filter expects than ``Settings.twist_gate`` of their spread (a joint held
        far out, at its limit) are left out."""
        j, dt, x = self.balls, 1.0 / self.fs, self.filters.x
        expected = x[..., j, 0] - x[..., j, 2]
        p = self.filters.p[..., j, :, :]
        spread = self.twist_var + p[..., 0, 0] + p[..., 2, 2] - 2 * p[..., 0, 2]
        measured = -b.turn[..., j]
        near = np.abs(wrap(measured - expected)) < self.settings.twist_gate * np.sqrt(spread)
        _add(b.referenced, (Ellipsis, j), measured,
             near * b.joined[..., j] * dt / (self.twist_var * self.settings.twist_corr_s))

    def _range(self, b: _Block) -> np.ndarray:
        """Each ball joint's range of motion (:mod:`.rom`), counted at the block's last tick;
        returns (B, balls) whether each is out of range at every heading tried (and has one)."""
        j = self.balls
        g = b.g_parent[-1][..., j, :]
        now = b.applied[-1][..., j]
        corrected = quat.multiply(axis_angle(g, now), b.r[-1][..., j, :])
        before, after = self.to_standing
        out = rom.out_of_range(quat.multiply(quat.multiply(before, corrected), after), quat.rotate(before, g), self.box)
        self.ranges.add(out, b.joined[-1][..., j], len(b.r) / self.fs)
        turn, asked = self.ranges.asked()
        information = asked * b.joined[-1][..., j] / np.radians(self.settings.rom_sd_deg) ** 2
        _add((b.absolute[0][-1], b.absolute[1][-1]), (Ellipsis, j), now + turn, information)
        return np.all(out, axis=-1)

    def _rates(self, q: np.ndarray, present: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T, B, S, 3) each segment's angular rate in its own frame, rad/s, from one tick to the
        next (the first from the last tick of the block before), and (T, B, S) where it is
        valid (present at both ticks)."""
        steps = np.concatenate([self.last[None], q])
        valid = present & np.concatenate([self.had[None], present[:-1]])
        self.last, self.had = q[-1].copy(), present[-1].copy()
        d = quat.multiply(quat.conjugate(steps[:-1]), steps[1:])
        return 2.0 * self.fs * d[..., 1:] * np.where(d[..., :1] < 0, -1.0, 1.0), valid

    def _stillness(self, b: _Block, speed: np.ndarray, steady: np.ndarray) -> None:
        """Fold in the still joints and the relaxed pose (:mod:`.still`) of one block."""
        s, lay, dt = self.settings, self.layout, 1.0 / self.fs
        self.still.add(speed, steady, dt)
        still = self.still.still_s >= s.still_s  # (B, S)
        seen = steady.any(axis=0)
        whole = np.all(still | ~seen, axis=-1) & np.any(seen, axis=-1)  # (B,)
        joint_still = still[..., lay.parent] & still[..., lay.child] & b.joined.all(axis=0)
        gate = np.maximum(np.radians(s.relaxed_gate_deg), filter_gate * self.filters.delta_sd())
        near = np.all(np.abs(wrap(-b.turn - b.applied)) < gate, axis=0)
        alike = np.all(leaning_alike(b.g_parent, b.g_child, s.relaxed_lean_deg), axis=0)
        episode = joint_still & ~self.was_still  # a still spell begins: the relaxed pose counts once in it
        self.relaxed_left = np.where(episode, 1.0 / np.radians(s.relaxed_pose_deg) ** 2, self.relaxed_left)
        self.was_still = joint_still
        relaxed = whole[:, None] & joint_still & near & alike & (self.relaxed_left > 0)
        spent = np.where(relaxed, np.minimum(self.relaxed_left, len(b.r) * dt / np.radians(s.relaxed_sd_deg) ** 2), 0.0)
        self.relaxed_left = self.relaxed_left - spent
        locking = joint_still & ~relaxed
        onset = locking & ~self.locked
        self.lock_ref = np.where(onset, b.turn[0] + b.applied[0], self.lock_ref)
        self.lock_p = np.where(onset[..., None, None], self.filters.p, self.lock_p)
        self.locked = locking
        _add(b.absolute, (Ellipsis,), -b.turn, np.broadcast_to(spent / len(b.r), b.turn.shape))

    # -- state ----------------------------------------------------------------------------------

    @property
    def contradicted(self) -> np.ndarray:
        """(subjects,) bool: found contradicted (:mod:`.contradiction`), no longer corrected."""
        return self.contradictions.contradicted

    @property
    def stopped_s(self) -> np.ndarray:
        """(subjects,) when each was found so, s of its ticks stepped (NaN: not)."""
        return self.contradictions.stopped_s

    def contradicted_joints(self, row: int) -> dict[str, float]:
        """Joint -> share of the last minute contradicted, of subject ``row``'s joints beyond the
        bound once it is :attr:`contradicted` (else empty)."""
        return self.contradictions.joints(row, self.layout.joints)

    def joint_offsets(self, ahead: np.ndarray | int = 0, rows: np.ndarray | None = None) -> np.ndarray:
        """(subjects, joints) each joint's correction ``ahead`` ((subjects,) or one) ticks after
        the last step, rad (of subjects ``rows`` only: (R, joints))."""
        x = self.filters.x if rows is None else self.filters.x[rows]
        return x[..., 0] + x[..., 1] * (np.asarray(ahead, np.float64)[..., None] / self.fs)

    def corrections(self, ahead: np.ndarray | int = 0, present: np.ndarray | None = None) -> np.ndarray:
        """(subjects, segments) the corrections ``ahead`` ((subjects,) or one) ticks after the last
        step, rad, of the segments ``present`` (subjects, segments) (default: those of the last
        step)."""
        return self._down_the_tree(self.joint_offsets(ahead), self.had if present is None else present)

    def lines(self, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Each device's correction as a line in time, of subjects ``rows`` (default all): (R,
        segments) twice, the correction at the last step (rad) and its rate (rad/s); ``k``
        ticks later it is ``offset + rate * k / fs`` (the devices present at the last step)."""
        rows = np.arange(self.subjects) if rows is None else rows
        x, present = self.filters.x[rows], self.had[rows]
        return self._down_the_tree(x[..., 0], present), self._down_the_tree(x[..., 1], present)

    def _down_the_tree(self, joint_values: np.ndarray, present: np.ndarray) -> np.ndarray:
        """(..., subjects, segments) per-segment values of per-joint differences ``joint_values``
        (..., subjects, joints): each child's is its parent's plus its joint's where both are
        ``present`` (subjects, segments); then each group of segments so joined is shifted to
        average 0 (absent segments get 0)."""
        lay = self.layout
        n = len(lay.segments)
        shape = joint_values.shape[:-1] + (n,)
        present = np.broadcast_to(present, shape)
        out = np.zeros(shape)
        root = np.broadcast_to(np.arange(n), shape).copy()
        for j in self.order:
            p, c = lay.parent[j], lay.child[j]
            linked = present[..., p] & present[..., c]
            out[..., c] = np.where(linked, out[..., p] + joint_values[..., j], 0.0)
            root[..., c] = np.where(linked, root[..., p], c)
        member = (root[..., :, None] == np.arange(n)) & present[..., :, None]  # (..., segment, group)
        mean = np.einsum("...s,...sg->...g", out, member) / np.maximum(member.sum(axis=-2), 1)
        return np.where(present, out - np.take_along_axis(mean, root, axis=-1), 0.0)

    def status(self, rows: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Per device of subjects ``rows`` (default all; (R, segments) each): ``offset_deg`` the
        correction applied now, ``rate_dpm`` its rate (deg/min) and ``confidence`` (0..1: 1 when
        its joint's heading is known to within ``Settings.confidence_deg``, 1/2 at that, towards
        0 as it is lost)."""
        lay = self.layout
        rows = np.arange(self.subjects) if rows is None else np.asarray(rows, np.int64)
        sd = np.sqrt(np.maximum(self.filters.p[rows, :, 0, 0], 0.0))
        conf_joint = 1.0 / (1.0 + (sd / np.radians(self.settings.confidence_deg)) ** 2)
        conf = np.zeros(conf_joint.shape[:-1] + (len(lay.segments),))
        weight = np.zeros_like(conf)
        for j in range(len(lay.joints)):  # a device: its joint to its parent; a root: its joints' mean
            conf[..., lay.child[j]] = conf_joint[..., j]
            weight[..., lay.child[j]] = np.inf
        for j in range(len(lay.joints)):
            root = ~np.isinf(weight[..., lay.parent[j]])
            conf[..., lay.parent[j]] += np.where(root, conf_joint[..., j], 0.0)
            weight[..., lay.parent[j]] += np.where(root, 1.0, 0.0)
        conf = np.where(np.isinf(weight), conf, conf / np.maximum(weight, 1.0))
        offset, rate = self.lines(rows)
        return {"offset_deg": np.degrees(offset + rate * (self.pending[rows, None] / self.fs)),
                "rate_dpm": 60.0 * np.degrees(rate), "confidence": conf}

    # -- offline --------------------------------------------------------------------------------

    @classmethod
    def batch(cls, q: np.ndarray, layout: Layout, fs: float = 50.0, settings: Settings = DEFAULTS,
              row: int = 0, present: np.ndarray | None = None) -> np.ndarray:
        """(m, S, 4) a recording's calibrated orientations ``q`` (m, S, 4) at ``fs`` Hz,
        corrected as the live estimator would have, tick by tick, in subject row ``row`` (its
        first block staggered as that row's); ``present`` (m, S) bool: where the devices are
        (default: where ``q`` is a finite unit quaternion; the others are left as they are)."""
        return cls.run_over(q, layout, fs, settings, row, present)[0]

    @classmethod
    def run_over(cls, q: np.ndarray, layout: Layout, fs: float = 50.0, settings: Settings = DEFAULTS,
                 row: int = 0, present: np.ndarray | None = None) -> tuple[np.ndarray, HeadingCorrection]:
        """:meth:`batch`'s corrected orientations, and the estimator as the recording left it
        (one subject: whether it found its constraints contradicted, ...)."""
        q = np.asarray(q, np.float64)
        est = cls(layout, 1, fs, settings)
        unit = np.all(np.isfinite(q), axis=-1) & (np.abs(np.sum(q * q, axis=-1) - 1.0) < 1e-2)
        present = unit if present is None else np.asarray(present, bool) & unit
        ticks = np.where(present[..., None], q, np.array([1.0, 0.0, 0.0, 0.0]))
        out = q.copy()
        first = est.block - row % est.block
        for k in (0, *range(first, len(q), est.block)):
            block, here = ticks[k:(first if k == 0 else k + est.block), None], present[k:(first if k == 0 else k + est.block), None]
            ahead = np.arange(1, len(block) + 1)[:, None, None]
            c = est._down_the_tree(est.filters.x[..., 0] + est.filters.x[..., 1] * (ahead / fs), here)
            mine = here[:, 0]
            out[k:k + len(block)][mine] = cls.apply(block[:, 0][mine], c[:, 0][mine])
            if len(block) == (first if k == 0 else est.block):
                est.process(block, here)
        return out, est


@dataclass
class _Block:
    """One block's arrays, (T, B, J, ...): relative orientations ``r``, the vertical in the
    parents' and children's frames, where both segments are ``joined``, the corrections
    ``applied`` at each tick, the twist ``turn`` about the vertical, and the two accumulators
    (weighted unit vectors, weights) of absolute and mean-referenced measurements."""

    r: np.ndarray
    g_parent: np.ndarray
    g_child: np.ndarray
    joined: np.ndarray
    applied: np.ndarray
    absolute: tuple[np.ndarray, np.ndarray]
    referenced: tuple[np.ndarray, np.ndarray]
    turn: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _add(acc: tuple[np.ndarray, np.ndarray], where, measured: np.ndarray, information: np.ndarray) -> None:
    """Add measurements (angles, rad) with their information to a circular accumulator
    ``acc`` (weighted unit vectors, weights), at index ``where``."""
    acc[0][where] += information * np.exp(1j * measured)
    acc[1][where] += information
