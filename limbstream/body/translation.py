"""Root translation from foot contacts: where the body is in the room, from its joints alone.

Joint positions come root-relative (the pelvis at the origin, world axes, Y up); the feet's contact
points (:func:`foot_points`: each foot's heel and toe, the heel only where the layout has no feet)
tell the rest. The floor is at height 0, learned at the start as the lowest foot point's height and
held (stairs and slopes are not modelled: a walk up a ramp stays on the first floor). Per frame:

- **Planted**: the lowest foot point stands on the floor, and one planted point, the **anchor**, is
  fixed in the world: the root moves so that the anchor stays where it was put down (horizontally)
  and the lowest foot point touches the floor (vertically). A low point (within :data:`LOW_M` of the
  lowest) whose motion fits the root's better by :data:`KEEP_MPS` becomes the anchor, put down where
  it was a frame ago, so the root never jumps (heel to toe to the other heel through a step).
- **Flight**: the root leaves the floor when its ballistic path from its last velocity would hold
  it higher than the legs can by more than :data:`TAKE_OFF_M` (a run's push-off, a jump). It then
  flies under gravity until its lowest foot point reaches the floor, and lands there.

Standing still, the anchor does not move, so the root does not drift. Contacts (``CONTACTS`` of
:mod:`limbstream.wire.pose`) are the foot points within :data:`CONTACT_M` of the floor while planted.
"""
from __future__ import annotations

import numpy as np

from limbstream import quat
from limbstream.body.builtin import DEFAULT_HEIGHT_M, WINTER_HEIGHTS
from limbstream.body.dimensions import Body
from limbstream.body.layout import Layout
from limbstream.wire.pose import CONTACTS

GRAVITY = 9.81
"""m/s², along -Y."""
TAKE_OFF_M = 0.02
"""The ballistic root higher than the planted one by this much: the body is in flight, m."""
CONTACT_M = 0.02
"""A foot point this close to the floor while planted is in contact, m."""
LOW_M = 0.03
"""Foot points within this of the lowest one may be planted, m."""
KEEP_MPS = 0.3
"""The anchor stays while no other low point is stiller in the world by more than this, m/s (a
point's world speed if the root keeps its velocity: the root's plus its own relative to the root)."""
VELOCITY_S = 0.05
"""Time constant of the root velocity a flight starts with (smoothed over the last steps), s."""

_FEET = {"l": ("l_ankle", "l_foot", "l_toe"), "r": ("r_ankle", "r_foot", "r_toe")}


def heel_drops(layout: Layout, body: Body) -> np.ndarray:
    """(2,) how far below its ankle each heel (left, right) lies in the rest pose, m: the foot
    bone's fall from ankle to toe (a layout with feet), else the ankle's standing height (Winter's
    0.039 of the body's height, the default adult's where the body does not say)."""
    drops = np.full(2, WINTER_HEIGHTS["ankle"] * float(body.height_m or DEFAULT_HEIGHT_M))
    for i, (_, foot, _) in enumerate(_FEET.values()):
        if foot in layout.segment_index:
            drops[i] = -float(body.vectors["standing"][layout.bone_names.index(foot)][1])
    return drops


def foot_points(layout: Layout, drops: np.ndarray, q: np.ndarray, joints: np.ndarray) -> tuple[tuple[str, ...], np.ndarray]:
    """The feet's contact points of frames: their names (a subset of ``CONTACTS``, in its order)
    and positions (F, C, 3) m, root-relative as ``joints`` (F, J, 3) (``layout.joints`` order) of
    orientations ``q`` (F, S, 4). ``drops`` (F, 2) or (2,): each frame's :func:`heel_drops`. A heel
    is below its ankle by its drop, turned by the foot (a layout without feet: the foot taken
    flat); a toe is the foot's toe joint."""
    at, seg = layout.joint_index, layout.segment_index
    drops = np.broadcast_to(np.asarray(drops, np.float64), (len(q), 2))
    names, points = [], []
    for i, (side, (ankle, foot, toe)) in enumerate(_FEET.items()):
        if ankle not in at:
            continue
        down = np.zeros((len(q), 3))
        down[:, 1] = -drops[:, i]
        heel = joints[:, at[ankle]].astype(np.float64) + (quat.rotate(q[:, seg[foot]], down) if foot in seg else down)
        names.append(f"{side}_heel")
        points.append(heel)
        if foot in seg and toe in at:
            names.append(f"{side}_toe")
            points.append(joints[:, at[toe]].astype(np.float64))
    order = sorted(range(len(names)), key=lambda k: CONTACTS.index(names[k]))
    return tuple(names[k] for k in order), np.stack([points[k] for k in order], axis=1)


