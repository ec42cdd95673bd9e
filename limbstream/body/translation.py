"""Root translation from foot contacts: where the body is in the room, from its joints alone.

Joint positions come root-relative (the pelvis at the origin, world axes, Y up); the body's points
(:class:`BodyPoints`: each foot's heel and toe, then the other joints) tell the rest. A layout
without feet (``paper10``) has no root translation (:func:`has_feet`): its frames say so
(``FRAME_NO_ROOT``). The floor is at height 0, learned at the start as the lowest point's height
and held (stairs and slopes are not modelled: a walk up a ramp stays on the first floor). Per frame:

- **Planted**: the lowest point stands on the floor (a foot point, or on a fall or lie-down, where
  no foot is lowest by :data:`OFF_FEET_M`, whatever joint is: ``FRAME_OFF_FEET``), and one low
  point, the **anchor**, is fixed in the world: the root moves so that the anchor stays where it
  was put down (horizontally) and the lowest point touches the floor (vertically). A low point
  (within :data:`LOW_M` of the floor) whose motion fits the root's better by :data:`KEEP_MPS`
  becomes the anchor, put down where it was a frame ago, so the root never jumps (heel to toe to
  the other heel through a step).
- **Flight**: the root leaves the floor when its ballistic path from its last velocity would hold
  it higher than the legs can, by more than :data:`TAKE_OFF_MPS` times the frame time (a run's
  push-off, a jump). It then
  flies under gravity until its lowest point reaches the floor, and lands there.
- **A foot missing** (its device offline: its points are not used): the root keeps the height it
  had with both feet, raised where the other foot would go through the floor, and stands on the
  other foot while that is down and still (within :data:`STILL_MPS`); while it is not, the missing
  foot may be the one standing: the root goes on at its pace (:data:`PACE_S`). No take-off
  without both feet.

Standing still, the anchor does not move, so the root does not drift. Contacts (``CONTACTS`` of
:mod:`limbstream.wire.pose`) are the foot points within :data:`CONTACT_M` of the floor while planted.
A frame with a non-finite point or time, or a time not after its row's last one, leaves the state
as it was and gets the row's last root (counted in :attr:`RootTracker.refused`); so does a frame
without a usable foot point.
"""
from __future__ import annotations

import numpy as np

from limbstream import quat
from limbstream.body.dimensions import Body
from limbstream.body.layout import Layout
from limbstream.kernel._lib import RootConst
from limbstream.kernel.root import STATE, BoundState, bind_state, root_frames
from limbstream.wire.pose import CONTACTS, FRAME_OFF_FEET

GRAVITY = 9.81
"""m/s², along -Y."""
TAKE_OFF_MPS = 1.0
"""The ballistic root rising away from where the legs hold it faster than this: the body is in
flight, m/s (2 cm in a 50 Hz frame; a rate, so that a jump flies at any frame rate)."""
CONTACT_M = 0.02
"""A foot point this close to the floor while planted is in contact, m."""
LOW_M = 0.03
"""Points within this of the floor may be planted, m."""
KEEP_MPS = 0.3
"""The anchor stays while no other low point is stiller in the world by more than this, m/s (a
point's world speed if the root keeps its velocity: the root's plus its own relative to the root)."""
STILL_MPS = 0.5
"""With a foot missing, the other foot stands only while its world speed is below this, m/s."""
OFF_FEET_M = 0.05
"""A joint lower than the lowest foot point by more than this: the body is off its feet, m."""
VELOCITY_S = 0.05
"""Time constant of the root velocity a flight starts with (smoothed over the last steps), s."""
PACE_S = 1.0
"""Time constant of the root's pace (its velocity over the last steps, both feet in view): where it
goes on while a missing foot may be the one standing, s."""
UNSEEN_MPS = 1e3
"""The world speed given a point that was not usable a frame ago (its motion unknown), m/s."""

