"""Scoring of the aggregator's reconstruction against the truth tap (the devices' raw samples),
kept apart from frame building (:mod:`.frames`), which never reads the truth.

- Per device, at every truth sample once its reconstruction is final: the angular error of the
  exact reconstruction (SLERP between segment points) and of the live view (the newest point at
  or before the sample, extrapolated to it: what a live frame at that instant showed) against the
  true segment; and, where the tap carries it, of the live view against the device's own
  orientation at the sample (what its kernel compressed, corrected as its points are): the
  figure the device's live bound holds. The first holds the sensor's fusion and calibration
  errors as well; the second the live rule's alone.
- Per subject, alignment-aware: when the truth tap carries reference times (the instant each
  sample was really taken), every exact frame at time ``t`` is compared, segment by segment,
  with the truth at reference instant ``t`` (SLERP between the truth samples around it) once
  the truth of every device has passed ``t``: the subject's ``frame_aad_deg``. Device clocks
  that disagree show up here and nowhere else. A segment the frame lacks (held at a point, or
  before its device's first: flagged MISSING, e.g. a late-joined stream whose history is still
  on its way) is not compared: its hold is not the reconstruction's error. Nor is a segment
  inside a span of its device's lost points (the frame flagged GAP: built before the device's
  cache gave them again, SLERP across the span): that error is the loss, which ``gaps`` counts.
- Joints: the same frames, joint by joint: the angle between the estimated and the true relative
  orientation of each pair of adjacent segments compared (:mod:`limbstream.heading.joints`), the
  subject's ``joint_aad_deg``. It does not depend on which way the subject faces (nor on a
  drift that all its sensors share), which ``frame_aad_deg`` does.
- Facing: calibrated sensors know the body but not which way it faces in the truth's world
  (without a magnetometer, nothing can). When a subject's devices are all calibrated (again),
  one rotation about the vertical per subject is fitted from the first FACING_FIT_FRAMES frames
  compared (the circular mean of the turn from frame to truth over their segments), those frames
  are not scored, and every later frame is compared after that rotation.

Errors are degrees, times microseconds.
"""
from __future__ import annotations

import math

import numpy as np

from collections.abc import Callable

from limbstream import calibration, quat, wire
from limbstream.body import PAPER10
from limbstream.body import Layout as BodyLayout
from limbstream.heading.joints import Layout, joint_errors_deg
from limbstream.wire import SEGMENTS
from limbstream.services.aggregator.layouts import joints_of
from limbstream.services.aggregator.rings import ErrorRings, SubjectRings
from limbstream.services.aggregator.store import PointStore, TruthQueue

FRAME_ERROR_WAIT_S = 10.0
"""An exact frame waits at most this long (frame time behind its subject's newest frame) for the
truth of its devices to pass it; then it is compared with the truth there is."""

FACING_FIT_FRAMES = 50
"""Frames (a second at 50 Hz) a subject's facing is fitted from after its calibration."""

JOINTS = joints_of(PAPER10)
"""The joints among paper10's segments (their relative orientations: the rest pose does not matter)."""


