"""Full-body frames of every subject from the devices' segment points (DESIGN section 4),
computed for all subjects at once.

:class:`Fusion` keeps every device's track (:mod:`.track`), its points (:mod:`.store`) and
columns (:mod:`.devices`), and holds four parts with their own state: the frame builder
(:mod:`.frames`), the scoring against the truth tap (:mod:`.scoring`), the calibrations
(:mod:`.calibrating`) and the heading corrections (:mod:`.heading`). Points and truth batches
come a drain's worth at a time: those that simply follow their device's stream are taken in for
all devices at once, the others checked one by one in arrival order; then they are corrected
(calibration) and stored in one go. A point's correction before it is stored (its calibration)
is :meth:`_corrected`; a correction that keeps changing as it is learnt (the heading held by the
joints) is applied where the points are read for frames and truth errors instead, so that what
is stored stays what it learns from (:mod:`.heading`).
"""
from __future__ import annotations

import itertools
import operator
import time
from collections.abc import Callable

import numpy as np

from limbstream import wire
from limbstream.body import PAPER10, Body, Layout
from limbstream.skeleton import Skeleton
from limbstream.services.aggregator.calibrating import CalibrationRequest, Calibrating
from limbstream.services.aggregator.devices import NO_TIME, DeviceTable
from limbstream.services.aggregator.frames import OVERDUE_GRACE_S, DeviceView, FrameBatch, FrameBuilder
from limbstream.services.aggregator.heading import HeadingStage
from limbstream.services.aggregator.layouts import SubjectLayouts
from limbstream.services.aggregator.scoring import Scoring
from limbstream.services.aggregator.store import PointStore
from limbstream.services.aggregator.track import NUMBERS as TRACK_NUMBERS
from limbstream.services.aggregator.track import TEXTS as TRACK_TEXTS
from limbstream.services.aggregator.track import MAX_T_US, DeviceTrack, stream_figures

_TRACK, _SLOT = operator.itemgetter(0), operator.attrgetter("slot")  # (track, row) -> track -> its slot


class Subject:
    """A subject's devices (by segment), its layout and its first frame's wait."""

    def __init__(self, name: str, index: int):
        self.name, self.index = name, index
        self.tracks: dict[str, DeviceTrack] = {}
        self.layout: Layout = PAPER10  # its frames' (:mod:`.layouts`)
        self.announced = False  # its layout is the one its devices' status names (else: of its devices' segments)
        self.rest_pose: str | None = None  # as its devices announce it (None: not yet heard)
        self.body: Body | None = None  # its wearer's dimensions as its devices announce them (None: the default)
        self.waiting_since: float | None = None  # arrival clock (s) when its first frame could start