class RootTracker:
    """Root translation of N bodies (rows), each fed its frames in time order.

    State per row (N,): root position (3,) m, velocity (3,) m/s, the anchor's index among the foot
    points and its world position (3,) (anchor -1: in flight), the newest frame time, s.
    """

    def __init__(self, rows: int = 0, names: tuple[str, ...] = ()):
        self.names = names
        self.root = np.zeros((rows, 3))
        self.velocity = np.zeros((rows, 3))
        self.anchor = np.full(rows, -2, np.int64)  # -2: no frame yet, -1: flight
        self.anchor_xyz = np.zeros((rows, 3))
        self.t = np.zeros(rows)
        self.points = np.zeros((rows, len(names), 3))

    def grow(self, rows: int) -> None:
        """Room for ``rows`` rows (new rows start on their first frame)."""
        more = rows - len(self.t)
        if more > 0:
            self.root = np.vstack([self.root, np.zeros((more, 3))])
            self.velocity = np.vstack([self.velocity, np.zeros((more, 3))])
            self.anchor = np.concatenate([self.anchor, np.full(more, -2, np.int64)])
            self.anchor_xyz = np.vstack([self.anchor_xyz, np.zeros((more, 3))])
            self.t = np.concatenate([self.t, np.zeros(more)])
            self.points = np.concatenate([self.points, np.zeros((more, len(self.names), 3))])

    def reset(self, rows: np.ndarray) -> None:
        """Rows start over at their next frame (the root back at the origin)."""
        self.anchor[rows] = -2
        self.root[rows] = 0.0
        self.velocity[rows] = 0.0

    def step(self, rows: np.ndarray, t: np.ndarray, points: np.ndarray, commit: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """One frame of each of ``rows`` (n,) distinct: times ``t`` (n,) s, foot points ``points``
        (n, C, 3) m root-relative. Returns the root positions (n, 3) m and contact bits (n,)
        (``CONTACTS``). ``commit`` False: what the frames would get, the state left as it was (a
        live frame ahead of the final ones)."""
        rows = np.asarray(rows, np.int64)
        p = np.asarray(points, np.float64)
        lowest = p[:, :, 1].argmin(axis=1)
        low_y = p[np.arange(len(rows)), lowest, 1]
        anchor, root, velocity = self.anchor[rows].copy(), self.root[rows].copy(), self.velocity[rows].copy()
        anchor_xyz = self.anchor_xyz[rows].copy()
        dt = np.clip(t - self.t[rows], 0.0, 0.5)
        first = anchor == -2
        # ballistic: where the root would be from its last velocity under gravity
        fly = root + velocity * dt[:, None]
        fly[:, 1] -= 0.5 * GRAVITY * dt ** 2
        fly_v = velocity.copy()
        fly_v[:, 1] -= GRAVITY * dt
        flying = anchor == -1
        # a flight lands where its lowest point reaches the floor; a planted body takes off when the
        # ballistic root is higher than the legs hold it
        lands = flying & (fly[:, 1] + low_y <= 0.0)
        takes_off = (anchor >= 0) & (fly[:, 1] + low_y > TAKE_OFF_M) & (fly_v[:, 1] > 0.0)
        still_flying = (flying & ~lands) | takes_off
        planted = ~still_flying & ~first
        new_root = root.copy()
        new_root[still_flying] = fly[still_flying]
        idx = np.arange(len(rows))
        keep = np.clip(anchor, 0, None)
        # planted: the anchor holds the root horizontally, the lowest point vertically; where another
        # low point fits the root's motion better (a point holds the root still where it was going
        # if its own velocity relative to the root, reversed, is the root's), it becomes the anchor
        rel_v = (p - self.points[rows]) / np.maximum(dt, 1e-6)[:, None, None]
        miss = np.hypot(velocity[:, None, 0] + rel_v[:, :, 0], velocity[:, None, 2] + rel_v[:, :, 2])
        cost = np.where(p[:, :, 1] - low_y[:, None] < LOW_M, miss, np.inf)
        best = cost.argmin(axis=1)
        switch = planted & ((anchor < 0) | (cost[idx, keep] > cost[idx, best] + KEEP_MPS))
        put = np.where(switch, best, keep)
        # a new anchor was already down over the last frame: put it where it was then (a landing:
        # where its flight brings it now)
        put_xyz = np.where(lands[:, None], fly + p[idx, put], root + self.points[rows][idx, put])
        put_xyz[:, 1] = 0.0
        anchor_xyz = np.where(switch[:, None], put_xyz, anchor_xyz)
        now = anchor_xyz - p[idx, put]
        new_root[planted, 0] = now[planted, 0]
        new_root[planted, 2] = now[planted, 2]
        new_root[planted, 1] = -low_y[planted]
        new_root[first] = np.stack([np.zeros(first.sum()), -low_y[first], np.zeros(first.sum())], axis=1)
        new_anchor = np.where(still_flying, -1, np.where(first, lowest, put))
        if first.any():
            start = new_root[first] + p[idx[first], lowest[first]]
            start[:, 1] = 0.0
            anchor_xyz[first] = start
        moved = (new_root - root) / np.maximum(dt, 1e-6)[:, None]
        gain = np.where((dt > 0) & ~first, 1.0 - np.exp(-dt / VELOCITY_S), 0.0)
        new_velocity = np.where(still_flying[:, None], fly_v,
                                np.where(first[:, None], 0.0, velocity + gain[:, None] * (moved - velocity)))
        height = new_root[:, 1:2] + p[:, :, 1]
        touching = (height <= CONTACT_M) & ~still_flying[:, None]
        bits = np.zeros(len(rows), np.int64)
        for c, name in enumerate(self.names):
            bits |= touching[:, c].astype(np.int64) << CONTACTS.index(name)
        if commit:
            self.root[rows], self.velocity[rows], self.anchor[rows] = new_root, new_velocity, new_anchor
            self.anchor_xyz[rows], self.t[rows], self.points[rows] = anchor_xyz, t, p
        return new_root, bits

    def track(self, t: np.ndarray, points: np.ndarray, row: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The root positions (F, 3) m and contact bits (F,) of one row's frames, times ``t`` (F,) s,
        foot points ``points`` (F, C, 3) (an offline motion: one row, its frames in turn)."""
        self.grow(row + 1)
        root, bits = np.zeros((len(t), 3)), np.zeros(len(t), np.int64)
        rows = np.array([row])
        for k in range(len(t)):
            r, b = self.step(rows, t[k:k + 1], points[k:k + 1])
            root[k], bits[k] = r[0], b[0]
        return root, bits