class Scoring:
    """The truth side of the aggregator: it reads the segment points (``store``, the fusion's point
    store) and never changes them; frame building never reads the truth.

    ``exact``, ``live``: per device slot, windows of angular errors; ``latency``: live frame
    publish time - frame time, ms; ``frame_errors``: per subject, the mean segment error of each
    frame compared; ``facing``: per subject, truth <- frames, a turn about the vertical.

    Parameters
    ----------
    store : the segment points of every device slot.
    error_window : values in each window.
    """

    def __init__(self, store: PointStore, error_window: int):
        self.store = store
        self.truth = TruthQueue()
        self.exact = ErrorRings(error_window)
        self.live = ErrorRings(error_window)
        self.live_own = ErrorRings(error_window)  # the live view against the device's own orientation
        self.own_correction: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], None] | None = None
        self.latency = SubjectRings(error_window)
        self.reference = PointStore(2048)          # truth samples by reference time, per device slot
        self.frame_errors = ErrorRings(error_window)
        self.joint_errors = ErrorRings(error_window)
        self.turns: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
        self.facing = np.zeros((0, 4))
        self.layouts: list[BodyLayout] = [PAPER10]  # the subjects' layouts, by code,
        self.joints: list[Layout] = [JOINTS]        # and their joints over the device table's columns
        self.joint_code = np.zeros(0, np.int64)    # per subject
        self._facing_fit: dict[int, list[float]] = {}  # subject index -> [sum sin, sum cos, frames]
        # exact frames waiting for the truth: (subject index,), (time us,), (frame, C, 4) float32,
        # (frame, C) the segments it lacks (held or missing: not scored), over the table's columns
        self._pending = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, len(SEGMENTS), 4), np.float32),
                         np.zeros((0, len(SEGMENTS)), bool))

    def add_subject(self, subjects: int) -> None:
        """Room for ``subjects`` subjects."""
        self.frame_errors.ensure(subjects)
        self.joint_errors.ensure(subjects)
        self.latency.add_subject(subjects)
        self.joint_code = np.append(self.joint_code, np.zeros(subjects - len(self.joint_code), np.int64))
        grown = np.zeros((subjects, 4))
        grown[:, 0] = 1.0
        grown[: len(self.facing)] = self.facing
        self.facing = grown

    def set_layout(self, subject: int, layout: BodyLayout, columns: list[str]) -> None:
        """The subject's layout: its frames are scored on its joints (over the device table's
        segment ``columns``: a layout's columns never move)."""
        if layout not in self.layouts:
            self.layouts.append(layout)
            self.joints.append(joints_of(layout, columns))
        self.joint_code[subject] = self.layouts.index(layout)

    def add_device(self, slot: int) -> None:
        self.reference.add_slot()
        self.exact.ensure(slot + 1)
        self.live.ensure(slot + 1)
        self.live_own.ensure(slot + 1)
        self.latency.add_device()

    def reset(self, slot: int) -> None:
        """A new stream of the device in ``slot``: its windows start over, its old truth is dropped."""
        self.truth.drop(slot)
        self.reference.reset(slot)
        self.exact.reset(slot)
        self.live.reset(slot)
        self.live_own.reset(slot)
        self.latency.reset(slot)

    def refit_facing(self, subject: int) -> None:
        """Fit the subject's facing again from the next frames compared (its calibrations changed)."""
        self._facing_fit[subject] = [0.0, 0.0, 0.0]

    def take_truth(self, slot: int, batch: wire.RawBatch) -> None:
        """A truth-tap batch of the device's current stream."""
        self.truth.put(slot, batch.t_us, batch.q, batch.own)
        if batch.ref_us is not None:
            self._reference(slot, batch.ref_us, batch.q)

    def take_truths(self, slots: np.ndarray, batches: wire.RawColumns, rows: np.ndarray) -> None:
        """Truth-tap batches ``rows`` (B,) of ``batches`` of the devices ``slots`` (B,), each of
        its device's current stream, in arrival order."""
        count, start = batches.count[rows], batches.start[rows]
        samples = np.repeat(start - np.cumsum(count) + count, count) + np.arange(int(count.sum()))
        self.truth.put(np.repeat(slots, count), batches.t_us[samples], batches.q[samples], batches.own[samples])
        for slot, i in zip(slots[batches.has_ref[rows]].tolist(), rows[batches.has_ref[rows]].tolist()):
            part = slice(int(batches.start[i]), int(batches.start[i] + batches.count[i]))
            self._reference(slot, batches.ref_us[part], batches.q[part])

    def _reference(self, slot: int, ref_us: np.ndarray, q: np.ndarray) -> None:
        """Truth samples by reference time: only for the alignment-aware frame error."""
        n = self.reference.n[slot]
        newer = ref_us > (self.reference.t[slot, n - 1] if n else np.iinfo(np.int64).min)
        if newer.any():
            self.reference.extend(slot, ref_us[newer], q[newer])

    def score_later(self, owner: np.ndarray, t_us: np.ndarray, q: np.ndarray, slots: np.ndarray,
                    lacking: np.ndarray) -> None:
        """Exact frames just built ((F,) subject index, (F,) time us, (F, C, 4) quaternions over the
        table's segment columns, (F, C) device slots, (F, C) the segments each lacks: held or missing, flagged MISSING, or
        inside a span of lost points, flagged GAP; never scored): those with a device that has reference times wait to be compared
        (:meth:`evaluate_frames`)."""
        with_truth = (self.reference.n[np.maximum(slots, 0)] > 0).any(axis=1)
        if with_truth.any():
            po, pt, pq, pl = self._pending
            more = q.shape[1] - pq.shape[1]  # segment columns added since (appended)
            if more:
                pq = np.concatenate([pq, np.tile(np.float32([1, 0, 0, 0]), (len(pq), more, 1))], axis=1)
                pl = np.concatenate([pl, np.zeros((len(pl), more), bool)], axis=1)
            self._pending = (np.concatenate([po, owner[with_truth]]), np.concatenate([pt, t_us[with_truth]]),
                             np.concatenate([pq, q[with_truth].astype(np.float32)]),
                             np.concatenate([pl, lacking[with_truth]]))

    def add_latency(self, subjects: np.ndarray, latency_ms: np.ndarray, slots: np.ndarray,
                    slot_subjects: np.ndarray) -> None:
        """The live latency of one live frame per subject (F,) (ms), for the devices ``slots`` of
        those subjects (``slot_subjects``) that have points."""
        self.latency.add(subjects, latency_ms, slots, slot_subjects)

    def evaluate_truth(self, usable_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Angular error of the exact reconstruction and of the live view (the newest point at or
        before the sample, extrapolated to it), at every truth sample whose reconstruction became
        final (``usable_t``: (slots,) newest usable point time, us). Returns the slots of the
        samples dropped: (queue overflow,) and (before the stream's first point known: no
        reconstruction,), one entry per sample."""
        slots, t_us, both, overflow = self.truth.take_ready(usable_t)
        before = t_us < self.store.t[slots, 0]
        slots, t_us, both, early = slots[~before], t_us[~before], both[~before], slots[before]
        if len(slots):
            truth = both[:, :4]
            self._score_own(slots, t_us, both[:, 4:])
            if self.turns is not None:  # the reconstruction turned by c is compared: truth turned by -c
                turn = self.turns(slots, t_us)
                turned = np.flatnonzero(turn)  # (devices without a correction: as they are)
                if len(turned):
                    truth = truth.astype(np.float64)
                    truth[turned] = quat.multiply(calibration.yaw(-turn[turned]), truth[turned])
            exact, predicted = self.store.errors(slots, t_us, truth)
            self.exact.add(slots, exact)
            self.live.add(slots, predicted)
        return overflow, early

    def _score_own(self, slots: np.ndarray, t_us: np.ndarray, own: np.ndarray) -> None:
        """The live view's error against the devices' own orientations ``own`` (k, 4) (NaN: not
        carried) at ``t_us`` (k,): each corrected as the point the view comes from was
        (``own_correction`` at that point's time), so the angle is the device's own live error."""
        known = np.isfinite(own).all(axis=1)
        if not known.any():
            return
        slots, t_us, own = slots[known], t_us[known], own[known].astype(np.float64)
        if self.own_correction is not None:
            k = np.maximum(self.store.locate(slots, t_us), 0)
            self.own_correction(slots, self.store.t[slots, k], own, np.zeros((len(own), 3)))
        self.live_own.add(slots, quat.angle_deg(self.store.predicted(slots, t_us), own))

    def evaluate_frames(self, seg_slots: np.ndarray) -> int:
        """Alignment-aware error of the exact frames waiting for it: each segment of a frame at
        ``t`` against its device's truth at reference time ``t``, once every device of the frame
        with reference times has truth past ``t`` (or the frame waited FRAME_ERROR_WAIT_S);
        ``seg_slots``: (subjects, C) device slot of each segment column.
        Adds each frame's mean over its compared segments (those it has) to its subject's window.
        Returns the frames compared."""
        owner, t_us, q, lacking = self._pending
        if len(owner) == 0:
            return 0
        slots = seg_slots[owner][:, :q.shape[1]]                        # (P, C)
        rows = np.maximum(slots, 0)
        n = self.reference.n[rows]
        has = (slots >= 0) & (n > 0) & ~lacking
        last = self.reference.t[rows, np.maximum(n - 1, 0)]
        newest = np.full(len(seg_slots), np.iinfo(np.int64).min)
        np.maximum.at(newest, owner, t_us)
        waited = newest[owner] - t_us > FRAME_ERROR_WAIT_S * 1e6
        ready = (~has | (last >= t_us[:, None])).all(axis=1) | waited
        if not ready.any():
            return 0
        first = self.reference.t[rows, 0]
        use = has & (first <= t_us[:, None]) & ready[:, None]          # segments with truth around t
        f, s = np.nonzero(use)
        truth = self.reference.interpolate(slots[f, s], t_us[f])
        frames = q[f, s].astype(np.float64)
        count = np.bincount(f, minlength=len(owner))
        done = ready & (count > 0)
        if self._facing_fit:
            done &= ~self._fitting(owner, f, frames, truth, done)
        err = quat.angle_deg(quat.multiply(self.facing[owner[f]], frames), truth)
        per_frame = np.bincount(f, err, minlength=len(owner))
        self.frame_errors.add(owner[done], per_frame[done] / count[done])
        self._score_joints(owner, done, f, s, frames, truth, q.shape[1])
        keep = ~ready
        self._pending = (owner[keep], t_us[keep], q[keep], lacking[keep])
        return int(done.sum())

    def _score_joints(self, owner: np.ndarray, done: np.ndarray, f: np.ndarray, s: np.ndarray, frames: np.ndarray,
                      truth: np.ndarray, width: int) -> None:
        """Add the mean joint error of each frame ``done`` (P,) that has a joint with both segments
        compared (frame ``f`` (k,), segment ``s`` (k,): ``frames``, ``truth`` (k, 4)) to its
        subject's window (``width``: the frames' segment columns C)."""
        estimated = np.zeros((len(owner), width, 4))
        estimated[..., 0] = 1.0
        true = estimated.copy()
        used = np.zeros((len(owner), width), bool)
        estimated[f, s], true[f, s], used[f, s] = frames, truth, True
        codes = self.joint_code[owner]
        for code in np.unique(codes[done]).tolist():  # the joints of each layout
            joints = self.joints[code]
            both = used[:, joints.parent] & used[:, joints.child] & (done & (codes == code))[:, None]
            scored = both.any(axis=1)
            if scored.any():
                err = np.where(both[scored], joint_errors_deg(estimated[scored], true[scored], joints), 0.0)
                self.joint_errors.add(owner[scored], err.sum(axis=1) / both[scored].sum(axis=1))

    def _fitting(self, owner: np.ndarray, f: np.ndarray, frames: np.ndarray, truth: np.ndarray,
                 done: np.ndarray) -> np.ndarray:
        """Take the compared frames ``done`` (P,) of subjects whose facing is being fitted into
        their fits (segments: frame index ``f`` (k,), orientations ``frames``, ``truth`` (k, 4));
        returns which frames went into a fit (P,), not to be scored."""
        fitting = np.isin(owner, list(self._facing_fit)) & done
        if not fitting.any():
            return fitting
        turn = calibration.yaw_of(quat.multiply(truth, quat.conjugate(frames)))  # (k,) rad
        for sub in np.unique(owner[fitting]):
            mine = fitting & (owner == sub)
            take = mine[f]
            fit = self._facing_fit[int(sub)]
            fit[0] += float(np.sin(turn[take]).sum())
            fit[1] += float(np.cos(turn[take]).sum())
            fit[2] += int(mine.sum())
            if fit[2] >= FACING_FIT_FRAMES:
                self.facing[sub] = calibration.yaw(math.atan2(fit[0], fit[1]))
                del self._facing_fit[int(sub)]
        return fitting

    def subject_figures(self, subjects: list[int]) -> list[tuple[float, int, float, float]]:
        """Per subject: (mean alignment-aware frame error over the window, deg; frames compared so
        far; fitted facing, deg; mean joint error over the window, deg)."""
        index = np.array(subjects, np.int64)
        mean, _ = self.frame_errors.summary(index)
        joints, _ = self.joint_errors.summary(index)
        facing = np.degrees(calibration.yaw_of(self.facing[index]))
        return list(zip(mean.tolist(), self.frame_errors.count[index].tolist(), facing.tolist(), joints.tolist()))

    def device_figures(self, slots: np.ndarray, owner: np.ndarray) -> dict[str, np.ndarray]:
        """The error and latency figures of devices ``slots`` (k,) of subjects ``owner`` (k,),
        by stats field name, each (k,) (NaN: none)."""
        aad, mx, p99 = self.exact.summary(slots, (0.99,))
        live, live_max, live_p50, live_p99 = self.live.summary(slots, (0.5, 0.99))
        _, own_max, own_p99 = self.live_own.summary(slots, (0.99,))
        lat_p50, lat_p99 = self.latency.quantiles(slots, owner, (0.5, 0.99))
        count = self.exact.count[slots]
        aad_all = np.where(count > 0, self.exact.total[slots] / np.maximum(count, 1), np.nan)
        return {"aad_deg": aad, "p99_deg": p99, "max_deg": mx, "live_err_deg": live, "aad_all_deg": aad_all,
                "error_samples": count, "live_p50_deg": live_p50, "live_p99_deg": live_p99,
                "live_max_deg": live_max, "live_own_p99_deg": own_p99, "live_own_max_deg": own_max,
                "live_latency_p50_ms": lat_p50, "live_latency_p99_ms": lat_p99}

    def truth_keep(self, slots: int) -> np.ndarray:
        """(slots,) time of each device's oldest truth sample still waiting (int64 max if none)."""
        return self.truth.oldest(slots)

    def prune_reference(self, frame_keep: np.ndarray, owner: np.ndarray, subjects: int) -> None:
        """Let every row of reference samples forget what no frame still to build or compare needs
        (``frame_keep``: (slots,) oldest frame time still to build, us; ``owner``: (slots,) subject
        index)."""
        pending, t_us, _, _ = self._pending
        oldest = np.full(subjects, np.iinfo(np.int64).max)
        if len(pending):
            np.minimum.at(oldest, pending, t_us)
        self.reference.prune(np.minimum(frame_keep, oldest[owner]))
