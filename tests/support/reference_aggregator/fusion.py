"""Full-body frames of every subject from the devices' segment points (DESIGN section 4),
computed for all subjects at once.

Exact frames lie on a fixed grid (multiples of the output period in device time) and are
emitted once every active device of the subject has a segment point at or after the frame
time (the watermark), so the SLERP reconstruction in them is final. A device that is offline
or has ended its stream does not hold the watermark back; its segment is held at its last
point and the frame is flagged MISSING. Live frames: at each subject's device time "now" (the
newest device time seen, advanced by the arrival clock since it arrived), every segment exact
(SLERP) where a point at or after that time is known, else its newest point extrapolated with
the point's body rate (``quat.predict``: the prediction the device's live rule keeps within
``live_bound_deg``; a point without a rate is held). Scoring against the truth tap: :mod:`.scoring`.
"""
from __future__ import annotations

import math

import numpy as np

from limbstream import wire
from limbstream.services.aggregator.frames import LIVE_EASE
from support.reference_aggregator.skeleton import Skeleton
from limbstream.wire import SEGMENTS
from support.reference_aggregator.calibrating import Calibrating
from support.reference_aggregator.scoring import Scoring
from support.reference_aggregator.store import IDENTITY, PointStore
from support.reference_aggregator.track import DeviceTrack

MAX_FRAMES_PER_CALL = 500
"""Most exact frames one subject gets per call (catch-up proceeds over several ticks)."""
FIRST_FRAME_WAIT_S = 1.0
"""How long a subject's first exact frame waits, at most, for all of its devices to settle
(DeviceTrack.settled) after it could first start, seconds; then it starts from the settled
ones (a device whose stream keeps restarting must not hold the others back)."""

OVERDUE_GRACE_S = 0.25
"""A live frame extrapolates an active device's newest point for at most its max segment length
(``max_len`` samples at the frame rate: by then the device has sent its next point) plus this
much for transport; a device silent for longer is overdue: held at its newest point, frame
flagged MISSING."""

_SEGMENT_INDEX = {name: i for i, name in enumerate(SEGMENTS)}
_NONE = np.iinfo(np.int64).min


class Subject:
    """A subject's devices and frame counters."""

    def __init__(self, name: str, index: int):
        self.name, self.index = name, index
        self.tracks: dict[str, DeviceTrack] = {}
        self.frames = 0
        self.skipped = 0
        self.rest_pose: str | None = None  # as its devices announce it (None: not yet heard)
        self.waiting_since: float | None = None  # arrival clock (s) when its first frame could start


