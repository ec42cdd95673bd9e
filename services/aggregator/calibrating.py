"""Per-device calibration in the aggregator, applied before fusion (limbstream.calibration).

With ``calibrate_on_start`` every new stream is calibrated from its own calibration script: once
the device's points reach past the script's mounting pose (its windows are fixed offsets from the
stream's first sample), the rest and mounting still windows of its reconstruction give the
device's correction; the points already stored are corrected, and every later one on arrival.
A stream whose windows are not still (it did not begin with the script, e.g. a restart mid-motion)
is refused with a sentence and stays uncalibrated. Truth samples are compared only once a device
is calibrated (before, its readings are in the sensor's frame, not the segment's).
"""
from __future__ import annotations

import math

import numpy as np

from limbstream import calibration, quat

STEP_S = 0.02
"""The reconstruction is read every this many seconds within a still window."""


def _window_us(start: float, length: float) -> tuple[float, float]:
    """A still pose held from ``start`` for ``length`` s of the script, less the margins, us."""
    return 1e6 * (start + calibration.STILL_MARGIN_S), 1e6 * (start + length - calibration.STILL_MARGIN_S)


REST_US = _window_us(0.0, calibration.REST_S)
MOUNTING_US = _window_us(calibration.REST_S + calibration.MOVE_S, calibration.MOUNTING_S)


class Calibrating:
    """The calibrations of a :class:`~.fusion.Fusion`'s devices (mixed into it: it reads and
    rewrites the fusion's point store)."""

    def _init_calibration(self, on_start: bool) -> None:
        self.calibrate_on_start = on_start
        self.calibrations: dict[int, calibration.Calibration] = {}  # by device slot
        self.calibrated_at: dict[int, float] = {}                   # arrival clock when made, s
        self.calibration_refused: dict[int, str] = {}               # the sentence, by slot
        self._awaiting: dict[int, int | None] = {}                  # slot -> its stream's first sample time, us

    def _new_stream_calibration(self, slot: int) -> None:
        """A new stream of the device in ``slot``: a new script, a new calibration."""
        self.calibrations.pop(slot, None)
        self.calibrated_at.pop(slot, None)
        self.calibration_refused.pop(slot, None)
        if self.calibrate_on_start:
            self._awaiting[slot] = None

    def _first_sample(self, slot: int, seq: int, t_us: int) -> None:
        """A point arrived; the one of sequence number 0 fixes the stream's script times."""
        if seq == 0 and slot in self._awaiting and self._awaiting[slot] is None:
            self._awaiting[slot] = t_us

    def _corrected(self, slot: int, q, omega):
        """A point's orientation (4,) and body rate (3,) rad/s or None, corrected if the device is
        calibrated (the rate turns with the right-hand factor: omega' = c^-1 omega c)."""
        cal = self.calibrations.get(slot)
        if cal is None:
            return q, omega
        q = cal.apply(np.asarray(q, np.float64)[None])[0]
        if omega is not None:
            omega = quat.rotate(quat.conjugate(cal.c), np.asarray(omega, np.float64))
        return q, omega

    def _calibration_keep(self, keep: np.ndarray) -> np.ndarray:
        """``keep`` (slots,) oldest point time each row must keep, us, lowered so that a device
        awaiting its calibration keeps its script."""
        for slot, t0 in self._awaiting.items():
            keep[slot] = min(keep[slot], np.iinfo(np.int64).min if t0 is None else t0)
        return keep

    def calibrate_ready(self) -> int:
        """Calibrate every awaiting device whose points passed its script's mounting pose; returns
        how many were calibrated or refused."""
        if not self._awaiting:
            return 0
        last = self.store.last_t()
        done = 0
        for slot, t0 in list(self._awaiting.items()):
            track = self.tracks[slot]
            if t0 is None and track.first_seq is not None and track.settled(self.clock):
                del self._awaiting[slot]  # its history is in, or no longer awaited, without sequence number 0
                self.calibration_refused[slot] = (f"{track.id}: the start of its stream (the calibration script) "
                                                  "never arrived")
                done += 1
                continue
            if t0 is None or last[slot] < t0 + MOUNTING_US[1]:
                continue
            del self._awaiting[slot]
            done += 1
            try:
                rest = self._window(slot, t0, REST_US)
                mounting = self._window(slot, t0, MOUNTING_US)
                pose = calibration.mounting_pose((track.segment,))[0]
                cal = calibration.calibrate(np.concatenate([rest, mounting]), slice(0, len(rest)),
                                            slice(len(rest), None), pose, track.id)
            except calibration.CalibrationError as exc:
                self.calibration_refused[slot] = str(exc)
                continue
            self._apply_to_store(slot, cal)
            self.calibrations[slot] = cal
            self.calibrated_at[slot] = self.clock
            self._view = None
        return done

    def _window(self, slot: int, t0: int, window: tuple[float, float]) -> np.ndarray:
        """(k, 4) the device's reconstruction every STEP_S within a still window of its script."""
        t = t0 + np.arange(window[0], window[1], STEP_S * 1e6).astype(np.int64)
        return self.store.interpolate(np.full(len(t), slot), t)

    def _apply_to_store(self, slot: int, cal: calibration.Calibration) -> None:
        """Correct the points the device's row holds (orientations and body rates)."""
        n = self.store.n[slot]
        self.store.q[slot, :n] = cal.apply(self.store.q[slot, :n].astype(np.float64)).astype(np.float32)
        w = self.store.w[slot, :n].astype(np.float64)
        self.store.w[slot, :n] = quat.rotate(np.broadcast_to(quat.conjugate(cal.c), (n, 4)), w).astype(np.float32)

    def calibration_figures(self, slot: int, now: float) -> dict:
        """The device's calibration fields of its stats."""
        at = self.calibrated_at.get(slot)
        return {"calibrated": slot in self.calibrations,
                "calibration_age_s": math.nan if at is None else max(0.0, now - at),
                "calibration_refused": self.calibration_refused.get(slot)}
