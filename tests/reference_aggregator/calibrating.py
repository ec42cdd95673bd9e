"""Per-device calibration in the aggregator, applied before fusion (limbstream.calibration).

With ``calibrate_on_start`` every new stream is calibrated from its own calibration script: once
the device's points reach past the script's mounting pose (its windows are fixed offsets from the
stream's first sample), the rest and mounting still windows of its reconstruction give the
device's correction; the points already stored are corrected, and every later one on arrival.
A stream whose windows are not still (it did not begin with the script, e.g. a restart mid-motion)
is refused with a sentence and stays uncalibrated. Truth samples are compared only once a device
is calibrated (before, its readings are in the sensor's frame, not the segment's).

On request (``limbstream/<subject>/calibrate``, :mod:`limbstream.wire.calibrate`) the subject's
devices are calibrated from the pose the subject holds for CALIBRATION_HOLD_S from the request
on: every device of the subject, all or none (a device missing, not still, restarted meanwhile,
or silent: refused with a sentence, the previous calibrations stay).

Calibrations live outside the aggregator process when it has a calibration file: every one made
is written there (atomically, at most once per tick), by device id with the stream it belongs to,
and a (re)started aggregator takes a device's saved calibration when it sees that stream again.

Each yaw reset also learns the heading's drift from the heading measured before (the mounting
pose or the previous yaw reset): from then on, every point is corrected with the heading
extrapolated to its device time (drift compensation).
"""
from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from limbstream import calibration, quat, wire
from limbstream.wire import SEGMENTS

log = logging.getLogger("limbstream.aggregator.calibration")

REQUEST_TIMEOUT_S = 5.0
"""A calibration request is refused when its devices' points do not pass the pose's hold within
this long after the hold should have ended (wall seconds)."""

STEP_S = 0.02
"""The reconstruction is read every this many seconds within a still window."""


def _window_us(start: float, length: float) -> tuple[float, float]:
    """A still pose held from ``start`` for ``length`` s of the script, less the margins, us."""
    return 1e6 * (start + calibration.STILL_MARGIN_S), 1e6 * (start + length - calibration.STILL_MARGIN_S)


REST_US = _window_us(0.0, calibration.REST_S)
MOUNTING_US = _window_us(calibration.REST_S + calibration.MOVE_S, calibration.MOUNTING_S)


@dataclass
class CalibrationRequest:
    """A subject's calibration under way: its devices, their stream generations at the request,
    the hold's device times (us) and the request's wall time (s)."""

    subject: str
    pose: str
    tracks: list
    generation: dict[int, int]
    t_from: int
    t_to: int
    wall: float


