"""Joint angles of every subject, from the frames of each tick, all subjects at once: the
aggregator's frame stage (:data:`.frames.FrameStage`) that publishes one joint-angle message
(:mod:`limbstream.wire.angles`) per live frame (per exact frame when the aggregator makes no
live frames), with that frame's kind, sequence number and time.

Which calibration a subject's angles rest on (``wire.ANGLE_BASES``) follows from its online
devices. A device calibrated by this aggregator is anatomical when its calibration holds the
mounting pose (``mounting``), else rest-calibrated; one that is not says what its orientations
are in its status (``wire.ORIENTATIONS``): its segment's own (``segments``), rest-calibrated
(``rest``: a recording calibrated on loading) or its sensor's (``uncalibrated``), or nothing yet
(``unknown``). The subject takes the weakest: no angles while a device is unknown or
uncalibrated; with rest-calibrated devices, the facing found from the hinges' motion
(:class:`limbstream.joints.HingeStats`, running sums over the frames since the subject's rest
calibration, per subject) undoes the heading of those devices' segments once a knee or an elbow
has moved enough (``functional``); until then no angles (``no_facing``).

A segment a frame lacks (no device, offline, no data yet: :attr:`.frames.FrameGroup.missing`)
gives its joints no angles (flag MISSING); an angle near gimbal lock is flagged GIMBAL.

Each subject's angles are those of its body layout (``wire.joint_angles(layout)``; its messages
name the layout, version 2): a tick's frames come one group per layout
(:class:`.frames.FrameGroup`, the layout's segments in its order), each group's angles in one pass. The facing from the
hinges is found for ``paper10`` subjects (its knees' and elbows' segments); rest-calibrated
devices of a subject of another layout give no angles (``no_facing``) until a mounting pose.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import numpy as np

from limbstream import joints, wire
from limbstream.body import PAPER10
from limbstream.services.aggregator.frames import FrameBatch
from limbstream.services.aggregator.fusion import Fusion

REFRESH_S = 0.5
"""How often the subjects' calibrations are looked at again, s (a device's status comes every few
seconds, a calibration once): the bases hold in between."""
FACING_S = 1.0
"""How often the facing of a subject with rest-calibrated devices is worked out from its hinge
sums again, s."""
FACING_FRAMES = 50
"""A hinge tells the facing only from this many frames on (1 s of live frames at 50 Hz)."""

_UNKNOWN, _UNCALIBRATED, _REST, _MOUNTING, _SEGMENTS, _NONE = range(6)
"""A device's level, weakest first (_NONE: no online device)."""
_OF_STATUS = np.array([_UNKNOWN] + [{"segments": _SEGMENTS, "rest": _REST, "sensors": _UNCALIBRATED}[o]
                                    for o in wire.ORIENTATIONS])
"""The level of what a device's status says (its ``orientations`` code + 1; 0: it has not said)."""
_BASIS_OF_LEVEL = np.array([wire.BASIS[name] for name in ("unknown", "uncalibrated", "no_facing", "mounting",
                                                          "segments")])
_VALID = np.array([b.valid for b in wire.ANGLE_BASES])