class Fusion(Scoring, Calibrating):
    """Tracks, stores and frame builder of all subjects of one aggregator.

    Parameters
    ----------
    rate : exact frame rate, Hz.
    skeleton : forward-kinematics model for the joint positions.
    capacity : segment points kept per device (history on joining + what frames still need).
    error_window : samples in each device's angular-error windows.
    max_backlog_s : frames further behind than this are skipped (counted) instead of built.
    """

    def __init__(self, rate: float, skeleton: Skeleton, capacity: int = 1024, error_window: int = 3000,
                 max_backlog_s: float = 60.0, calibrate_on_start: bool = False, calibration_file: str = ""):
        self.period_us = 1e6 / rate
        self.skeleton = skeleton
        self.max_backlog = int(max_backlog_s * rate)
        self.store = PointStore(capacity)
        self._init_scoring(error_window)
        self._init_calibration(calibrate_on_start, calibration_file)
        self.subjects: dict[str, Subject] = {}
        self.tracks: list[DeviceTrack] = []
        self.clock = 0.0  # newest arrival time seen (s): the "now" of the history grace period
        self.seg_slots = np.full((0, len(SEGMENTS)), -1, np.int64)  # (subjects, 10) device slot or -1
        self.next_frame = np.zeros(0, np.int64)  # grid index of each subject's next exact frame, -1 unset
        self.exact_seq = np.zeros(0, np.int64)
        self.live_seq = np.zeros(0, np.int64)
        self.live_t = {}                         # per subject index: newest live frame time, us
        self.live_offset = {}                    # per subject index: device time - clock, us
        self.live_clock = None                   # the clock of the last live frames, s
        self.rest_flag = np.zeros(0, np.uint8)   # per subject: pose-frame flag bits of its rest pose
        # per device slot, kept current as messages arrive, so a tick reads them without a loop
        self.owner = np.zeros(0, np.int64)        # subject index
        self.online = np.zeros(0, bool)           # liveliness token present
        self.active = np.zeros(0, bool)           # online and its stream not ended
        self.generation = np.zeros(0, np.int64)   # stream generation (truth samples of older ones are dropped)
        self.latest_t = np.zeros(0, np.int64)     # newest device time of a point or truth sample, or _NONE
        self.latest_arrival = np.zeros(0)         # arrival clock (s) when latest_t arrived
        self.last_raw_t = np.zeros(0, np.int64)   # newest truth sample time, _NONE before one
        self.horizon_us = np.zeros(0, np.int64)   # longest extrapolation of the newest point (OVERDUE_GRACE_S)
        self.settled = np.zeros(0, bool)          # DeviceTrack.settled, refreshed for the _unsettled ones
        self._unsettled: set[DeviceTrack] = set()
        self._gappy: set[DeviceTrack] = set()     # tracks with lost points (frames in those spans: GAP)
        self._view: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # see _device_view

    # ------------------------------------------------------------------ devices

    def track(self, subject: str, segment: str) -> DeviceTrack:
        """The track of a device, created (with its rows) on first sight."""
        sub = self.subjects.get(subject)
        if sub is None:
            sub = self.subjects[subject] = Subject(subject, len(self.subjects))
            self.seg_slots = np.vstack([self.seg_slots, np.full((1, len(SEGMENTS)), -1, np.int64)])
            self.next_frame = np.append(self.next_frame, -1)
            self.exact_seq = np.append(self.exact_seq, 0)
            self.live_seq = np.append(self.live_seq, 0)
            self.rest_flag = np.append(self.rest_flag, np.uint8(wire.rest_pose_flag(self.skeleton.rest_pose)))
            self._add_subject_scores(len(self.subjects))
        track = sub.tracks.get(segment)
        if track is None:
            slot = self.store.add_slot()
            self._add_device_scores(slot)
            track = sub.tracks[segment] = DeviceTrack(subject, segment, slot)
            self.tracks.append(track)
            self.owner = np.append(self.owner, sub.index)
            self.online = np.append(self.online, False)
            self.active = np.append(self.active, False)
            self.generation = np.append(self.generation, 0)
            self.latest_t = np.append(self.latest_t, _NONE)
            self.latest_arrival = np.append(self.latest_arrival, np.nan)
            self.last_raw_t = np.append(self.last_raw_t, _NONE)
            self.horizon_us = np.append(self.horizon_us, self._horizon_us(wire.MAX_LEN.default))
            self.settled = np.append(self.settled, True)
            self._view = None
            if segment in _SEGMENT_INDEX:
                self.seg_slots[sub.index, _SEGMENT_INDEX[segment]] = slot
        return track

    def _horizon_us(self, max_len: int) -> int:
        return int(max_len * self.period_us + OVERDUE_GRACE_S * 1e6)

    def set_config(self, track: DeviceTrack, config: wire.DeviceConfig) -> None:
        """The settings the device reports it runs (its max_len sets its live horizon)."""
        track.config = config
        self.horizon_us[track.slot] = self._horizon_us(config.max_len)

    def set_rest_pose(self, subject: str, rest_pose: str) -> None:
        """The rest pose a subject's devices announce: its frames' skeleton and flag from now on."""
        sub = self.subjects[subject]
        if sub.rest_pose != rest_pose:
            sub.rest_pose = rest_pose
            self.rest_flag[sub.index] = wire.rest_pose_flag(rest_pose)

    def history_done(self, track: DeviceTrack) -> None:
        """The aggregator's history query for the track's stream has completed: it is settled."""
        track.history_done()
        self._view = None

    def set_online(self, track: DeviceTrack, online: bool) -> None:
        """The device's liveliness token appeared (True) or vanished (False)."""
        track.online = self.online[track.slot] = online
        self.active[track.slot] = online and not track.final
        self._view = None

    def _stream(self, track: DeviceTrack, stream: int, now: float) -> bool:
        state = track.check_stream(stream)
        if state == "new":
            slot = track.slot
            self.store.reset(slot)
            self._reset_scores(slot)
            self._new_stream_calibration(slot)
            self.generation[slot] = track.generation
            self.latest_t[slot] = self.last_raw_t[slot] = _NONE
            self._unsettled.add(track)
            self._gappy.discard(track)
            for batch in track.take_held_raw():  # truth that came before the stream's first point
                self.add_raw(track, batch, now)
        return state != "stale"

    def add_point(self, track: DeviceTrack, p: wire.SegmentPoint, nbytes: int, now: float) -> bool:
        """A decoded segment point; False if dropped (counted on the track)."""
        self.advance_clock(now)
        if not self._stream(track, p.stream, now):
            return False
        slot = track.slot
        how = track.accept_point(p, nbytes, now, lambda t_us: self.store.contains(slot, t_us))
        if how is not None:
            self._first_sample(slot, p.seq, p.t_us)
        q, omega = self._corrected(slot, p.q, p.omega, p.t_us)
        if how == "append":
            forgotten = self.store.append(slot, p.t_us, q, omega)
            if forgotten:
                track.dropped["buffer_full"] += forgotten
            self.active[slot] = track.online and not track.final
            if track.gap_spans:
                self._gappy.add(track)
        elif how == "final":
            self.active[slot] = False
        elif how == "insert" and not self.store.insert(slot, p.t_us, q, omega):
            track.dropped["buffer_full"] += 1
        if how is None:
            return False
        self.latest_t[slot] = track.latest_t_us
        self.latest_arrival[slot] = track.latest_arrival
        self._view = None
        return True

    def add_raw(self, track: DeviceTrack, batch: wire.RawBatch, now: float) -> bool:
        """A decoded truth-tap batch; False if dropped (counted) or held until the first point of
        its stream arrives."""
        self.advance_clock(now)
        if not track.accept_raw(batch, now):
            return False
        self.last_raw_t[track.slot] = track.last_raw_t_us
        self.latest_t[track.slot] = track.latest_t_us
        self.latest_arrival[track.slot] = track.latest_arrival
        self._take_truth(track.slot, track.generation, batch)
        return True

    def advance_clock(self, now: float) -> None:
        """Advance the arrival clock; devices still in their history grace period may settle."""
        if now > self.clock:
            self.clock = now
            if self._unsettled:
                self._view = None

    # ------------------------------------------------------------------ frames

    def _device_view(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What frames and truth evaluation need of every device, computed once per change:
        (slots,) newest usable point time (_NONE: no points yet, or earlier points of its stream
        may still arrive), (subjects,) watermark (us; _NONE if no data) and (subjects, 10) bool
        stale segments (no device, offline, ended, or not settled: held and flagged)."""
        if self._view is not None:
            return self._view
        for track in list(self._unsettled):
            ok = self.settled[track.slot] = track.settled(self.clock)
            if ok and track.first_seq is not None:
                self._unsettled.discard(track)
        last = np.where(self.settled, self.store.last_t(), _NONE)
        slots = self.seg_slots
        have = slots >= 0
        last_s = np.where(have, last[np.maximum(slots, 0)], _NONE)
        have &= last_s != _NONE
        active = have & self.active[np.maximum(slots, 0)]
        big = np.iinfo(np.int64).max
        wm_active = np.where(active, last_s, big).min(axis=1, initial=big)
        wm_have = np.where(have, last_s, big).min(axis=1, initial=big)
        wm = np.where(active.any(axis=1), wm_active, np.where(have.any(axis=1), wm_have, _NONE))
        self._view = last, wm, ~active
        return self._view

    def exact_frames(self) -> tuple[list[Subject], wire.PoseFrames]:
        """Every exact frame that became final since the last call, per subject oldest first,
        and the subject of each."""
        _, wm, stale = self._device_view()
        subjects = list(self.subjects.values())
        for sub in subjects:  # a subject's first frame: where every device it has is covered,
            # once every one of them settled (its start in, or its history query answered: a
            # device whose history is still on its way would otherwise start the frames at its
            # live points), at the latest FIRST_FRAME_WAIT_S after it could first start
            if self.next_frame[sub.index] >= 0 or wm[sub.index] == _NONE:
                continue
            if sub.waiting_since is None:
                sub.waiting_since = self.clock
            if (all(self.settled[t.slot] for t in sub.tracks.values())
                    or self.clock - sub.waiting_since >= FIRST_FRAME_WAIT_S):
                ready = [t for t in sub.tracks.values() if self.settled[t.slot]] or sub.tracks.values()
                first = max(self.store.first_t(t.slot) or 0 for t in ready)
                self.next_frame[sub.index] = math.ceil(first / self.period_us)
        last_k = np.where(wm != _NONE, np.floor(wm / self.period_us), -1).astype(np.int64)
        count = np.where(self.next_frame >= 0, last_k - self.next_frame + 1, 0)
        behind = count > self.max_backlog
        if behind.any():  # far behind (e.g. a long outage): jump ahead, count what is skipped
            for i in np.flatnonzero(behind):
                subjects[i].skipped += int(count[i] - self.max_backlog)
            self.next_frame[behind] = last_k[behind] - self.max_backlog + 1
            count[behind] = self.max_backlog
        count = np.clip(count, 0, MAX_FRAMES_PER_CALL)
        total = int(count.sum())
        if total == 0:
            return [], wire.PoseFrames.empty(wire.KIND_EXACT)
        owner = np.repeat(np.arange(len(count)), count)
        k = self.next_frame[owner] + np.arange(total) - np.repeat(np.cumsum(count) - count, count)
        t_us = np.round(k * self.period_us).astype(np.int64)
        seq = self.exact_seq[owner] + (k - self.next_frame[owner])
        self.next_frame += count
        self.exact_seq += count

        slots = self.seg_slots[owner]                       # (F, 10)
        q = np.tile(IDENTITY, (total, len(SEGMENTS), 1))
        valid = slots >= 0
        q[valid] = self.store.interpolate(slots[valid], np.broadcast_to(t_us[:, None], slots.shape)[valid])
        last = self.store.last_t()
        rows = np.maximum(slots, 0)
        beyond = valid & (last[rows] < t_us[:, None])
        before = valid & (self.store.n[rows] > 0) & (self.store.t[rows, 0] > t_us[:, None])
        lacking = (stale[owner] & beyond) | before | ~valid
        missing = lacking.any(axis=1)
        gap = np.zeros(slots.shape, bool)  # segments inside a span of their device's lost points
        for track in self._gappy:
            mine = owner == self.owner[track.slot]
            if mine.any():
                gap[mine] |= (slots[mine] == track.slot) & np.array(track.in_gap(t_us[mine]), bool)[:, None]
        rest = self.rest_flag[owner]
        flags = np.where(missing, wire.FRAME_MISSING, 0) | np.where(gap.any(axis=1), wire.FRAME_GAP, 0) | rest
        per_subject = np.bincount(owner, minlength=len(subjects))
        for i in np.flatnonzero(per_subject):
            subjects[i].frames += int(per_subject[i])
        self._score_later(owner, t_us, q, lacking | gap)
        return [subjects[i] for i in owner], wire.PoseFrames(seq, t_us, wire.KIND_EXACT, flags, q,
                                                             self.skeleton.positions(q, rest != 0))

    def _live_now(self, has_points: np.ndarray, now: float | None) -> np.ndarray:
        """(subjects,) each subject's device time "now" (the rule of frames.FrameBuilder._live_now,
        subject by subject): the clock plus the largest (newest device time - its arrival) of its
        devices, kept and eased down at most LIVE_EASE; at least its newest device time, after its
        previous live frame."""
        elapsed = 0.0 if self.live_clock is None or now is None else max(now - self.live_clock, 0.0)
        self.live_clock = now if now is not None else self.live_clock
        latest = np.full(len(self.seg_slots), _NONE)
        for i, slots in enumerate(self.seg_slots):
            mine = [int(s) for s, has in zip(slots, has_points[i]) if has]
            if not mine:
                continue
            newest = max(int(self.latest_t[s]) for s in mine)
            offset = max((float(self.latest_t[s]) - float(self.latest_arrival[s]) * 1e6 for s in mine
                          if math.isfinite(self.latest_arrival[s])), default=-math.inf)
            if i in self.live_offset and not offset > self.live_offset[i] - LIVE_EASE * elapsed * 1e6:
                offset = self.live_offset[i] - LIVE_EASE * elapsed * 1e6
            if math.isfinite(offset):
                self.live_offset[i] = offset
            t = newest if now is None else round(now * 1e6 + self.live_offset.get(i, 0.0))
            latest[i] = max(t, newest, self.live_t.get(i, _NONE) + 1)
            self.live_t[i] = int(latest[i])
        return latest

    def live_frames(self, now: float | None = None, wall: float | None = None) -> tuple[list[Subject], wire.PoseFrames]:
        """One frame per subject at its device time "now": the newest device time of its devices,
        each advanced by the arrival clock ``now`` (s) since it arrived. Every segment is exact
        where a point at or after that time is known, else predicted from its newest point (an
        offline or ended device, or one silent for longer than its horizon, OVERDUE_GRACE_S, is
        held at its newest point, frame flagged MISSING). ``wall`` (s since the epoch, the
        publication time): each device of a frame records ``wall`` - frame time as its live
        latency (ms)."""
        slots = self.seg_slots
        valid = slots >= 0
        rows = np.maximum(slots, 0)
        has_points = valid & (self.store.n[rows] > 0)
        latest = self._live_now(has_points, now)
        index = np.flatnonzero(latest != _NONE)
        if len(index) == 0:
            return [], wire.PoseFrames.empty(wire.KIND_LIVE)
        t_us, slots, valid, has_points = latest[index], slots[index], valid[index], has_points[index]
        at = np.broadcast_to(t_us[:, None], slots.shape)[valid]
        last_t = self.store.last_t()[slots[valid]]
        overdue = np.zeros(slots.shape, bool)
        since = np.where(has_points[valid], at - np.maximum(last_t, 0), 0)
        overdue[valid] = since > self.horizon_us[slots[valid]]  # silent too long: no guess
        held = ~self.active[slots[valid]] | overdue[valid]  # offline, ended or overdue: held
        at = np.where(held, np.minimum(at, last_t), at)
        q = np.tile(IDENTITY, (len(index), len(SEGMENTS), 1))
        q[valid] = self.store.live(slots[valid], at)
        missing = (~valid | ~self.online[np.maximum(slots, 0)] | overdue).any(axis=1)
        seq = self.live_seq[index].copy()
        self.live_seq[index] += 1
        if wall is not None:
            f, s = np.nonzero(has_points)
            self.latency.add(slots[f, s], (wall * 1e6 - t_us[f]) / 1e3)
        subjects = list(self.subjects.values())
        rest = self.rest_flag[index]
        return [subjects[i] for i in index], wire.PoseFrames(seq, t_us, wire.KIND_LIVE,
                                                             np.where(missing, wire.FRAME_MISSING, 0) | rest, q,
                                                             self.skeleton.positions(q, rest != 0))

    def prune(self) -> None:
        """Let every row forget points no frame and no waiting truth sample needs."""
        nf = self.next_frame[self.owner]
        keep = np.where(nf >= 0, np.floor(nf * self.period_us), np.iinfo(np.int64).min).astype(np.int64)
        frame_keep = keep.copy()
        keep = np.where(self.last_raw_t != _NONE, np.minimum(keep, self.last_raw_t), keep)  # truth still to come
        keep = np.minimum(keep, self.truth.oldest(self.store.size))
        keep = self._calibration_keep(keep)
        self.store.prune(keep)
        self._prune_reference(frame_keep)

    # ------------------------------------------------------------------ figures

    def device_stats(self, sub: Subject, now: float) -> list[dict]:
        tracks = [sub.tracks[name] for name in sorted(sub.tracks)]
        slots = np.array([t.slot for t in tracks], np.int64)
        aad, mx, p99 = self.exact.summary(slots, (0.99,))
        live, live_max, live_p50, live_p99 = self.live.summary(slots, (0.5, 0.99))
        _, _, lat_p50, lat_p99 = self.latency.summary(slots, (0.5, 0.99))
        count = self.exact.count[slots]
        aad_all = np.where(count > 0, self.exact.total[slots] / np.maximum(count, 1), np.nan)
        return [t.stats(now, (float(aad[i]), float(p99[i]), float(mx[i]), float(live[i]), float(aad_all[i]),
                              int(count[i])),
                        {"live_p50_deg": float(live_p50[i]), "live_p99_deg": float(live_p99[i]),
                         "live_max_deg": float(live_max[i]), "live_latency_p50_ms": float(lat_p50[i]),
                         "live_latency_p99_ms": float(lat_p99[i])} | self.calibration_figures(t.slot))
                for i, t in enumerate(tracks)]

    def watermark(self, sub: Subject) -> int | None:
        wm = self._device_view()[1]
        return None if wm[sub.index] == _NONE else int(wm[sub.index])