_FEET = {"l": ("l_ankle", "l_foot", "l_toe"), "r": ("r_ankle", "r_foot", "r_toe")}
_FIRST, _FLIGHT, _COAST = -2, -1, -3  # anchor codes: no frame yet, in flight, going on at its velocity
_CONST = RootConst(GRAVITY, TAKE_OFF_MPS, CONTACT_M, LOW_M, KEEP_MPS, VELOCITY_S, PACE_S, STILL_MPS, UNSEEN_MPS,
                   OFF_FEET_M, _FIRST, _FLIGHT, _COAST, FRAME_OFF_FEET)
"""The constants as the C tracker takes them (firmware_c/host/lsw_root.h)."""


def has_feet(layout: Layout) -> bool:
    """Whether ``layout`` has both feet (``l_foot``, ``r_foot`` and their ankles): its root can be
    tracked (a layout without them, ``paper10``, has no root translation)."""
    return all(foot in layout.segment_index and ankle in layout.joint_index for ankle, foot, _ in _FEET.values())


def heel_drops(layout: Layout, body: Body) -> np.ndarray:
    """(2,) how far below its ankle each heel (left, right) lies in the rest pose, m: the foot
    bone's fall from ankle to toe (``layout`` has feet: :func:`has_feet`)."""
    return np.array([-float(body.vectors["standing"][layout.bone_names.index(foot)][1]) for _, foot, _ in _FEET.values()])


