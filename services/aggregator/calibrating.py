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
on: every device of the subject that streams, all or none (not still, restarted meanwhile, or
silent: refused with a sentence, the previous calibrations stay); a partial body (e.g. legs only)
calibrates the devices it has, and the answer names the body's segments it lacks.

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
from limbstream.body import PAPER10, Layout
from limbstream.services.aggregator.store import PointStore
from limbstream.services.aggregator.track import DeviceTrack

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
    absent: list[str]


class Calibrating:
    """The calibrations of the aggregator's devices, by device slot. It reads the segment points
    (``store``, the fusion's point store) to calibrate, and rewrites a device's stored points when
    its calibration changes; its owner applies :meth:`correct` to every point before storing it,
    and is told which devices' calibrations changed (facing fits, views).

    Parameters
    ----------
    store : the segment points of every device slot.
    on_start : calibrate each new stream from the calibration script it begins with.
    path : the calibration file (None or "": calibrations are not kept).
    """

    def __init__(self, store: PointStore, on_start: bool, path: str | os.PathLike | None = None):
        self.store = store
        self.on_start = on_start
        self.calibrations: dict[int, calibration.Calibration] = {}  # by device slot
        self.calibrated_at: dict[int, float] = {}                   # wall time when made, s
        self.calibration_refused: dict[int, str] = {}               # the sentence, by slot
        self._awaiting: dict[int, int | None] = {}                  # slot -> its stream's first sample time, us
        self.calibration_file = Path(path) if path else None
        self._saved: dict[str, dict] = self._load() if self.calibration_file else {}
        self._dirty = False

    def compares(self, slot: int) -> bool:
        """Whether the device's truth is compared yet: not before it is calibrated, when streams
        are calibrated on start (before, its readings are in the sensor's frame)."""
        return not self.on_start or slot in self.calibrations

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

    def new_stream(self, track: DeviceTrack) -> bool:
        """A new stream of ``track``'s device: a new script, a new calibration (or the saved one of
        that very stream, after an aggregator restart: then True, its calibration changed)."""
        slot = track.slot
        self.calibrations.pop(slot, None)
        self.calibrated_at.pop(slot, None)
        self.calibration_refused.pop(slot, None)
        self._awaiting.pop(slot, None)
        saved = self._saved.get(track.id)
        if saved is not None and saved.get("stream") == track.stream:
            try:
                cal = calibration.Calibration.from_dict(saved)
                self.calibrations[slot], self.calibrated_at[slot] = cal, float(saved["made_at"])
                return True
            except (KeyError, TypeError, ValueError) as exc:
                log.warning("saved calibration of %s ignored: %s", track.id, exc)
        if self.on_start:
            self._awaiting[slot] = None
        return False

    def _remember(self, track: DeviceTrack, cal: calibration.Calibration) -> None:
        """A calibration made: in use from now on, and saved with its stream."""
        slot = track.slot
        self.calibrations[slot] = cal
        self.calibrated_at[slot] = time.time()
        self.calibration_refused.pop(slot, None)
        self._awaiting.pop(slot, None)
        if self.calibration_file is not None:
            self._saved[track.id] = {"stream": track.stream, "made_at": self.calibrated_at[slot]} | cal.as_dict()
            self._dirty = True

    def first_sample(self, slot: int, seq: int, t_us: int) -> None:
        """A point arrived; the one of sequence number 0 fixes the stream's script times."""
        if seq == 0 and slot in self._awaiting and self._awaiting[slot] is None:
            self._awaiting[slot] = t_us

    def correct(self, slots: np.ndarray, t_us: np.ndarray, q: np.ndarray, w: np.ndarray) -> None:
        """Correct points before they are stored, in place: orientations ``q`` (P, 4) float64 and
        body rates ``w`` (P, 3) rad/s float64 of devices ``slots`` (P,) at device times ``t_us``
        (P,) us, where the device is calibrated (the rate turns with the right-hand factor:
        omega' = c^-1 omega c)."""
        if not self.calibrations:
            return
        for slot in np.unique(slots):
            cal = self.calibrations.get(int(slot))
            if cal is not None:
                mine = slots == slot
                q[mine] = cal.apply(q[mine], t_us[mine] * 1e-6)
                w[mine] = quat.rotate(quat.conjugate(cal.c), w[mine])

    def keep(self, keep: np.ndarray) -> np.ndarray:
        """``keep`` (slots,) oldest point time each row must keep, us, lowered so that a device
        awaiting its calibration keeps its script."""
        for slot, t0 in self._awaiting.items():
            keep[slot] = min(keep[slot], np.iinfo(np.int64).min if t0 is None else t0)
        return keep

    def calibrate_ready(self, tracks: list[DeviceTrack], clock: float) -> list[DeviceTrack]:
        """Calibrate every awaiting device (``tracks``: by slot) whose points passed its script's
        mounting pose, or refuse it; returns those calibrated (their calibration changed)."""
        if not self._awaiting:
            return []
        last = self.store.last_t()
        made = []
        for slot, t0 in list(self._awaiting.items()):
            track = tracks[slot]
            if t0 is None and track.first_seq is not None and track.settled(clock):
                del self._awaiting[slot]  # its history is in, or no longer awaited, without sequence number 0
                self.calibration_refused[slot] = (f"{track.id}: the start of its stream (the calibration script) "
                                                  "never arrived")
                continue
            if t0 is None or last[slot] < t0 + MOUNTING_US[1]:
                continue
            del self._awaiting[slot]
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
            self._remember(track, cal)
            made.append(track)
        if self._dirty:
            self._save()
        return made

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

    def start_request(self, subject: str, tracks: dict[str, DeviceTrack] | None, pose: str, latest_t: np.ndarray,
                      wall: float, layout: Layout | None = None) -> CalibrationRequest | str:
        """Begin a calibration of ``subject``'s devices that stream (``tracks``: by segment, None:
        no such subject here; streaming: online, with points) from ``pose`` held from now on
        (``latest_t``: (slots,) newest device time of each device, us); a refusal sentence instead
        if it cannot begin (unknown subject, no device streams). ``layout``: the subject's (default
        paper10), whose segments without a device streaming the answer names."""
        if tracks is None:
            return f"{subject}: no such subject here"
        chosen = [t for t in tracks.values() if t.online and latest_t[t.slot] >= 0]
        if not chosen:
            return f"{subject}: no device streams (none online with points)"
        if pose == "mounting":
            uncalibrated = [t.id for t in chosen if "rest" not in getattr(self.calibrations.get(t.slot), "poses", ())]
            if uncalibrated:
                return f"mounting: calibrate the rest pose first ({', '.join(uncalibrated)} not calibrated)"
        t_from = int(max(latest_t[t.slot] for t in chosen))
        return CalibrationRequest(subject, pose, chosen, {t.slot: t.generation for t in chosen}, t_from,
                                  t_from + round(wire.CALIBRATION_HOLD_S * 1e6), wall,
                                  [s for s in (layout or PAPER10).segment_names if s not in {t.segment for t in chosen}])

    def finish_request(self, req: CalibrationRequest, wall: float) -> tuple[wire.CalibrateAnswer | None, list]:
        """The answer once every device's points passed the hold (None: not yet), and the devices
        whose calibrations changed: on success the new calibrations are in use and saved."""
        for t in req.tracks:
            if t.generation != req.generation[t.slot]:
                return wire.CalibrateAnswer(False, f"{t.id} restarted (a new stream) during the calibration; "
                                                   "calibrate again"), []
        last = self.store.last_t()
        late = [t.id for t in req.tracks if last[t.slot] < req.t_to]
        if late:
            if wall - req.wall > wire.CALIBRATION_HOLD_S + REQUEST_TIMEOUT_S:
                return wire.CalibrateAnswer(False, f"no points past the pose from {', '.join(late)}"), []
            return None, []
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
            return wire.CalibrateAnswer(False, str(exc)), []
        by_slot = {t.slot: t for t in req.tracks}
        for slot, (old, new) in made.items():
            self._reapply_store(slot, old, new)
            self._remember(by_slot[slot], new)
        if self._dirty:
            self._save()
        return wire.CalibrateAnswer(True, None, {
            by_slot[slot].id: {"poses": list(new.poses), "heading_deg": round(math.degrees(new.heading), 3)}
            for slot, (_, new) in made.items()}, req.absent), [by_slot[slot] for slot in made]

    def _reapply_store(self, slot: int, old: calibration.Calibration | None, new: calibration.Calibration) -> None:
        """The row's points corrected by ``new`` instead of ``old`` (None: raw)."""
        if old is not None:
            n = self.store.n[slot]
            t = self.store.t[slot, :n] * 1e-6
            self.store.q[slot, :n] = old.undo(self.store.q[slot, :n].astype(np.float64), t).astype(np.float32)
            w = self.store.w[slot, :n].astype(np.float64)
            self.store.w[slot, :n] = quat.rotate(np.broadcast_to(old.c, (n, 4)), w).astype(np.float32)
        self._apply_to_store(slot, new)

    def figures(self, slots: list[int]) -> dict[str, list]:
        """The calibration fields of the stats entries of devices ``slots``, by name: a list of
        values each."""
        wall = time.time()
        at = [self.calibrated_at.get(slot) for slot in slots]
        cal = [self.calibrations.get(slot) for slot in slots]
        return {"calibrated": [c is not None for c in cal],
                "calibration_age_s": [math.nan if a is None else max(0.0, wall - a) for a in at],
                "heading_drift_dps": [math.nan if c is None else math.degrees(c.drift) for c in cal],
                "calibration_refused": [self.calibration_refused.get(slot) for slot in slots]}
