"""Root translation of every subject's frames (docs/body.md, "Root translation").

Each subject's exact frames, oldest first, move its root tracker (:class:`RootTracker`, one per
layout's set of body points, a row per subject); a live frame gets the root the tracker gives it
from the newest exact frame's state without moving it, so live and exact frames share one path
and a live frame's guess never steers the final one. A subject's root carries on through its
devices' restarts and calibrations (its frames do: the anchor holds it where it was). A
layout without feet has no root translation: its frames keep the origin, flagged ``FRAME_NO_ROOT``.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from limbstream import wire
from limbstream.body import Body, Layout
from limbstream.body.translation import BodyPoints, RootTracker, has_feet, heel_drops


class Rooting:
    """Root positions (F, 3) m, contact bits (F,) and flags (F,) of frames, per subject row."""

    def __init__(self) -> None:
        self.trackers: dict[tuple[str, ...], RootTracker] = {}
        self.points: dict[Layout, BodyPoints] = {}
        self.drops: dict[tuple[Layout, int], tuple[Body, np.ndarray]] = {}  # (layout, id(body)) -> (body, its heel drops)

    def _drops(self, layout: Layout, body: Body) -> np.ndarray:
        key = (layout, id(body))
        found = self.drops.get(key)
        if found is None or found[0] is not body:
            found = self.drops[key] = (body, heel_drops(layout, body))
        return found[1]

    def _tracker(self, names: tuple[str, ...], rows: int) -> RootTracker:
        tracker = self.trackers.get(names)
        if tracker is None:
            tracker = self.trackers[names] = RootTracker(0, names)
        tracker.grow(rows)
        return tracker

    def place(self, owner: np.ndarray, t_us: np.ndarray, q: np.ndarray, joints: np.ndarray, layout: Layout,
              bodies: Sequence[Body], which: np.ndarray | int, commit: bool | np.ndarray,
              missing: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The roots, contacts and flags (``FRAME_NO_ROOT``, ``FRAME_OFF_FEET``) of frames of one
        layout, taken in the order given: subject rows ``owner`` (F,) (each subject's frames oldest
        first), times ``t_us`` (F,) µs, orientations ``q`` (F, S, 4), root-relative joints
        ``joints`` (F, J, 3) m, drawn with the bodies ``bodies[which]`` (``which`` (F,) or one
        index for all), ``missing`` (F, S) bool the segments each frame lacks (held or identity:
        their points are not used; None: none). ``commit`` (F,) bool or one bool for all: the
        frames that are final (exact) and move the trackers; the others (live frames, one per
        subject after its exact ones) only read them."""
        root, contacts = np.zeros((len(owner), 3)), np.zeros(len(owner), np.int64)
        flags = np.zeros(len(owner), np.int64)
        if not len(owner):
            return root, contacts, flags
        if not has_feet(layout):
            return root, contacts, flags | wire.FRAME_NO_ROOT
        body_points = self.points.get(layout)
        if body_points is None:
            body_points = self.points[layout] = BodyPoints(layout)
        which = np.broadcast_to(which, owner.shape)
        used = np.unique(which).tolist()  # (the bodies these frames are drawn with: a few)
        drops = np.zeros((used[-1] + 1, 2))
        drops[used] = [self._drops(layout, bodies[i]) for i in used]
        points = body_points.positions(drops[which], q, joints)
        usable = None if missing is None or not missing.any() else body_points.usable(missing)
        tracker = self._tracker(body_points.names, int(owner.max()) + 1)
        return tracker.frames(owner, t_us / 1e6, points, usable, commit)
