"""Scoring of the aggregator's reconstruction against the truth tap (the devices' raw samples),
kept apart from frame building (:mod:`.fusion`), which never reads the truth.

- Per device, at every truth sample once its reconstruction is final: the angular error of the
  exact reconstruction (SLERP between segment points) and of the live view (the newest point at
  or before the sample, extrapolated to it: what a live frame at that instant showed).
- Per subject, alignment-aware: when the truth tap carries reference times (the instant each
  sample was really taken), every exact frame at time ``t`` is compared, segment by segment,
  with the truth at reference instant ``t`` (SLERP between the truth samples around it) once
  the truth of every device has passed ``t``: the subject's ``frame_aad_deg``. Device clocks
  that disagree show up here and nowhere else.
- Facing: calibrated sensors know the body but not which way it faces in the truth's world
  (without a magnetometer, nothing can). When a subject's devices are all calibrated (again),
  one rotation about the vertical per subject is fitted from the first FACING_FIT_FRAMES frames
  compared (the circular mean of the turn from frame to truth over their segments), those frames
  are not scored, and every later frame is compared after that rotation.

Errors are degrees, times microseconds.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from limbstream import calibration, quat, wire
from limbstream.wire import SEGMENTS
from support.reference_aggregator.store import ErrorRings, PointStore, TruthQueue

if TYPE_CHECKING:
    from support.reference_aggregator.fusion import Subject

FRAME_ERROR_WAIT_S = 10.0
"""An exact frame waits at most this long (frame time behind its subject's newest frame) for the
truth of its devices to pass it; then it is compared with the truth there is."""


FACING_FIT_FRAMES = 50
"""Frames (a second at 50 Hz) a subject's facing is fitted from after its calibration."""


class Scoring:
    """The truth-side state of a :class:`~.fusion.Fusion` (mixed into it: it reads the fusion's
    point store, device slots and device view). ``exact``, ``live``: per device slot, windows of
    angular errors; ``latency``: live frame publish time - frame time, ms; ``frame_errors``: per
    subject, the mean segment error of each frame compared."""

    def _init_scoring(self, error_window: int) -> None:
        self.truth = TruthQueue()
        self.exact = ErrorRings(error_window)
        self.live = ErrorRings(error_window)
        self.latency = ErrorRings(error_window)
        self.reference = PointStore(2048)          # truth samples by reference time, per device slot
        self.frame_errors = ErrorRings(error_window)
        self.facing = np.zeros((0, 4))                  # per subject: truth <- frames, a turn about the vertical
        self._facing_fit: dict[int, list[float]] = {}  # subject index -> [sum sin, sum cos, frames]
        # exact frames waiting for the truth: (subject index,), (time us,), (frame, 10, 4) float32
        self._pending = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, len(SEGMENTS), 4), np.float32),
                         np.zeros((0, len(SEGMENTS)), bool))  # and (frame, 10) the segments it lacks: not scored

    def _add_subject_scores(self, subjects: int) -> None:
        self.frame_errors.ensure(subjects)
        grown = np.zeros((subjects, 4))
        grown[:, 0] = 1.0
        grown[: len(self.facing)] = self.facing
        self.facing = grown

    def _fit_facing(self, subject: int) -> None:
        """Fit the subject's facing again from the next frames compared (a calibration changed)."""
        self._facing_fit[subject] = [0.0, 0.0, 0.0]

    def _add_device_scores(self, slot: int) -> None:
        self.reference.add_slot()
        self.exact.ensure(slot + 1)
        self.live.ensure(slot + 1)
        self.latency.ensure(slot + 1)

    def _reset_scores(self, slot: int) -> None:
        """A new stream of the device in ``slot``: its windows start over."""
        self.reference.reset(slot)
        self.exact.reset(slot)
        self.live.reset(slot)
        self.latency.reset(slot)

    def _take_truth(self, slot: int, generation: int, batch: wire.RawBatch) -> None:
        """A truth-tap batch of the device's current stream ``generation`` (not compared before
        the device is calibrated, when calibrations are made)."""
        if self.calibrate_on_start and slot not in self.calibrations:
            return
        self.truth.put(slot, generation, batch.t_us, batch.q)
        if batch.ref_us is not None:  # reference times: only for the alignment-aware frame error
            n = self.reference.n[slot]
            newer = batch.ref_us > (self.reference.t[slot, n - 1] if n else np.iinfo(np.int64).min)
            if newer.any():
                self.reference.extend(slot, batch.ref_us[newer], batch.q[newer])

    def _score_later(self, owner: np.ndarray, t_us: np.ndarray, q: np.ndarray, lacking: np.ndarray) -> None:
        """Exact frames just built ((F,) subject index, (F,) time us, (F, 10, 4) quaternions, (F, 10)
        the segments each lacks or has inside a span of lost points: not scored): those with a device that has reference times wait to be compared
        (:meth:`evaluate_frames`)."""
        slots = self.seg_slots[owner]
        with_truth = (self.reference.n[np.maximum(slots, 0)] > 0).any(axis=1)
        if with_truth.any():
            po, pt, pq, pl = self._pending
            self._pending = (np.concatenate([po, owner[with_truth]]), np.concatenate([pt, t_us[with_truth]]),
                             np.concatenate([pq, q[with_truth].astype(np.float32)]), np.concatenate([pl, lacking[with_truth]]))

    def evaluate_truth(self) -> int:
        """Angular error of the exact reconstruction and of the live view (the newest point at or
        before the sample, extrapolated to it), at every truth sample whose reconstruction became
        final. Returns how many samples."""
        slots, t_us, truth, overflow = self.truth.take_ready(self._device_view()[0], self.generation)
        for slot in overflow:
            self.tracks[slot].dropped["raw_overflow"] += 1
        before = t_us < self.store.t[slots, 0]  # older than the stream's first point known: no reconstruction
        for slot in slots[before]:
            self.tracks[slot].dropped["raw_before_first_point"] += 1
        slots, t_us, truth = slots[~before], t_us[~before], truth[~before]
        if len(slots):
            self.exact.add(slots, quat.angle_deg(self.store.interpolate(slots, t_us), truth))
            self.live.add(slots, quat.angle_deg(self.store.predicted(slots, t_us), truth))
        return len(slots)

    def evaluate_frames(self) -> int:
        """Alignment-aware error of the exact frames waiting for it: each segment of a frame at
        ``t`` against its device's truth at reference time ``t``, once every device of the frame
        with reference times has truth past ``t`` (or the frame waited FRAME_ERROR_WAIT_S).
        Adds each frame's mean over its compared segments to its subject's window. Returns the
        frames compared."""
        owner, t_us, q, lacking = self._pending
        if len(owner) == 0:
            return 0
        slots = self.seg_slots[owner]                                   # (P, 10)
        rows = np.maximum(slots, 0)
        n = self.reference.n[rows]
        has = (slots >= 0) & (n > 0) & ~lacking
        last = self.reference.t[rows, np.maximum(n - 1, 0)]
        newest = np.full(len(self.subjects), np.iinfo(np.int64).min)
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
        keep = ~ready
        self._pending = (owner[keep], t_us[keep], q[keep], lacking[keep])
        return int(done.sum())

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

    def facing_deg(self, sub: Subject) -> float:
        """The subject's fitted facing (truth <- frames, about the vertical), degrees."""
        return math.degrees(float(calibration.yaw_of(self.facing[sub.index])))

    def frame_error(self, sub: Subject) -> tuple[float, int]:
        """(mean alignment-aware frame error over the window, deg; frames compared so far)."""
        idx = np.array([sub.index])
        mean, _ = self.frame_errors.summary(idx)
        return float(mean[0]), int(self.frame_errors.count[sub.index])

    def _prune_reference(self, frame_keep: np.ndarray) -> None:
        """Let every row of reference samples forget what no frame still to build or compare needs
        (``frame_keep``: (slots,) oldest frame time still to build, us)."""
        owner, t_us, _, _ = self._pending
        oldest = np.full(len(self.subjects), np.iinfo(np.int64).max)
        if len(owner):
            np.minimum.at(oldest, owner, t_us)
        self.reference.prune(np.minimum(frame_keep, oldest[self.owner]))