class BodyPoints:
    """The points a layout's root stands on: its feet's contact points (their names a subset of
    ``CONTACTS``, in its order: each foot's heel and toe), then its other joints (not ankles or
    toes), and the segments each point hangs on (a point of a missing segment is not used)."""

    def __init__(self, layout: Layout):
        if not has_feet(layout):
            raise ValueError(f"layout {layout.name} has no feet (l_foot, r_foot): no root translation")
        self.layout = layout
        at, seg = layout.joint_index, layout.segment_index
        chains: dict[str, set[int]] = {layout.root.joint: set()}
        for bone in layout.bones:  # parents first
            chains[bone.joint] = chains[bone.origin] | {seg[name] for name in bone.turned_by}
        feet: list[tuple[str, tuple[str, str, str | None], set[int]]] = []
        for side, (ankle, foot, toe) in _FEET.items():
            feet.append((f"{side}_heel", (ankle, foot, None), chains[ankle] | {seg[foot]}))
            if toe in at:
                feet.append((f"{side}_toe", (toe, foot, toe), chains[toe]))
        feet.sort(key=lambda f: CONTACTS.index(f[0]))
        foot_joints = {j for names in _FEET.values() for j in names}
        self.others = [j for j, name in enumerate(layout.joints) if name not in foot_joints]
        self.names: tuple[str, ...] = tuple(f[0] for f in feet) + tuple(layout.joints[j] for j in self.others)
        take = [at[joint] for _, (joint, _, _), _ in feet] + self.others
        self._take = np.array(take, np.intp)  # (P,) the joint each point starts from (a heel: its ankle)
        heels = [c for c, (_, (_, _, toe), _) in enumerate(feet) if toe is None]
        self._heels = np.array(heels, np.intp)  # (H,) the heel points, below their ankles
        self._heel_feet = np.array([seg[feet[c][1][1]] for c in heels], np.intp)  # (H,) their feet's segments
        self._heel_side = np.array([0 if CONTACTS.index(feet[c][0]) < 2 else 1 for c in heels], np.intp)  # (H,) drop column
        deps = [f[2] for f in feet] + [chains[layout.joints[j]] for j in self.others]
        self.segments = np.zeros((len(deps), len(layout.segments)), bool)
        """(P, S) the segments each point hangs on."""
        for p, d in enumerate(deps):
            self.segments[p, sorted(d)] = True

    def positions(self, drops: np.ndarray, q: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """(F, P, 3) m the points of frames of orientations ``q`` (F, S, 4) and root-relative joints
        ``joints`` (F, J, 3) (``layout.joints`` order); ``drops`` (F, 2) or (2,) each frame's
        :func:`heel_drops`. A heel is below its ankle by its drop, turned by the foot; a toe is
        the foot's toe joint."""
        drops = np.broadcast_to(np.asarray(drops, np.float64), (len(q), 2))
        points = np.take(joints, self._take, axis=1).astype(np.float64)
        down = np.zeros((len(q), len(self._heels), 3))
        down[:, :, 1] = -np.take(drops, self._heel_side, axis=1)
        points[:, self._heels] += quat.rotate(np.take(q, self._heel_feet, axis=1), down)
        return points

    def usable(self, missing: np.ndarray) -> np.ndarray:
        """(F, P) bool: the points of frames whose segments ``missing`` (F, S) bool lack none."""
        return np.logical_not((np.asarray(missing, bool)[:, None, :] & self.segments[None]).any(axis=2))


class RootTracker:
    """Root translation of N bodies (rows), each fed its frames in time order.

    ``names``: the points (P,) of every frame, the foot points first (those in ``CONTACTS``; the
    others are other joints: :class:`BodyPoints`). State per row (N,): root position (3,) m,
    velocity (3,) m/s and pace (3,) m/s, the anchor's index among the points and its world position (3,) (anchor
    -1: in flight, -3: going on at its velocity), the newest frame time, s, the root's height
    with both feet, m, the last points (P, 3) and which of them were usable (P,).
    """

    def __init__(self, rows: int = 0, names: tuple[str, ...] = ()):
        self.names = names
        self.feet = np.array([name in CONTACTS for name in names], bool)
        self.contact_bit = np.array([CONTACTS.index(name) if name in CONTACTS else 0 for name in names], np.int64)
        self.root = np.zeros((0, 3))
        self.velocity = np.zeros((0, 3))
        self.pace = np.zeros((0, 3))
        self.anchor = np.zeros(0, np.int64)
        self.anchor_xyz = np.zeros((0, 3))
        self.t = np.zeros(0)
        self.height = np.zeros(0)
        self.points = np.zeros((0, len(names), 3))
        self.seen = np.zeros((0, len(names)), bool)
        self.refused = np.zeros(0, np.int64)
        """Frames refused per row: a non-finite point or time, a time not after the row's last."""
        self._bound: BoundState | None = None  # the state as the C tracker takes it (bound again when replaced)
        self.grow(rows)

    def grow(self, rows: int) -> None:
        """Room for ``rows`` rows (new rows start on their first frame)."""
        more = rows - len(self.t)
        if more > 0:
            self.root = np.vstack([self.root, np.zeros((more, 3))])
            self.velocity = np.vstack([self.velocity, np.zeros((more, 3))])
            self.pace = np.vstack([self.pace, np.zeros((more, 3))])
            self.anchor = np.concatenate([self.anchor, np.full(more, _FIRST, np.int64)])
            self.anchor_xyz = np.vstack([self.anchor_xyz, np.zeros((more, 3))])
            self.t = np.concatenate([self.t, np.zeros(more)])
            self.height = np.concatenate([self.height, np.zeros(more)])
            self.points = np.concatenate([self.points, np.zeros((more, len(self.names), 3))])
            self.seen = np.concatenate([self.seen, np.zeros((more, len(self.names)), bool)])
            self.refused = np.concatenate([self.refused, np.zeros(more, np.int64)])

    def step(self, rows: np.ndarray, t: np.ndarray, points: np.ndarray, commit: bool = True,
             usable: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One frame of each of ``rows`` (n,) distinct: times ``t`` (n,) s, points ``points``
        (n, P, 3) m root-relative, ``usable`` (n, P) bool the points to go on (None: all; a
        missing segment's are not). Returns the root positions (n, 3) m, contact bits (n,)
        (``CONTACTS``) and flags (n,) (``FRAME_OFF_FEET``). ``commit`` False: what the frames
        would get, the state left as it was (a live frame ahead of the final ones).

        The reference in numpy: :meth:`frames` runs the same steps in C
        (``firmware_c/host/lsw_root.c``), frame by frame, and is what the aggregator uses;
        tests/test_root_tracker_c.py holds them equal."""
        rows = np.asarray(rows, np.int64)
        t = np.asarray(t, np.float64)
        raw = np.asarray(points, np.float64)
        idx = np.arange(len(rows))
        use = np.ones(raw.shape[:2], bool) if usable is None else np.asarray(usable, bool)
        first = self.anchor[rows] == _FIRST
        bad = ~np.isfinite(raw).all(axis=(1, 2)) | ~np.isfinite(t) | (~first & ~(t > self.t[rows]))
        hold = bad | ~(use & self.feet).any(axis=1)  # the last good root, the state left as it was
        p = np.where(np.isfinite(raw), raw, 0.0)
        y = np.where(use, p[:, :, 1], np.inf)
        lowest = y.argmin(axis=1)
        low_y = np.where(hold, 0.0, y[idx, lowest])
        off_feet = ~hold & (low_y < np.where(self.feet, y, np.inf).min(axis=1) - OFF_FEET_M)
        whole = (use | ~self.feet).all(axis=1)  # every foot point usable
        anchor, root, velocity = self.anchor[rows].copy(), self.root[rows].copy(), self.velocity[rows].copy()
        anchor_xyz, last, seen = self.anchor_xyz[rows].copy(), self.points[rows], self.seen[rows]
        dt = np.where(hold, 0.0, np.clip(t - self.t[rows], 0.0, 0.5))
        # ballistic: where the root would be from its last velocity under gravity
        fly = root + velocity * dt[:, None]
        fly[:, 1] -= 0.5 * GRAVITY * dt ** 2
        fly_v = velocity.copy()
        fly_v[:, 1] -= GRAVITY * dt
        flying = anchor == _FLIGHT
        # a flight lands where its lowest point reaches the floor; a planted body takes off when the
        # ballistic root is higher than the legs hold it
        lands = flying & (fly[:, 1] + low_y <= 0.0)
        takes_off = (anchor >= 0) & whole & (fly[:, 1] + low_y > TAKE_OFF_MPS * dt) & (fly_v[:, 1] > 0.0)
        still_flying = ((flying & ~lands) | takes_off) & ~hold
        planted = ~still_flying & ~first & ~hold
        new_root = root.copy()
        new_root[still_flying] = fly[still_flying]
        # the lowest point on the floor; with a foot missing (it may be the one standing) the height
        # the root had with both feet, raised where the rest would go through the floor
        height = np.where(~whole & ~off_feet, np.maximum(self.height[rows], -low_y), -low_y)
        new_root[planted, 1] = height[planted]
        # planted: the anchor holds the root horizontally; where another low point fits the root's
        # motion better (a point holds the root still where it was going if its own velocity
        # relative to the root, reversed, is the root's), it becomes the anchor
        rel_v = (p - last) / np.maximum(dt, 1e-6)[:, None, None]
        miss = np.hypot(velocity[:, None, 0] + rel_v[:, :, 0], velocity[:, None, 2] + rel_v[:, :, 2])
        miss = np.where(seen, miss, UNSEEN_MPS)
        down = (new_root[:, 1:2] + y < LOW_M) & (whole[:, None] | (miss < STILL_MPS))
        cost = np.where(down, miss, np.inf)
        best = cost.argmin(axis=1)
        keep = np.clip(anchor, 0, None)
        stands = planted & np.isfinite(cost[idx, best])
        coast = planted & ~stands  # a foot missing, the other not down: the missing one may stand
        switch = stands & ((anchor < 0) | (cost[idx, keep] > cost[idx, best] + KEEP_MPS))
        put = np.where(switch, best, keep)
        # a new anchor was already down over the last frame: put it where it was then (one not seen
        # then: where it is if the root went on; a landing: where its flight brings it now)
        was = np.where(seen[idx, put][:, None], root + last[idx, put], root + velocity * dt[:, None] + p[idx, put])
        put_xyz = np.where(lands[:, None], fly + p[idx, put], was)
        put_xyz[:, 1] = 0.0
        anchor_xyz = np.where(switch[:, None], put_xyz, anchor_xyz)
        now = anchor_xyz - p[idx, put]
        new_root[stands, 0], new_root[stands, 2] = now[stands, 0], now[stands, 2]
        pace = self.pace[rows]
        new_root[coast, 0] += pace[coast, 0] * dt[coast]
        new_root[coast, 2] += pace[coast, 2] * dt[coast]
        new_root[first] = np.stack([np.zeros(first.sum()), -low_y[first], np.zeros(first.sum())], axis=1)
        new_anchor = np.where(still_flying, _FLIGHT, np.where(first, lowest, np.where(coast, _COAST, put)))
        if first.any():
            start = new_root[first] + p[idx[first], lowest[first]]
            start[:, 1] = 0.0
            anchor_xyz[first] = start
        moved = (new_root - root) / np.maximum(dt, 1e-6)[:, None]
        gain = np.where((dt > 0) & ~first, 1.0 - np.exp(-dt / VELOCITY_S), 0.0)
        new_velocity = np.where(still_flying[:, None], fly_v,
                                np.where(first[:, None], 0.0, velocity + gain[:, None] * (moved - velocity)))
        slow = np.where((dt > 0) & ~first & whole, 1.0 - np.exp(-dt / PACE_S), 0.0)
        new_pace = np.where(first[:, None], 0.0, pace + slow[:, None] * (moved - pace))
        touching = (new_root[:, 1:2] + y <= CONTACT_M) & ~still_flying[:, None] & ~hold[:, None]
        bits = np.zeros(len(rows), np.int64)
        for c in np.flatnonzero(self.feet):
            bits |= touching[:, c].astype(np.int64) << CONTACTS.index(self.names[c])
        flags = np.where(off_feet, FRAME_OFF_FEET, 0)
        new_root[hold] = self.root[rows[hold]]
        if commit:
            ok, at = ~hold, rows[~hold]
            self.root[at], self.velocity[at], self.anchor[at] = new_root[ok], new_velocity[ok], new_anchor[ok]
            self.pace[at] = new_pace[ok]
            self.anchor_xyz[at], self.t[at], self.points[at], self.seen[at] = anchor_xyz[ok], t[ok], p[ok], use[ok]
            self.height[at] = np.where(whole[ok] | first[ok], new_root[ok, 1], self.height[at])
            np.add.at(self.refused, rows[bad], 1)
        return new_root, bits, flags

    def frames(self, owner: np.ndarray, t: np.ndarray, points: np.ndarray, usable: np.ndarray | None = None,
               commit: bool | np.ndarray = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`step` in C for frames of rows ``owner`` (F,) in the order given (each row's
        oldest first), one call: each frame against its row's state as the committed frames before
        it left it. ``commit``: (F,) bool or one bool for all, the frames that move the state
        (final ones); the others (live frames) only read it. Times ``t`` (F,) s, points ``points``
        (F, P, 3) m, ``usable`` (F, P) bool (None: all). Returns the roots (F, 3) m, contact bits
        (F,) and flags (F,)."""
        points = np.asarray(points, np.float64)
        use = np.ones(points.shape[:2], bool) if usable is None else usable
        return root_frames(self._state(), _CONST, owner, t, points, use, commit)

    def _state(self) -> BoundState:
        """The state arrays bound for the C tracker (once, and again after an array was replaced)."""
        arrays = [getattr(self, name) for name, _, _ in STATE]
        bound = self._bound
        if bound is None or any(a is not b for a, b in zip(arrays, bound.arrays)):
            bound = self._bound = bind_state(dict(zip([name for name, _, _ in STATE], arrays)), self.feet,
                                             self.contact_bit)
        return bound

    def track(self, t: np.ndarray, points: np.ndarray, row: int = 0,
              usable: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The root positions (F, 3) m, contact bits (F,) and flags (F,) of one row's frames, times
        ``t`` (F,) s, points ``points`` (F, P, 3), ``usable`` (F, P) (None: all) (an offline
        motion: one row, its frames in turn)."""
        self.grow(row + 1)
        return self.frames(np.full(len(t), row, np.int64), t, points, usable)