class JointStage:
    """The joint-angle frame stage of an aggregator's :class:`~.fusion.Fusion` (see the module
    docstring); call it with each tick's :class:`~.frames.FrameBatch`.

    Parameters
    ----------
    fusion : the aggregator's devices, calibrations and subjects.
    live : take the live frames (the aggregator makes them), else the exact frames.
    clock : the time source of the refreshes (monotonic seconds).
    layout_of : subject index -> its body layout (``limbstream.body.Layout``; None: ``paper10``);
        None: every subject's is ``paper10``.
    unheard : (keys by subject, subjects, their ``zconfig.QOS`` kind) -> the positions of those
        subjects whose key no subscriber matches now (the aggregator's
        :meth:`~.aggregator.Aggregator.unheard`): their angles are not worked out, unless their
        hinge sums need the frames (rest-calibrated devices); None: every subject's are.
    """

    def __init__(self, fusion: Fusion, live: bool = True, clock=time.monotonic,
                 layout_of: Callable[[int], object | None] | None = None,
                 unheard: Callable[[list[str], list[int], str], list[int]] | None = None):
        self.fusion, self.live, self.clock, self.layout_of, self.unheard = fusion, live, clock, layout_of, unheard
        self.layouts: list = []                       # per subject: its layout (None: paper10)
        self.basis = np.zeros(0, np.int64)            # (S,) wire.ANGLE_BASES code
        self.level = np.zeros(0, np.int64)            # (S,) the level of its weakest online device
        self.rest_segments = np.zeros((0, len(wire.SEGMENTS)), bool)  # (S, 10) rest-calibrated segments
        self.heading = np.zeros(0)                    # (S,) the facing the hinges told, rad (NaN: none)
        self.hinges = joints.HingeStats.empty((0,))
        self._signature: list = []                    # per subject: the rest calibrations its sums rest on
        self._keys: list[str] = []                    # per subject: its angles key
        self._next_refresh = self._next_facing = -np.inf
        self._any_rest = False  # some subject has rest-calibrated segments

    def __call__(self, batch: FrameBatch) -> Iterable[tuple[str, str, bytes]]:
        groups = [g for g in (batch.live if self.live else batch.exact) if len(g.owner)]  # one per layout
        if not groups:
            return []
        now = self.clock()
        if len(self._keys) < len(self.fusion.subjects) or now >= self._next_refresh:
            self.refresh()
            self._next_refresh = now + REFRESH_S
        out: list[tuple[str, str, bytes]] = []
        for g in groups:
            layout = None if g.frames.layout == PAPER10 else g.frames.layout
            rows = np.arange(len(g.owner))
            if self.unheard is not None and not (self._any_rest and layout is None):
                unheard = self.unheard(self._keys, g.owner.tolist(), wire.ANGLES)
                if unheard:
                    rows = np.delete(rows, unheard)
                    if len(rows) == 0:
                        continue
            out += self._angles(g.frames, g.owner, g.missing, rows, layout, now)
        return out

    def _angles(self, frames, owner: np.ndarray, missing: np.ndarray, rows: np.ndarray, layout,
                now: float) -> list[tuple[str, str, bytes]]:
        """The messages of the frames ``rows``, all of subjects of ``layout`` (None: paper10)."""
        n = len(wire.SEGMENTS) if layout is None else len(layout.segments)
        whole = len(rows) == len(owner)
        q = (frames.q if whole else frames.q[rows])[:, :n].astype(np.float32)  # as published (and quicker)
        owner, missing = (owner, missing) if whole else (owner[rows], missing[rows])
        missing = missing[:, :n]
        if self._any_rest and layout is None:
            facing = self.rest_segments[owner] & ~missing  # (F, 10) segments whose heading the facing undoes
            if facing.any():
                q = self._faced(q, owner, facing, now)
        tpose = ((frames.flags if whole else frames.flags[rows]) & wire.FRAME_TPOSE) != 0
        kind = "paper10" if layout is None else layout
        if tpose.any():
            q = np.where(tpose[:, None, None], joints.standing(q, "tpose", kind), q)
        basis = self.basis[owner]
        angles, flags = joints.joint_angles(q, ~missing, "standing", _VALID[basis], kind)
        seq, t_us = (frames.seq, frames.t_us) if whole else (frames.seq[rows], frames.t_us[rows])
        payloads = wire.AngleFrames(seq, t_us, np.full(len(rows), frames.kind), basis, np.degrees(self.heading[owner]),
                                    angles, flags, layout).encode()
        keys = self._keys
        return [(keys[i], wire.ANGLES, payload) for i, payload in zip(owner.tolist(), payloads)]

    def _faced(self, q: np.ndarray, owner: np.ndarray, facing: np.ndarray, now: float) -> np.ndarray:
        """``q`` (F, 10, 4) with the facing undone on the rest-calibrated segments ``facing`` (F, 10),
        the hinge sums of their subjects taken in first (and their facing worked out again when due)."""
        rows = np.flatnonzero(facing.any(axis=1))
        sub = owner[rows]
        tpose = (self.fusion.frames.rest_flag[sub] != 0)[:, None, None]
        standing = np.where(tpose, joints.standing(q[rows], "tpose"), q[rows])
        sums = joints.HingeStats.empty((len(rows),))
        sums.add(standing[:, None], facing[rows][:, None], "standing")
        for name in ("n", "total", "scatter"):
            np.add.at(getattr(self.hinges, name), sub, getattr(sums, name))
        if now >= self._next_facing:
            self._next_facing = now + FACING_S
            need = np.flatnonzero(self.rest_segments.any(axis=1))
            found = joints.HingeStats(self.hinges.n[need], self.hinges.total[need], self.hinges.scatter[need]).facing(FACING_FRAMES)
            self.heading[need] = found.heading
            told = need[self.level[need] == _REST]  # subjects whose weakest devices are rest-calibrated
            self.basis[told] = np.where(np.isfinite(self.heading[told]), wire.BASIS["functional"], wire.BASIS["no_facing"])
        heading = self.heading[sub]
        known = np.isfinite(heading)
        if not known.any():
            return q
        q = q.copy()
        k = rows[known]
        faced = joints.face(q[k], heading[known])
        q[k] = np.where(facing[k][..., None], faced, q[k])
        return q

    # ------------------------------------------------------------------ calibrations

    def refresh(self) -> None:
        """Each subject's basis and rest-calibrated segments, from its online devices (a subject
        whose rest calibrations changed starts its hinge sums over)."""
        fusion, table = self.fusion, self.fusion.table
        self._grow(len(fusion.subjects))
        level = _OF_STATUS[table.orientations + 1]  # (slots,) what the devices say
        calibrations = fusion.calibrating.calibrations
        if calibrations:
            level[np.fromiter(calibrations, np.int64, len(calibrations))] = [
                _MOUNTING if {"mounting", "functional"} & set(c.poses) else _REST for c in calibrations.values()]
        slots = table.seg_slots[:, :len(wire.SEGMENTS)]  # (paper10's segments: the table's first columns)
        rows = np.maximum(slots, 0)
        online = (slots >= 0) & table.online[rows]
        seg_level = np.where(online, level[rows], _NONE)  # (S, 10)
        self.level = np.where(online.any(axis=1), seg_level.min(axis=1), _UNKNOWN)
        self.rest_segments = seg_level == _REST
        self._any_rest = bool(self.rest_segments.any())
        for i in np.flatnonzero(self.rest_segments.any(axis=1) | np.array([bool(s) for s in self._signature])):
            signature = [(slot, int(table.stream[slot]), getattr(calibrations.get(slot), "t_ref", None))
                         for slot in slots[i][self.rest_segments[i]].tolist()]
            if signature != self._signature[i]:  # other rest calibrations: the sums start over
                self._signature[i] = signature
                for name in ("n", "total", "scatter"):
                    getattr(self.hinges, name)[i] = 0.0
                self.heading[i] = np.nan
        self.basis = np.where(self.level != _REST, _BASIS_OF_LEVEL[self.level],
                              np.where(np.isfinite(self.heading), wire.BASIS["functional"], wire.BASIS["no_facing"]))
        if self.layout_of is not None:
            self.layouts = [self.layout_of(i) for i in range(len(self.basis))]
            other = np.array([x is not None for x in self.layouts], bool)
            self.basis = np.where(other & (self.level == _REST), wire.BASIS["no_facing"], self.basis)

    def _grow(self, n: int) -> None:
        """Room for ``n`` subjects (new ones: unknown, no sums, no facing)."""
        more = n - len(self.basis)
        if more <= 0:
            return
        self.basis = np.append(self.basis, np.full(more, wire.BASIS["unknown"]))
        self.level = np.append(self.level, np.full(more, _UNKNOWN))
        self.rest_segments = np.concatenate([self.rest_segments, np.zeros((more, len(wire.SEGMENTS)), bool)])
        self.heading = np.append(self.heading, np.full(more, np.nan))
        new = joints.HingeStats.empty((more,))
        self.hinges = joints.HingeStats(*(np.concatenate([getattr(self.hinges, k), getattr(new, k)])
                                          for k in ("n", "total", "scatter")))
        self._signature += [[] for _ in range(more)]
        self.layouts += [None] * more
        self._keys += [wire.angles_key(name) for name in list(self.fusion.subjects)[len(self._keys):]]