class Fusion:
    """Tracks, stores and frames of all subjects of one aggregator.

    Parameters
    ----------
    rate : exact frame rate, Hz.
    skeleton : forward-kinematics model for the joint positions.
    capacity : segment points kept per device (history on joining + what frames still need).
    error_window : values in each device's error and latency windows.
    max_backlog_s : frames further behind than this are skipped (counted) instead of built.
    calibrate_on_start, calibration_file : :class:`~.calibrating.Calibrating`'s.
    heading_correction : correct the heading of each calibrated device by the joints (:mod:`.heading`).
    """

    def __init__(self, rate: float, skeleton: Skeleton, capacity: int = 1024, error_window: int = 3000,
                 max_backlog_s: float = 60.0, calibrate_on_start: bool = False, calibration_file: str = "",
                 heading_correction: bool = True):
        self.period_us = 1e6 / rate
        self.skeleton = skeleton
        self.store = PointStore(capacity)
        self.table = DeviceTable()
        self.frames = FrameBuilder(self.period_us, skeleton, int(max_backlog_s * rate))
        self.scoring = Scoring(self.store, error_window)
        self.calibrating = Calibrating(self.store, calibrate_on_start, calibration_file)
        self.heading = HeadingStage(heading_correction, rate)
        self.layouts = SubjectLayouts(self.table, self.frames, self.heading, self.scoring)
        self.scoring.turns = self.heading.turns
        self.scoring.own_correction = self.calibrating.correct
        self.subjects: dict[str, Subject] = {}
        self.tracks: list[DeviceTrack] = []  # by slot
        self.clock = 0.0  # newest arrival time seen (s): the "now" of the history grace period
        self._unsettled: set[DeviceTrack] = set()
        self._gappy: set[DeviceTrack] = set()  # tracks with lost points (frames in those spans: GAP)
        self._view: DeviceView | None = None

    # ------------------------------------------------------------------ devices

    def track(self, subject: str, segment: str) -> DeviceTrack:
        """The track of a device, created (with its rows) on first sight."""
        sub = self.subjects.get(subject)
        if sub is None:
            sub = self.subjects[subject] = Subject(subject, self.table.add_subject())
            self.frames.add_subject(wire.rest_pose_flag(self.skeleton.rest_pose))
            self.scoring.add_subject(len(self.subjects))
            self.heading.add_subject()
            self.layouts.set_layout(sub, PAPER10)
        track = sub.tracks.get(segment)
        if track is None:
            slot = self.store.add_slot()
            if self.table.add_device(sub.index, self._horizon_us(int(wire.MAX_LEN.default))) != slot:
                raise RuntimeError("device table and point store out of step")
            self.scoring.add_device(slot)
            self.heading.add_device()
            track = sub.tracks[segment] = DeviceTrack(subject, segment, slot, self.table)
            self.tracks.append(track)
            self.layouts.add_device(sub, track)
            self._view = None
        return track

    def _horizon_us(self, max_len: int) -> int:
        return int(max_len * self.period_us + OVERDUE_GRACE_S * 1e6)

    def set_config(self, track: DeviceTrack, config: wire.DeviceConfig) -> None:
        """The settings the device reports it runs (its max_len sets its live horizon)."""
        track.config = config
        self.table.horizon_us[track.slot] = self._horizon_us(config.max_len)

    def set_rest_pose(self, subject: str, rest_pose: str) -> None:
        """The rest pose a subject's devices announce: its frames' skeleton and flag from now on."""
        sub = self.subjects[subject]
        if sub.rest_pose != rest_pose:
            sub.rest_pose = rest_pose
            self.frames.rest_flag[sub.index] = wire.rest_pose_flag(rest_pose)

    def set_body(self, track: DeviceTrack, body: Body | None, refused: str | None = None) -> None:
        """The body a device's status announces (SubjectLayouts.set_body)."""
        self.layouts.set_body(self.subjects[track.subject], track, body, refused)
        self._view = None

    def history_done(self, track: DeviceTrack) -> None:
        """The aggregator's history query for the track's stream has completed: it is settled."""
        track.history_done()
        self._view = None

    def set_online(self, track: DeviceTrack, online: bool) -> None:
        """The device's liveliness token appeared (True) or vanished (False)."""
        track.online = online
        self.table.active[track.slot] = online and not track.final
        self._view = None

    def _new_stream(self, track: DeviceTrack, now: float) -> None:
        """The track's device began a new stream: its rows start over."""
        slot = track.slot
        self.store.reset(slot)
        self.scoring.reset(slot)
        self.heading.reset(self.subjects[track.subject].index, track.segment, slot, False, None)
        if self.calibrating.new_stream(track):  # a calibration of this very stream, kept from before
            self._calibrations_changed([track], made_now=False)
        self._unsettled.add(track)
        self._gappy.discard(track)
        for batch in track.take_held_raw():  # truth that came before the stream's first point
            self.add_raw(track, batch, now)

    def add_point(self, track: DeviceTrack, p: wire.SegmentPoint, nbytes: int, now: float) -> bool:
        """One decoded segment point; False if dropped (counted on the track)."""
        return self.add_points([(track, 0)], wire.PointColumns.of([p], [nbytes]), now) == 1

    def add_points(self, items: list[tuple[DeviceTrack, int]], points: wire.PointColumns, now: float,
                   taken: Callable[[DeviceTrack, int], None] | None = None,
                   gapped: Callable[[DeviceTrack, int, int], None] | None = None) -> int:
        """The valid points of one drain, in arrival order: (track, row of ``points``) each.
        The usual ones (:meth:`_usual`) are taken in all at once from the devices' columns; the
        others one by one by the full rules (:meth:`_accept`). Those kept are corrected
        (calibration) and stored in one go. ``taken(track, row)`` is called, at once, for each
        point taken in of a stream whose history is not settled yet (``DeviceTrack.history``
        "none": it may want its start); ``gapped(track, row, points)`` for each point taken in after a
        gap of that many points the device's cache may still hold (``DeviceTrack.holes``). Returns how
        many were taken in."""
        self.advance_clock(now)
        items, slots = self._placed(items, "segment_not_in_layout")
        if not items:
            return 0
        rows = np.fromiter((i for _, i in items), np.int64, len(items))
        fast = self._usual(slots, rows, points)
        self._take_usual(slots[fast], rows[fast], points, now)
        self._store_rows(slots[fast], rows[fast], points)
        appended: dict[int, list[int]] = {}
        stream, seq, index, t_us, flags, nbytes = (getattr(points, name).tolist() for name in
                                                   ("stream", "seq", "index", "t_us", "flags", "nbytes"))
        kept = slots[fast].tolist()
        for j in np.flatnonzero(~fast).tolist():
            track, i = items[j]
            last_gap = track.gap_spans[-1] if track.gap_spans else None
            if self._accept(track, i, stream, seq, index, t_us, flags, nbytes, now, appended, points):
                kept.append(track.slot)
                if taken is not None and track.history == "none":  # (a stream that may want its start)
                    taken(track, i)
                if gapped is not None and track.gap_spans and (gap := track.gap_spans[-1]) != last_gap and gap in track.holes:
                    gapped(track, i, len(track.holes[gap]))
        self._store(appended, points)
        table = self.table
        table.active[kept] = table.online[kept] & ~table.final[kept]
        self._view = None
        return len(kept)

    def _placed(self, items: list[tuple[DeviceTrack, int]], reason: str) -> tuple[list[tuple[DeviceTrack, int]], np.ndarray]:
        """The ``items`` of devices placed in their subject's layout, and their slots (k,); each of
        the others is counted on its device as ``reason`` (:mod:`.layouts`)."""
        slots = np.fromiter(map(_SLOT, map(_TRACK, items)), np.int64, len(items))
        placed = self.table.placed[slots]
        if placed.all():
            return items, slots
        for j in np.flatnonzero(~placed).tolist():
            items[j][0].dropped[reason] += 1
        return [item for item, ok in zip(items, placed.tolist()) if ok], slots[placed]

    def _usual(self, slots: np.ndarray, rows: np.ndarray, points: wire.PointColumns) -> np.ndarray:
        """(P,) which points are the usual case (DeviceTrack.accept_point appends them without a
        second look): each device's leading run in the drain of points that are the next of its
        current stream, later in time and index than the one before, without flags, of a stream
        that wants no history query."""
        table = self.table
        order = np.argsort(slots, kind="stable")  # each device's points together, in arrival order
        s, r = slots[order], rows[order]
        seq, t, index = points.seq[r], points.t_us[r], points.index[r]
        first = np.ones(len(s), bool)
        first[1:] = s[1:] != s[:-1]
        before = np.roll(np.arange(len(s)), 1)  # the point before in the same device's run
        next_seq = np.where(first, table.next_seq[s], seq[before] + 1)
        last_t = np.where(first, table.last_t[s], t[before])
        last_index = np.where(first, table.last_index[s], index[before])
        step = ((points.stream[r] == table.stream[s]) & (seq == next_seq) & (points.flags[r] == 0)
                & (last_t != NO_TIME) & (last_t < t) & (t < MAX_T_US) & (last_index < index)
                & ((table.history[s] != 0) | (table.first_seq[s] == 0)))
        run = np.flatnonzero(first)
        stop = np.minimum.reduceat(np.where(step, len(s), np.arange(len(s))), run)  # each run's first misfit
        usual = np.empty(len(s), bool)
        usual[order] = np.arange(len(s)) < np.repeat(stop, np.diff(np.append(run, len(s))))
        return usual

    def _take_usual(self, slots: np.ndarray, rows: np.ndarray, points: wire.PointColumns, now: float) -> None:
        """Take the usual points ``rows`` of devices ``slots`` in (in arrival order): their devices'
        columns as DeviceTrack.accept_point leaves them after such points."""
        if len(slots) == 0:
            return
        table = self.table
        devices, newest, count = np.unique(slots[::-1], return_index=True, return_counts=True)
        last = rows[len(rows) - 1 - newest]  # each device's newest point
        t = points.t_us[last]
        table.next_seq[devices] = points.seq[last] + 1
        table.last_t[devices], table.last_index[devices] = t, points.index[last]
        table.final[devices] = False
        table.points[devices] += count
        later = t >= table.latest_t[devices]
        table.latest_t[devices[later]] = t[later]
        table.latest_arrival[devices[later]] = now
        nbytes = np.bincount(slots, points.nbytes[rows], minlength=len(table))[devices].astype(np.int64)
        table.arrivals.add(devices, now, count, nbytes)

    def _accept(self, track: DeviceTrack, i: int, stream: list, seq: list, index: list, t_us: list, flags: list,
                nbytes: list, now: float, appended: dict[int, list[int]], points: wire.PointColumns) -> bool:
        """Point ``i`` (its fields: the columns as lists) by the full rules (a new stream, the
        start of a stream, gaps, duplicates, time going back, the stream's end, an earlier point
        arriving late); True if it is taken in. ``appended``: the rows of the points taken in so far
        by device slot, still to store (the device's own are stored before its row changes)."""
        state = track.check_stream(stream[i])
        if state == "stale":
            return False
        if state == "new":
            self._store({track.slot: appended.pop(track.slot, [])}, points)
            self._new_stream(track, now)
        slot, gaps = track.slot, track.gaps
        how = track.accept_point(seq[i], index[i], t_us[i], flags[i], nbytes[i], now,
                                 lambda t: self.store.contains(slot, t))
        if how is None:
            return False
        self.calibrating.first_sample(slot, seq[i], t_us[i])
        if how == "append":
            appended.setdefault(slot, []).append(i)
            if track.gaps != gaps:
                self._gappy.add(track)
        elif how == "insert":  # an earlier point (the stream's start, a gap filled), in time order
            self._store({slot: appended.pop(slot, [])}, points)
            self._insert(track, points, i)
        return True

    def _corrected(self, slots: np.ndarray, rows: np.ndarray, points: wire.PointColumns) -> tuple[np.ndarray, ...]:
        """(times, orientations (P, 4), body rates (P, 3)) of ``points`` ``rows`` of devices
        ``slots``, as stored: corrected where the device is calibrated (and by every later
        correction a device gets before fusion)."""
        t_us = points.t_us[rows]
        q, w = points.q[rows].astype(np.float64), points.omega[rows].astype(np.float64)
        self.calibrating.correct(slots, t_us, q, w)
        return t_us, q, w

    def _store(self, appended: dict[int, list[int]], points: wire.PointColumns) -> None:
        """Store the points ``appended`` (their rows by device slot, in order) and forget them."""
        if any(appended.values()):
            slots = np.repeat(np.fromiter(appended, np.int64, len(appended)), [len(r) for r in appended.values()])
            self._store_rows(slots, np.fromiter(itertools.chain.from_iterable(appended.values()), np.int64, len(slots)),
                             points)
        appended.clear()

    def _store_rows(self, slots: np.ndarray, rows: np.ndarray, points: wire.PointColumns) -> None:
        """Store points ``rows`` (P,) of ``points`` in the rows of devices ``slots`` (P,), in order."""
        if len(slots):
            t_us, q, w = self._corrected(slots, rows, points)
            for slot, forgotten in self.store.append_many(slots, t_us, q, w).items():
                self.tracks[slot].dropped["buffer_full"] += forgotten

    def _insert(self, track: DeviceTrack, points: wire.PointColumns, i: int) -> None:
        """Store an earlier point of a stream's start in time order (counted if the row is full)."""
        t_us, q, w = self._corrected(np.array([track.slot]), np.array([i]), points)
        if not self.store.insert(track.slot, int(t_us[0]), q[0], w[0]):
            track.dropped["buffer_full"] += 1

    def add_raw(self, track: DeviceTrack, batch: wire.RawBatch, now: float) -> bool:
        """A decoded truth-tap batch; False if dropped (counted) or held until the first point of
        its stream arrives."""
        self.advance_clock(now)
        taken = track.accept_raw(batch.stream, batch.first_index, len(batch.t_us), int(batch.t_us[0]),
                                 int(batch.t_us[-1]), now)
        if taken is None:
            track.hold_raw(batch)
        if not taken:
            return False
        if self.calibrating.compares(track.slot):  # readings of a device being calibrated are not the segment's
            self.scoring.take_truth(track.slot, batch)
        return True

    def add_raws(self, items: list[tuple[DeviceTrack, int]], batches: wire.RawColumns, now: float) -> int:
        """The valid truth-tap batches of one drain, in arrival order: (track, row of ``batches``)
        each; the usual ones (of their device's current stream, in time range, one per device)
        taken in all at once from the devices' columns, the others one by one
        (DeviceTrack.accept_raw). Returns how many were taken in."""
        self.advance_clock(now)
        items, slots = self._placed(items, wire.device_reason("raw", "segment_not_in_layout"))
        if not items:
            return 0
        table = self.table
        rows = np.fromiter((i for _, i in items), np.int64, len(items))
        first, last = batches.start[rows], batches.start[rows] + batches.count[rows] - 1
        t_first, t_last = batches.t_us[first], batches.t_us[last]
        fast = ((np.bincount(slots, minlength=len(table))[slots] == 1) & (table.stream[slots] == batches.stream[rows])
                & (0 <= t_first) & (t_first <= t_last) & (t_last < MAX_T_US))
        s = slots[fast]
        table.last_raw_index[s] = np.maximum(table.last_raw_index[s], batches.first_index[rows[fast]] + batches.count[rows[fast]] - 1)
        table.last_raw_t[s] = np.maximum(np.where(table.last_raw_t[s] == NO_TIME, 0, table.last_raw_t[s]), t_last[fast])
        later = (table.latest_t[s] == NO_TIME) | (t_last[fast] >= table.latest_t[s])
        table.latest_t[s[later]], table.latest_arrival[s[later]] = t_last[fast][later], now
        taken = fast.copy()
        for j in np.flatnonzero(~fast).tolist():
            track, i = items[j]
            ok = track.accept_raw(int(batches.stream[i]), int(batches.first_index[i]), int(batches.count[i]),
                                  int(t_first[j]), int(t_last[j]), now)
            if ok is None:
                track.hold_raw(batches.batch(i))
            taken[j] = bool(ok)
        compared = taken if not self.calibrating.on_start else taken & np.fromiter(
            (self.calibrating.compares(int(slot)) for slot in slots), bool, len(slots))
        if compared.any():  # readings of a device being calibrated are not the segment's
            self.scoring.take_truths(slots[compared], batches, rows[compared])
        return int(taken.sum())

    def advance_clock(self, now: float) -> None:
        """Advance the arrival clock; devices still in their history grace period may settle."""
        if now > self.clock:
            self.clock = now
            if self._unsettled:
                self._view = None

    # ------------------------------------------------------------------ frames

    def device_view(self) -> DeviceView:
        """What frames and truth evaluation need of every device (:class:`~.frames.DeviceView`),
        computed once per change."""
        if self._view is not None:
            return self._view
        table = self.table
        for track in list(self._unsettled):
            ok = table.settled[track.slot] = track.settled(self.clock)
            if ok and track.first_seq is not None:
                self._unsettled.discard(track)
        last = self.store.last_t()
        usable = np.where(table.settled, last, NO_TIME)
        slots = table.seg_slots
        have = slots >= 0
        rows = np.maximum(slots, 0)
        last_s = np.where(have, usable[rows], NO_TIME)
        have &= last_s != NO_TIME
        active = have & table.active[rows]
        big = np.iinfo(np.int64).max
        wm_active = np.where(active, last_s, big).min(axis=1, initial=big)
        wm_have = np.where(have, last_s, big).min(axis=1, initial=big)
        wm = np.where(active.any(axis=1), wm_active, np.where(have.any(axis=1), wm_have, NO_TIME))
        self._view = DeviceView(usable, last, wm, ~active)
        return self._view

    def tick(self, live: bool, now: float | None = None, wall: float | None = None) -> FrameBatch:
        """One tick's work on the points taken in: calibrations due, truth evaluation, every exact
        frame that became final (per subject oldest first) and, if ``live``, one live frame per
        subject at the arrival clock ``now`` (s; default: the newest arrival), published at
        ``wall`` (s since the epoch: each device of a live frame records ``wall`` - frame time
        as its live latency, ms)."""
        made = self.calibrating.calibrate_ready(self.tracks, self.clock)
        if made:
            self._calibrations_changed(made)
        self.evaluate_truth()
        view = self.device_view()
        subjects = list(self.subjects.values())
        self.frames.start(subjects, view, self.table, self.store, self.clock)
        owner, t_us, seq = self.frames.plan_exact(view.watermark)
        flags, lacking, lost = self.frames.exact_flags(owner, t_us, view, self.table, self.store, self._gappy)
        planned = self.frames.plan_live(view, self.table, self.store, self.clock if now is None else now) if live else None
        heading = self.heading if self.heading.active else None
        batch = self.frames.build(self.store, self.table, (owner, t_us, seq, flags, lacking), planned,
                                  None if heading is None else heading.correct)
        if heading is not None:
            heading.take_frames(owner, t_us, batch.exact_q, self.table.seg_slots, view.stale, self.frames.rest_flag)
        self.scoring.score_later(owner, t_us, batch.exact_q, self.table.seg_slots[owner], lacking | lost)
        self.scoring.evaluate_frames(self.table.seg_slots)
        if planned is not None and wall is not None:
            index, l_t, _, _, l_slots, _, has_points, _ = planned
            f, s = np.nonzero(has_points)
            self.scoring.add_latency(index, (wall * 1e6 - l_t) / 1e3, l_slots[f, s], index[f])
        return batch

    def evaluate_truth(self) -> None:
        """Score the truth samples whose reconstruction became final (counting those dropped)."""
        overflow, early = self.scoring.evaluate_truth(self.device_view().usable_t)
        for slot in overflow:
            self.tracks[slot].dropped["raw_overflow"] += 1
        for slot in early:
            self.tracks[slot].dropped["raw_before_first_point"] += 1

    def prune(self) -> None:
        """Let every row forget points no frame and no waiting truth sample needs."""
        table = self.table
        nf = self.frames.next_frame[table.owner]
        keep = np.where(nf >= 0, np.floor(nf * self.period_us), np.iinfo(np.int64).min).astype(np.int64)
        frame_keep = keep.copy()
        keep = np.where(table.last_raw_t != NO_TIME, np.minimum(keep, table.last_raw_t), keep)  # truth still to come
        keep = np.minimum(keep, self.scoring.truth_keep(self.store.size))
        keep = self.calibrating.keep(keep)
        self.store.prune(keep)
        self.scoring.prune_reference(frame_keep, table.owner, len(self.subjects))

    # ------------------------------------------------------------------ calibration

    def _calibrations_changed(self, tracks: list[DeviceTrack], made_now: bool = True) -> None:
        """Devices' calibrations changed (``made_now``: just made, not kept from before): their
        heading corrections start again (:mod:`.heading`); a subject whose devices are all
        calibrated has its facing fitted again (:mod:`.scoring`); the view changes with the
        stored points."""
        wall = time.time()
        for track in tracks:
            sub = self.subjects[track.subject]
            made_at = self.calibrating.calibrated_at.get(track.slot)
            age = 0.0 if made_now else None if made_at is None else wall - made_at
            self.heading.reset(sub.index, track.segment, track.slot, track.slot in self.calibrating.calibrations, age)
            if all(t.slot in self.calibrating.calibrations for t in sub.tracks.values()):
                self.scoring.refit_facing(sub.index)
        self._view = None

    def start_request(self, subject: str, pose: str, wall: float) -> CalibrationRequest | str:
        """Begin a calibration of ``subject``'s devices from ``pose`` (Calibrating.start_request)."""
        sub = self.subjects.get(subject)
        return self.calibrating.start_request(subject, None if sub is None else sub.tracks, pose,
                                              self.table.latest_t, wall, None if sub is None else sub.layout)

    def finish_request(self, req: CalibrationRequest, wall: float) -> wire.CalibrateAnswer | None:
        """The request's answer once its pose hold is complete (None: not yet)."""
        answer, made = self.calibrating.finish_request(req, wall)
        if made:
            self._calibrations_changed(made)
        return answer

    # ------------------------------------------------------------------ figures

    def stats_table(self, subjects: list[Subject], now: float) -> tuple[list[int], np.ndarray, dict[str, list]]:
        """The device columns of the stats messages of ``subjects``, their devices by segment name,
        one subject after the other: (devices of each subject, numbers (N, K) float64 in the order
        of wire.STATS_NUMBERS (NaN: null), texts {wire.STATS_TEXTS field: N values})."""
        tracks = [[sub.tracks[name] for name in sorted(sub.tracks)] for sub in subjects]
        flat = [t for mine in tracks for t in mine]
        slots = np.array([t.slot for t in flat], np.int64)
        own = [t.stats() for t in flat]
        track_numbers = np.array([numbers for numbers, _ in own], np.float64).reshape(len(flat), len(TRACK_NUMBERS))
        columns = {name: track_numbers[:, j] for j, name in enumerate(TRACK_NUMBERS)}
        columns |= stream_figures(self.table, slots, now) | self.scoring.device_figures(slots, self.table.owner[slots])
        texts = {name: [t[j] for _, t in own] for j, name in enumerate(TRACK_TEXTS)}
        for name, values in self.calibrating.figures(slots.tolist()).items():
            (texts if name in wire.STATS_TEXTS else columns)[name] = values
        columns |= self.heading.figures(slots, self.table.owner[slots], [t.segment for t in flat])
        numbers = np.column_stack([np.asarray(columns[name], np.float64) for name in wire.STATS_NUMBERS])
        return [len(mine) for mine in tracks], numbers.reshape(len(flat), len(wire.STATS_NUMBERS)), texts

    def device_stats(self, subjects: list[Subject], now: float) -> list[list[dict]]:
        """The device entries of each subject's stats message, by segment name (:meth:`stats_table`
        as dicts)."""
        counts, numbers, texts = self.stats_table(subjects, now)
        entries = iter(wire.stats_devices(list(wire.STATS_NUMBERS), numbers.tolist(), texts))
        return [[next(entries) for _ in range(n)] for n in counts]