class Calibrating:
    """The calibrations of a :class:`~.fusion.Fusion`'s devices (mixed into it: it reads and
    rewrites the fusion's point store)."""

    def _init_calibration(self, on_start: bool, path: str | os.PathLike | None = None) -> None:
        self.calibrate_on_start = on_start
        self.calibrations: dict[int, calibration.Calibration] = {}  # by device slot
        self.calibrated_at: dict[int, float] = {}                   # wall time when made, s
        self.calibration_refused: dict[int, str] = {}               # the sentence, by slot
        self._awaiting: dict[int, int | None] = {}                  # slot -> its stream's first sample time, us
        self.calibration_file = Path(path) if path else None
        self._saved: dict[str, dict] = self._load() if self.calibration_file else {}
        self._dirty = False

    def _load(self) -> dict[str, dict]:
        """The saved calibrations ({device id: entry}); a missing file is none, a bad one is
        logged and ignored (calibrations are then made again)."""
        try:
            data = json.loads(self.calibration_file.read_text())
            if not isinstance(data, dict):
                raise ValueError("not a JSON object")
            return {k: v for k, v in data.items() if isinstance(v, dict)}
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as exc:
            log.warning("calibration file %s ignored: %s", self.calibration_file, exc)
            return {}

    def _save(self) -> None:
        """Write every calibration known (atomically: readers never see half a file)."""
        tmp = self.calibration_file.with_name(self.calibration_file.name + ".tmp")
        tmp.write_text(json.dumps(self._saved, indent=1) + "\n")
        os.replace(tmp, self.calibration_file)
        self._dirty = False

    def _new_stream_calibration(self, slot: int) -> None:
        """A new stream of the device in ``slot``: a new script, a new calibration (or the saved
        one of that very stream, after an aggregator restart)."""
        self.calibrations.pop(slot, None)
        self.calibrated_at.pop(slot, None)
        self.calibration_refused.pop(slot, None)
        self._awaiting.pop(slot, None)
        track = self.tracks[slot]
        saved = self._saved.get(track.id)
        if saved is not None and saved.get("stream") == track.stream:
            try:
                cal = calibration.Calibration.from_dict(saved)
                self.calibrations[slot], self.calibrated_at[slot] = cal, float(saved["made_at"])
                self._calibration_changed(slot)
                return
            except (KeyError, TypeError, ValueError) as exc:
                log.warning("saved calibration of %s ignored: %s", track.id, exc)
        if self.calibrate_on_start:
            self._awaiting[slot] = None

    def _remember(self, slot: int, cal: calibration.Calibration) -> None:
        """A calibration made: in use from now on, and saved with its stream."""
        track = self.tracks[slot]
        self.calibrations[slot] = cal
        self.calibrated_at[slot] = time.time()
        self._calibration_changed(slot)
        self.calibration_refused.pop(slot, None)
        self._awaiting.pop(slot, None)
        self._view = None
        if self.calibration_file is not None:
            self._saved[track.id] = {"stream": track.stream, "made_at": self.calibrated_at[slot]} | cal.as_dict()
            self._dirty = True

    def _calibration_changed(self, slot: int) -> None:
        """A device's calibration changed: once its subject's devices are all calibrated, its
        facing is fitted again (:mod:`.scoring`)."""
        sub = self.subjects[self.tracks[slot].subject]
        if all(t.slot in self.calibrations for t in sub.tracks.values()):
            self._fit_facing(sub.index)

    def _first_sample(self, slot: int, seq: int, t_us: int) -> None:
        """A point arrived; the one of sequence number 0 fixes the stream's script times."""
        if seq == 0 and slot in self._awaiting and self._awaiting[slot] is None:
            self._awaiting[slot] = t_us

    def _corrected(self, slot: int, q, omega, t_us: int):
        """A point's orientation (4,) and body rate (3,) rad/s or None at device time ``t_us``,
        corrected if the device is calibrated (the rate turns with the right-hand factor:
        omega' = c^-1 omega c)."""
        cal = self.calibrations.get(slot)
        if cal is None:
            return q, omega
        q = cal.apply(np.asarray(q, np.float64)[None], np.array([t_us * 1e-6]))[0]
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
                rest, t_rest = self._window(slot, t0, REST_US)
                mounting, t_mounting = self._window(slot, t0, MOUNTING_US)
                pose = calibration.mounting_pose((track.segment,))[0]
                cal = calibration.calibrate(np.concatenate([rest, mounting]), slice(0, len(rest)),
                                            slice(len(rest), None), pose, track.id,
                                            np.concatenate([t_rest, t_mounting]))
            except calibration.CalibrationError as exc:
                self.calibration_refused[slot] = str(exc)
                continue
            self._apply_to_store(slot, cal)
            self._remember(slot, cal)
        if self._dirty:
            self._save()
        return done

    def _window(self, slot: int, t0: int, window: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """The device's reconstruction (k, 4) every STEP_S within ``window`` (us after ``t0``,
        device time us) and its device times (k,) s."""
        t = t0 + np.arange(window[0], window[1], STEP_S * 1e6).astype(np.int64)
        return self.store.interpolate(np.full(len(t), slot), t), t * 1e-6

    def _apply_to_store(self, slot: int, cal: calibration.Calibration) -> None:
        """Correct the points the device's row holds (orientations and body rates)."""
        n = self.store.n[slot]
        t = self.store.t[slot, :n] * 1e-6
        self.store.q[slot, :n] = cal.apply(self.store.q[slot, :n].astype(np.float64), t).astype(np.float32)
        w = self.store.w[slot, :n].astype(np.float64)
        self.store.w[slot, :n] = quat.rotate(np.broadcast_to(quat.conjugate(cal.c), (n, 4)), w).astype(np.float32)

    # ------------------------------------------------------------------ requests

    def start_request(self, subject: str, pose: str, wall: float) -> CalibrationRequest | str:
        """Begin a calibration of ``subject``'s devices from ``pose`` held from now on; a refusal
        sentence instead if it cannot begin (unknown subject, a device missing)."""
        sub = self.subjects.get(subject)
        if sub is None:
            return f"{subject}: no such subject here"
        missing = [seg for seg in SEGMENTS if seg not in sub.tracks or not sub.tracks[seg].online
                   or self.latest_t[sub.tracks[seg].slot] < 0]
        if missing:
            return f"{subject}: device(s) missing: {', '.join(missing)}"
        tracks = [sub.tracks[seg] for seg in SEGMENTS]
        if pose == "mounting":
            uncalibrated = [t.id for t in tracks if "rest" not in getattr(self.calibrations.get(t.slot), "poses", ())]
            if uncalibrated:
                return f"mounting: calibrate the rest pose first ({', '.join(uncalibrated)} not calibrated)"
        t_from = int(max(self.latest_t[t.slot] for t in tracks))
        return CalibrationRequest(subject, pose, tracks, {t.slot: t.generation for t in tracks}, t_from,
                                  t_from + round(wire.CALIBRATION_HOLD_S * 1e6), wall)

    def finish_request(self, req: CalibrationRequest, wall: float) -> wire.CalibrateAnswer | None:
        """The answer once every device's points passed the hold (None: not yet); on success the
        new calibrations are in use and saved."""
        for t in req.tracks:
            if t.generation != req.generation[t.slot]:
                return wire.CalibrateAnswer(False, f"{t.id} restarted (a new stream) during the calibration; "
                                                   "calibrate again")
        last = self.store.last_t()
        late = [t.id for t in req.tracks if last[t.slot] < req.t_to]
        if late:
            if wall - req.wall > wire.CALIBRATION_HOLD_S + REQUEST_TIMEOUT_S:
                return wire.CalibrateAnswer(False, f"no points past the pose from {', '.join(late)}")
            return None
        made = {}
        try:
            for t in req.tracks:
                old = self.calibrations.get(t.slot)
                window, t_window = self._window(t.slot, req.t_from, (0.0, req.t_to - req.t_from))
                raw = window if old is None else old.undo(window, t_window)
                reading = calibration.still_mean(raw, f"{t.id}, {req.pose} pose")
                middle = float(t_window.mean())
                if req.pose == "rest" or old is None:
                    new = calibration.Calibration.rest(reading, middle)
                elif req.pose == "mounting":
                    new = old.with_mounting(reading, calibration.mounting_pose((t.segment,))[0])
                else:
                    new = old.with_yaw(reading, middle)  # and the drift since the last heading measured
                made[t.slot] = (old, new)
        except calibration.CalibrationError as exc:
            return wire.CalibrateAnswer(False, str(exc))
        for slot, (old, new) in made.items():
            self._reapply_store(slot, old, new)
            self._remember(slot, new)
        if self._dirty:
            self._save()
        return wire.CalibrateAnswer(True, None, {
            self.tracks[slot].id: {"poses": list(new.poses), "heading_deg": round(math.degrees(new.heading), 3)}
            for slot, (_, new) in made.items()})

    def _reapply_store(self, slot: int, old: calibration.Calibration | None, new: calibration.Calibration) -> None:
        """The row's points corrected by ``new`` instead of ``old`` (None: raw)."""
        if old is not None:
            n = self.store.n[slot]
            t = self.store.t[slot, :n] * 1e-6
            self.store.q[slot, :n] = old.undo(self.store.q[slot, :n].astype(np.float64), t).astype(np.float32)
            w = self.store.w[slot, :n].astype(np.float64)
            self.store.w[slot, :n] = quat.rotate(np.broadcast_to(old.c, (n, 4)), w).astype(np.float32)
        self._apply_to_store(slot, new)

    def calibration_figures(self, slot: int) -> dict:
        """The device's calibration fields of its stats."""
        at = self.calibrated_at.get(slot)
        return {"calibrated": slot in self.calibrations,
                "calibration_age_s": math.nan if at is None else max(0.0, time.time() - at),
                "heading_drift_dps": math.degrees(cal.drift) if (cal := self.calibrations.get(slot)) else math.nan,
                "calibration_refused": self.calibration_refused.get(slot)}
