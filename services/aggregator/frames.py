"""Full-body frames of every subject of a tick, built in one pass (DESIGN section 4).

Exact frames lie on a fixed grid (multiples of the output period in device time) and are
emitted once every active device of the subject has a segment point at or after the frame
time (the watermark), so the SLERP reconstruction in them is final. A device that is offline
or has ended its stream does not hold the watermark back; its segment is held at its last
point and the frame is flagged MISSING. Live frames: at each subject's device time "now" (the
newest device time seen, advanced by the arrival clock since it arrived), every segment exact
(SLERP) where a point at or after that time is known, else its newest point extrapolated with
the point's body rate (``quat.predict``: the prediction the device's live rule keeps within
``live_bound_deg``; a point without a rate is held). A subject's "now" is the clock plus its
live clock offset (device time minus arrival of its least delayed message, eased down at
LIVE_EASE): its live frames' times strictly increase.

A tick plans the exact frames that became final and the live frames due (who, when, which
device at which time, flags), reconstructs every segment of all of them in one
:meth:`PointStore.reconstruct` call and their joints in one forward-kinematics call: a
:class:`FrameBatch`. Work on whole frames of all subjects at once (joint angles from the live
frames, say) takes the batch before it is encoded (:data:`FrameStage`).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from limbstream import wire
from limbstream.body import PAPER10, Body, Layout
from limbstream.skeleton import Skeleton
from limbstream.wire import SEGMENTS
from limbstream.services.aggregator.devices import NO_TIME, DeviceTable
from limbstream.services.aggregator.rooting import Rooting
from limbstream.services.aggregator.store import PointStore
from limbstream.services.aggregator.track import DeviceTrack

MAX_FRAMES_PER_CALL = 500
"""Most exact frames one subject gets per call (catch-up proceeds over several ticks)."""
FIRST_FRAME_WAIT_S = 1.0
"""How long a subject's first exact frame waits, at most, for all of its devices to settle
(DeviceTrack.settled) after it could first start, seconds; then it starts from the settled
ones (a device whose stream keeps restarting must not hold the others back)."""
FIRST_POINT_REACH = 0.25
"""How far before a device's first point, in frame periods, its first point stands for it in
exact frames (held there, not flagged MISSING). The devices of a subject take their first
samples together, but each stamps its own on its own clock, and the clocks agree only to within
the sync's error (about 0.1 ms here; more before the sync has converged). Without a reach, a
frame time that fell between those stamps split the subject's frames: a running aggregator built
the frames up to it (the earliest stamp passed), and one restarted just then began the subject
after it (its first frame needs every device's first point), so a consumer lost that frame."""
LIVE_EASE = 0.1
"""How fast a subject's live clock offset may come down, s per s of the aggregator's clock: a
message that arrives later than the best one seen (transport delay, a stalled loop) lowers the
offset no faster than this, so live frame times never go back and advance at least 0.9 times as
fast as the clock (device clocks running at ``--speed 1``)."""
OVERDUE_GRACE_S = 0.25
"""A live frame extrapolates an active device's newest point for at most its max segment length
(``max_len`` samples at the frame rate: by then the device has sent its next point) plus this
much for transport; a device silent for longer is overdue: held at its newest point, frame
flagged MISSING."""


@dataclass(frozen=True)
class DeviceView:
    """What frames and truth evaluation need of every device at a tick: (slots,) newest usable
    point time (NO_TIME: no points yet, or earlier points of its stream may still arrive), (slots,)
    newest point time, (subjects,) watermark (us; NO_TIME if no data) and (subjects, C) bool stale
    segments (no device, offline, ended, or not settled: held and flagged)."""

    usable_t: np.ndarray
    last_t: np.ndarray
    watermark: np.ndarray
    stale: np.ndarray


@dataclass(frozen=True)
class FrameGroup:
    """One layout's frames of one kind in a tick: the subject index of each (``owner`` (F,)), the
    frames (in the layout's segments and joints; orientations float64 until encoded) and the
    segments each lacks (``missing`` (F, S) bool, the layout's order: no device, no data at the
    frame's time, or held: what sets a frame's MISSING flag)."""

    owner: np.ndarray
    frames: wire.PoseFrames
    missing: np.ndarray

    @classmethod
    def empty(cls, kind: int, layout: Layout) -> FrameGroup:
        return cls(np.zeros(0, np.int64), wire.PoseFrames.empty(kind, layout), np.zeros((0, len(layout.segments)), bool))


@dataclass(frozen=True)
class FrameBatch:
    """The frames of one tick. Every subject's exact frames (per subject oldest first) over the
    device table's segment columns (C): subject ``exact_owner`` (E,), time ``exact_t`` (E,) us,
    orientations ``exact_q`` (E, C, 4) float64 (identity where the subject has no device or its
    layout lacks the segment), segments lacking ``exact_lacking`` (E, C) (only ever those of the
    subject's layout); and the frames to publish, one :class:`FrameGroup` per layout and kind
    (``exact``, ``live``: paper10's first, a layout without frames left out)."""

    exact_owner: np.ndarray
    exact_t: np.ndarray
    exact_q: np.ndarray
    exact_lacking: np.ndarray
    exact: list[FrameGroup]
    live: list[FrameGroup]

    def group(self, kind: int, layout: Layout) -> FrameGroup:
        """The frames of ``kind`` (wire.KIND_EXACT, KIND_LIVE) of ``layout``'s subjects (none: empty)."""
        for g in self.live if kind == wire.KIND_LIVE else self.exact:
            if g.frames.layout == layout:
                return g
        return FrameGroup.empty(kind, layout)


Correction = Callable[[np.ndarray, np.ndarray, np.ndarray], None]
"""A per-device correction of reconstructed segments: (device slots (Q,), device times (Q,) us,
orientations (Q, 4) float64 to correct in place)."""

FrameStage = Callable[[FrameBatch], Iterable[tuple[str, str, bytes]]]
"""Work on a tick's frames, all subjects at once, before they are encoded (the aggregator's
``frame_stages``): returns messages to publish as (key, its ``zconfig.QOS`` kind, payload)."""


class FrameBuilder:
    """Per subject: the next exact frame (grid index, -1 before the first), the sequence numbers
    of both kinds, the rest-pose flag, its layout and the body its joints are drawn with, and the
    frames made and skipped.

    Parameters
    ----------
    period_us : exact frame period, us.
    skeleton : forward-kinematics model for the joint positions of paper10 subjects whose devices
        announce no body (``bodies``: those of the others; a subject of another layout without one
        is drawn with that layout's default body).
    max_backlog : frames further behind than this are skipped (counted) instead of built.
    """

    def __init__(self, period_us: float, skeleton: Skeleton, max_backlog: int):
        self.period_us, self.skeleton, self.max_backlog = period_us, skeleton, max_backlog
        self.next_frame = np.zeros(0, np.int64)
        self.exact_seq = np.zeros(0, np.int64)
        self.live_seq = np.zeros(0, np.int64)
        self.live_t = np.zeros(0, np.int64)          # newest live frame time, us (NO_TIME: none)
        self.live_offset = np.zeros(0, np.float64)   # device time - clock, us (NaN: none yet)
        self.live_missed = np.zeros(0, np.int64)     # live frame deadlines missed (counted by the loop)
        self._live_clock = math.nan                  # the clock of the last live plan, s
        self.rest_flag = np.zeros(0, np.uint8)
        self.body_code = np.zeros(0, np.int64)  # per subject: the body its devices announce, in ``bodies`` (-1: none)
        self.bodies: list[Body] = []  # the bodies announced, each once (subjects of one body share it)
        self.layouts: list[Layout] = [PAPER10]  # the layouts of the subjects, by code
        self.layout_cols = [np.arange(len(SEGMENTS))]  # by code: the table's columns of its segments (S,)
        self.layout_code = np.zeros(0, np.int64)  # per subject
        self._defaults: dict[Layout, Body] = {}  # the default body of each layout
        self.rooting = Rooting()  # each subject's root translation (docs/body.md, "Root translation")
        self.made = np.zeros(0, np.int64)     # exact frames per subject
        self.skipped = np.zeros(0, np.int64)  # frame times skipped per subject

    def add_subject(self, rest_flag: int) -> None:
        for name, value in (("next_frame", -1), ("exact_seq", 0), ("live_seq", 0), ("made", 0), ("skipped", 0),
                            ("live_t", NO_TIME), ("live_offset", math.nan), ("live_missed", 0)):
            setattr(self, name, np.append(getattr(self, name), value))
        self.rest_flag = np.append(self.rest_flag, np.uint8(rest_flag))
        self.body_code = np.append(self.body_code, -1)
        self.layout_code = np.append(self.layout_code, 0)

    def set_layout(self, subject: int, layout: Layout, cols: np.ndarray) -> None:
        """The subject's frames are of ``layout`` from now on, its segments the table's columns ``cols`` (S,)."""
        if layout not in self.layouts:
            self.layouts.append(layout)
            self.layout_cols.append(cols)
        self.layout_code[subject] = self.layouts.index(layout)

    def set_body(self, subject: int, body: Body | None) -> None:
        """The subject's frames are drawn with ``body`` from now on (None: ``skeleton`` for paper10,
        another layout's default body)."""
        if body is None:
            self.body_code[subject] = -1
            return
        code = next((i for i, b in enumerate(self.bodies) if b is body), None)
        if code is None:
            code = len(self.bodies)
            self.bodies.append(body)
        self.body_code[subject] = code

    def start(self, subjects: list, view: DeviceView, table: DeviceTable, store: PointStore, clock: float) -> None:
        """Fix the first frame of the subjects that can start: where every device they have is
        covered (from FIRST_POINT_REACH before its first point), once every one of them settled (its start in, or its history query answered: a
        device whose history is still on its way would otherwise start the frames at its live
        points), at the latest FIRST_FRAME_WAIT_S after it could first start."""
        for i in np.flatnonzero((self.next_frame < 0) & (view.watermark != NO_TIME)):
            sub = subjects[i]
            if sub.waiting_since is None:
                sub.waiting_since = clock
            tracks = [t for t in sub.tracks.values() if table.placed[t.slot]]  # (those its layout has)
            if all(table.settled[t.slot] for t in tracks) or clock - sub.waiting_since >= FIRST_FRAME_WAIT_S:
                ready = [t for t in tracks if table.settled[t.slot]] or tracks
                first = max(store.first_t(t.slot) or 0 for t in ready) - FIRST_POINT_REACH * self.period_us
                self.next_frame[i] = math.ceil(first / self.period_us)

    def plan_exact(self, watermark: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The exact frames final below each subject's ``watermark`` (subjects,) and not built yet:
        (subject index, time us, seq), each (E,), per subject oldest first; counted as made."""
        last_k = np.where(watermark != NO_TIME, np.floor(watermark / self.period_us), -1).astype(np.int64)
        count = np.where(self.next_frame >= 0, last_k - self.next_frame + 1, 0)
        behind = count > self.max_backlog
        if behind.any():  # far behind (e.g. a long outage): jump ahead, count what is skipped
            self.skipped[behind] += count[behind] - self.max_backlog
            self.next_frame[behind] = last_k[behind] - self.max_backlog + 1
            count[behind] = self.max_backlog
        count = np.clip(count, 0, MAX_FRAMES_PER_CALL)
        total = int(count.sum())
        if total == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
        owner = np.repeat(np.arange(len(count)), count)
        k = self.next_frame[owner] + np.arange(total) - np.repeat(np.cumsum(count) - count, count)
        t_us = np.round(k * self.period_us).astype(np.int64)
        seq = self.exact_seq[owner] + (k - self.next_frame[owner])
        self.next_frame += count
        self.exact_seq += count
        self.made += count
        return owner, t_us, seq

    def exact_flags(self, owner: np.ndarray, t_us: np.ndarray, view: DeviceView, table: DeviceTable,
                    store: PointStore, gappy: set[DeviceTrack]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(E,) flags of exact frames (subject ``owner``, time ``t_us``), (E, C) the segments
        of their layouts they lack and (E, C) the segments inside a span of their device's lost
        points: MISSING where a segment has no device, is held beyond a stale device's last
        point or lies before its first point's reach;
        GAP inside a span whose points were lost (``gappy``: the devices with such spans; one whose
        spans all end before its subject's frames is taken out: no frame to come is in them); the
        subject's rest pose."""
        slots = table.seg_slots[owner]                       # (E, C)
        valid = slots >= 0
        rows = np.maximum(slots, 0)
        beyond = valid & (view.last_t[rows] < t_us[:, None])
        before = valid & (store.n[rows] > 0) & (store.t[rows, 0] > t_us[:, None] + FIRST_POINT_REACH * self.period_us)
        lacking = ((view.stale[owner] & beyond) | before | ~valid) & table.in_layout[owner]
        missing = lacking.any(axis=1)
        gap = np.zeros(slots.shape, bool)
        tracks = list(gappy)
        subject = table.owner[np.array([t.slot for t in tracks], np.int64)]
        start, end = np.searchsorted(owner, subject), np.searchsorted(owner, subject, side="right")
        for track, a, b in zip(tracks, start.tolist(), end.tolist()):  # a subject's frames: one run of ``owner``
            if a == b:
                continue
            if not track.gap_spans or track.gap_spans[-1][1] <= t_us[a]:  # spans end in time order (or all filled)
                gappy.discard(track)
            else:
                gap[a:b] |= (slots[a:b] == track.slot) & track.in_gap(t_us[a:b])[:, None]
        return (np.where(missing, wire.FRAME_MISSING, 0) | np.where(gap.any(axis=1), wire.FRAME_GAP, 0)
                | self.rest_flag[owner], lacking, gap)

    def miss_live(self, deadlines: int) -> None:
        """``deadlines`` live frame deadlines passed without a frame (the loop was late): counted
        for every subject that has had live frames."""
        self.live_missed[self.live_seq > 0] += deadlines

    def _live_now(self, table: DeviceTable, rows: np.ndarray, has_points: np.ndarray, now: float) -> np.ndarray:
        """(subjects,) each subject's device time "now", us (NO_TIME: no data): the clock ``now``
        (s) plus its live clock offset, the largest of (newest device time - its arrival) over its
        devices, kept from tick to tick and eased down at most LIVE_EASE; never before its
        newest device time, never at or before its previous live frame."""
        latest = np.where(has_points, table.latest_t[rows], NO_TIME)
        newest = latest.max(axis=1, initial=NO_TIME)
        offset = np.nan_to_num(np.where(has_points, latest - table.latest_arrival[rows] * 1e6, -np.inf),
                               nan=-np.inf).max(axis=1, initial=-np.inf)
        elapsed = 0.0 if math.isnan(self._live_clock) else max(now - self._live_clock, 0.0)
        self._live_clock = now
        eased = self.live_offset - LIVE_EASE * elapsed * 1e6
        offset = np.where(np.isnan(eased) | (offset > eased), offset, eased)
        self.live_offset = np.where(np.isfinite(offset), offset, self.live_offset)
        t = np.round(now * 1e6 + np.nan_to_num(self.live_offset, nan=0.0, neginf=0.0))
        t = np.maximum(np.maximum(t, newest), self.live_t + 1).astype(np.int64)
        return np.where(newest != NO_TIME, t, NO_TIME)

    def plan_live(self, view: DeviceView, table: DeviceTable, store: PointStore,
                  now: float) -> tuple[np.ndarray, ...]:
        """The live frames due: one per subject with data at its device time "now"
        (:meth:`_live_now`, the arrival clock ``now`` in s). Returns (subject index (L,), time (L,)
        us, seq (L,), flags (L,), segment slots (L, C), each segment's query time (L, C) us,
        devices with points (L, C) bool, segments of its layout lacking (L, C) bool). A segment is held at its
        newest point (frame MISSING) where its device is offline or ended, or silent for longer
        than its horizon (OVERDUE_GRACE_S)."""
        slots = table.seg_slots
        valid = slots >= 0
        rows = np.maximum(slots, 0)
        has_points = valid & (store.n[rows] > 0)
        latest = self._live_now(table, rows, has_points, now)
        index = np.flatnonzero(latest != NO_TIME)
        t_us, slots, valid, has_points, rows = latest[index], slots[index], valid[index], has_points[index], rows[index]
        self.live_t[index] = t_us
        at = np.broadcast_to(t_us[:, None], slots.shape).copy()
        last_t = view.last_t[rows]
        since = np.where(has_points, at - np.maximum(last_t, 0), 0)
        overdue = valid & (since > table.horizon_us[rows])  # silent too long: no guess
        held = valid & (~table.active[rows] | overdue)       # offline, ended or overdue: held
        at[held] = np.minimum(at[held], last_t[held])
        mine = table.in_layout[index]
        lacking = (~valid | ~table.online[rows] | overdue) & mine
        seq = self.live_seq[index].copy()
        self.live_seq[index] += 1
        flags = np.where(lacking.any(axis=1), wire.FRAME_MISSING, 0) | self.rest_flag[index]
        return index, t_us, seq, flags, slots, at, has_points, (lacking | ~has_points) & mine

    def _default(self, layout: Layout) -> Body:
        """The default body of ``layout`` (drawn once)."""
        default = self._defaults.get(layout)
        if default is None:
            default = self._defaults[layout] = Body.default(layout)
        return default

    def drawn_with(self, owner: np.ndarray, layout: Layout) -> tuple[list[Body], np.ndarray]:
        """The bodies frames of ``layout``'s subjects ``owner`` (F,) are drawn with: a list and
        each frame's index in it (F,) (a subject without a body: the layout's default, the list's
        last)."""
        codes = self.body_code[owner]
        return [*self.bodies, self._default(layout)], np.where(codes >= 0, codes, len(self.bodies))

    def positions(self, q: np.ndarray, owner: np.ndarray, layout: Layout) -> np.ndarray:
        """(F, J, 3) float32 joint positions of frames ``q`` (F, S, 4) of ``layout``'s subjects
        ``owner`` (F,): each subject's by its body (where it has none: paper10's by the skeleton,
        another layout's by its default body), in its rest pose."""
        tpose = self.rest_flag[owner] != 0
        codes = self.body_code[owner]
        fallback = self.skeleton.positions if layout == PAPER10 else self._default(layout).positions
        drawn = np.unique(codes).tolist()  # the bodies drawn with (-1: the fallback), a few
        if len(drawn) == 1:
            return (fallback if drawn[0] < 0 else self.bodies[drawn[0]].positions)(q, tpose)
        joints = np.empty((len(owner), len(layout.joints), 3), np.float32)
        for code in drawn:
            rows = np.flatnonzero(codes == code)
            joints[rows] = (fallback if code < 0 else self.bodies[code].positions)(q[rows], tpose[rows])
        return joints

    def build(self, store: PointStore, table: DeviceTable, exact: tuple[np.ndarray, ...],
              live: tuple[np.ndarray, ...] | None, correct: Correction | None = None) -> FrameBatch:
        """Orientations and joints of the planned frames, one reconstruction for all and one forward
        kinematics per layout. ``exact``: (subject, time, seq, flags, segments lacking) of
        :meth:`plan_exact` and :meth:`exact_flags`; ``live``: :meth:`plan_live`, or None for no
        live frames; ``correct``: a correction of the reconstructed segments before the forward
        kinematics."""
        e_owner, e_t, e_seq, e_flags, e_missing = exact
        shape = (len(e_t), len(table.columns))
        slots, times, live_view = [table.seg_slots[e_owner]], [np.broadcast_to(e_t[:, None], shape)], [np.zeros(shape, bool)]
        l_owner = np.zeros(0, np.int64)
        l_seq = l_t = l_flags = l_owner
        l_missing = np.zeros((0, shape[1]), bool)
        if live is not None:
            l_owner, l_t, l_seq, l_flags, l_slots, l_at, _, l_missing = live
            slots.append(l_slots)
            times.append(l_at)
            live_view.append(np.ones(l_slots.shape, bool))
        all_slots, at, live_at = np.concatenate(slots), np.concatenate(times), np.concatenate(live_view)
        valid = all_slots >= 0
        whole = valid.all()  # (the usual: every column of every frame has a device; then no masks)
        asked, at, live_at = (a.reshape(-1) if whole else a[valid] for a in (all_slots, at, live_at))
        found = store.reconstruct(asked, at, live_at)
        if correct is not None:
            correct(asked, at, found)
        if whole:
            q = found.reshape(*all_slots.shape, 4)
        else:
            q = np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (*all_slots.shape, 1))
            q[valid] = found
        owner, n = np.concatenate([e_owner, l_owner]), len(e_t)
        codes = self.layout_code[owner]
        groups: tuple[list[FrameGroup], list[FrameGroup]] = ([], [])
        for code in np.unique(codes).tolist():  # paper10 (code 0) first
            layout, cols = self.layouts[code], self.layout_cols[code]
            rows = np.flatnonzero(codes == code)
            mine = q[rows][:, cols]
            joints = self.positions(mine, owner[rows], layout)
            e, k = rows < n, rows[rows >= n] - n
            r = rows[e]
            missing = np.concatenate([e_missing[r], l_missing[k]])[:, cols]
            bodies, which = self.drawn_with(owner[rows], layout)
            # one call for the layout's exact frames (they move the roots) and then its live ones
            root, contacts, flags = self.rooting.place(owner[rows], np.concatenate([e_t[r], l_t[k]]), mine, joints, layout,
                                                       bodies, which, e, missing)
            if len(r):
                groups[0].append(FrameGroup(e_owner[r], wire.PoseFrames(e_seq[r], e_t[r], wire.KIND_EXACT, e_flags[r] | flags[e],
                                                                        mine[e], joints[e], layout, root[e], contacts[e]),
                                            missing[e]))
            if len(k):
                groups[1].append(FrameGroup(l_owner[k], wire.PoseFrames(l_seq[k], l_t[k], wire.KIND_LIVE, l_flags[k] | flags[~e],
                                                                        mine[~e], joints[~e], layout, root[~e], contacts[~e]),
                                            missing[~e]))
        return FrameBatch(e_owner, e_t, q[:n], e_missing, *groups)
