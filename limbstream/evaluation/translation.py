"""Translation figures: how far the estimated root wanders from the true one, how high it floats,
and how much the estimated feet skate where the true ones stand (docs/evaluation.md, "Root
translation").

Both paths are first aligned once, on the first :data:`ALIGN_S` seconds: the estimate's world is
turned about the vertical by the heading the caller measured (``heading_rad``, e.g. the pelvis'
mean heading difference over that window) and shifted horizontally by the mean offset there. The
floor of each is its own: height 0 for the estimate (the tracker's floor), the true feet's lowest
point over the whole motion for the truth (``height_cm``); and, beside it, the truth's lowest foot
point frame by frame (``height_feet_cm``, the root's height over its feet, as the tracker stands
its lowest point on its floor): a file's planted feet do not all stand at one height (its floor
is not level, a foot's lowest point is not always its sole), which a flat floor cannot follow.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ALIGN_S = 0.5
"""The start window the estimate is aligned to the truth on, s."""
PLANTED_M = 0.02
"""A true foot point is planted within this of the frame's lowest true foot point, m, ..."""
PLANTED_MPS = 0.1
"""... while its height changes slower than this, m/s."""


@dataclass(frozen=True)
class TranslationFigures:
    """One motion's figures: ``path_m`` the true root's horizontal path (m, over 0.1 s steps);
    ``end_cm`` the horizontal root error at the end (cm) and ``end_pct`` it as a percentage of the
    path; ``height_cm`` the mean absolute root height error (cm), the truth's floor at its feet's
    lowest point over the motion, and ``height_feet_cm`` the same with the truth's floor at its
    lowest foot point frame by frame (in a flight too); ``below_cm`` how far an estimated
    foot point went below the floor at most (cm, 0 if never); ``skate_cmps`` the estimated foot
    points' mean horizontal speed while the true ones are planted and ``true_skate_cmps`` the
    truth's own over the same frames (cm/s)."""

    path_m: float
    end_cm: float
    end_pct: float
    height_cm: float
    height_feet_cm: float
    below_cm: float
    skate_cmps: float
    true_skate_cmps: float


def _yaw(rad: float) -> np.ndarray:
    c, s = np.cos(rad), np.sin(rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def aligned(t: np.ndarray, root: np.ndarray, feet: np.ndarray, true_root: np.ndarray,
            heading_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """The estimated root (m, 3) and foot points (m, C, 3) in the truth's world, times ``t`` (m,)
    s: turned about +Y by ``heading_rad`` and shifted horizontally by the mean offset from
    ``true_root`` (m, 3) over the first :data:`ALIGN_S` s (metres)."""
    turn = _yaw(heading_rad)
    root = root @ turn.T
    start = t - t[0] < ALIGN_S
    offset = (true_root[start] - root[start]).mean(axis=0)
    offset[1] = 0.0
    return root + offset, feet @ turn.T + offset


def translation_figures(t: np.ndarray, root: np.ndarray, feet: np.ndarray, true_root: np.ndarray,
                        true_feet: np.ndarray, heading_rad: float = 0.0) -> TranslationFigures:
    """The figures of one motion: times ``t`` (m,) s; the estimated root (m, 3) and foot points
    (m, C, 3), metres, its world (floor at 0, Y up); the true ones likewise in the truth's world
    (``true_feet``: the same C points). ``heading_rad``: the turn about +Y taking the estimate's
    world to the truth's."""
    root, feet = aligned(t, root, feet, true_root, heading_rad)
    under = np.nanmin(true_feet[:, :, 1], axis=1)
    floor = float(np.nanmin(true_feet[:, :, 1]))
    true_root = true_root - [0.0, floor, 0.0]
    true_feet = true_feet - [0.0, floor, 0.0]
    step = max(1, round(0.1 / float(np.median(np.diff(t)))))
    every = np.unique(np.r_[np.arange(0, len(t), step), len(t) - 1])
    path = float(np.linalg.norm(np.diff(true_root[every][:, [0, 2]], axis=0), axis=1).sum())
    end = float(np.linalg.norm(root[-1, [0, 2]] - true_root[-1, [0, 2]]))
    dt = np.diff(t)[:, None]
    lowest = true_feet[:, :, 1].min(axis=1, keepdims=True)
    rising = np.abs(np.diff(true_feet[:, :, 1], axis=0)) / dt
    planted = ((true_feet[1:, :, 1] - lowest[1:]) < PLANTED_M) & (rising < PLANTED_MPS)
    speed = np.linalg.norm(np.diff(feet[:, :, [0, 2]], axis=0), axis=2) / dt
    true_speed = np.linalg.norm(np.diff(true_feet[:, :, [0, 2]], axis=0), axis=2) / dt
    some = planted.any()
    return TranslationFigures(
        path_m=path, end_cm=100 * end, end_pct=100 * end / path if path > 0 else float("nan"),
        height_cm=100 * float(np.abs(root[:, 1] - true_root[:, 1]).mean()),
        height_feet_cm=100 * float(np.abs(root[:, 1] - (true_root[:, 1] + floor - under)).mean()),
        below_cm=100 * max(0.0, -float(np.nanmin(feet[:, :, 1]))),
        skate_cmps=100 * float(speed[planted].mean()) if some else float("nan"),
        true_skate_cmps=100 * float(true_speed[planted].mean()) if some else float("nan"))


MIN_PATH_M = 0.5
"""A motion has a root trajectory to score when its true root travels at least this far, m."""


@dataclass(frozen=True)
class RootPaths:
    """An evaluated body's root paths, on its frames (m,): ``root`` the estimate's (m, 3) m, its
    world (floor at 0), NaN on frames left out; ``true_root`` the file's (m, 3) m, its world;
    ``feet``, ``true_feet`` (m, C, 3) the same foot points of both (world), ``names`` (C,) theirs;
    ``contacts`` (m,) the estimate's contact bits (``wire.CONTACTS``; 0 on frames left out);
    ``heading_rad`` the pelvis' mean heading difference, truth less estimate, over the first
    :data:`ALIGN_S` s."""

    root: np.ndarray
    true_root: np.ndarray
    feet: np.ndarray
    true_feet: np.ndarray
    names: tuple[str, ...]
    contacts: np.ndarray
    heading_rad: float


def root_paths(body, positions) -> RootPaths | None:
    """The root paths of one evaluated body (:class:`limbstream.evaluation.body.Body`) and its joint
    positions (:class:`limbstream.evaluation.positions.Positions`), or None where there is no file
    root path (a BVH file's), the layout has no feet, or less than 2 s of frames with every joint.
    The estimated root: a :class:`~limbstream.body.translation.RootTracker` on the estimated joints'
    body points (:class:`~limbstream.body.translation.BodyPoints`), over the frames
    that have every joint; the true one: the file's root joint, its feet the same foot points of
    the file's joints."""
    from limbstream.body.translation import BodyPoints, RootTracker, has_feet, heel_drops
    from limbstream.calibration import yaw_of

    source, layout = body.source, body.layout
    if source is None or not positions.from_file or not has_feet(layout):
        return None
    ok = (np.isfinite(positions.estimated).all(axis=(1, 2)) & np.isfinite(positions.truth).all(axis=(1, 2))
          & np.isfinite(body.estimated).all(axis=(1, 2)) & np.isfinite(body.truth).all(axis=(1, 2)))
    if ok.sum() < 2 or body.t[ok][-1] - body.t[ok][0] < 2.0:
        return None
    t, est_q, true_q = body.t[ok], body.estimated[ok], body.truth[ok]
    true_root = source.root_at(body.source_t, layout)
    if not np.isfinite(true_root[ok]).all():
        return None
    drops = heel_drops(layout, positions.dimensions)
    points = BodyPoints(layout)
    tracker = RootTracker(1, points.names)
    names = tuple(n for n, foot in zip(points.names, tracker.feet) if foot)
    est_pts = points.positions(drops, est_q, positions.estimated[ok])
    true_pts = points.positions(drops, true_q, positions.truth[ok])[:, tracker.feet]
    root, contacts = np.full((len(body.t), 3), np.nan), np.zeros(len(body.t), np.int64)
    root[ok], contacts[ok], _ = tracker.track(t - t[0], est_pts)
    est_pts = est_pts[:, tracker.feet]
    feet, true_feet = np.full((len(body.t), *est_pts.shape[1:]), np.nan), np.full((len(body.t), *est_pts.shape[1:]), np.nan)
    feet[ok], true_feet[ok] = root[ok][:, None] + est_pts, true_root[ok][:, None] + true_pts
    hip = layout.segment_index[layout.root.name]
    start = t - t[0] < ALIGN_S
    turn = float(np.angle(np.mean(np.exp(1j * (yaw_of(true_q[start, hip]) - yaw_of(est_q[start, hip]))))))
    return RootPaths(root, true_root, feet, true_feet, names, contacts, turn)


def translation_of(body, positions) -> dict | None:
    """The figures of one evaluated body and its positions (:func:`root_paths`), as a dict with the
    motion's ``motion`` name, or None where there is nothing to score: no root paths, or a true
    root that travels less than :data:`MIN_PATH_M`."""
    paths = root_paths(body, positions)
    if paths is None:
        return None
    ok = np.isfinite(paths.root).all(axis=1)
    figures = translation_figures(body.t[ok], paths.root[ok], paths.feet[ok], paths.true_root[ok],
                                  paths.true_feet[ok], paths.heading_rad)
    if figures.path_m < MIN_PATH_M:
        return None
    return {"motion": body.name} | vars(figures)


def pooled(per_motion: list[dict]) -> dict:
    """The figures of several motions together: the median end error (% of path), the mean height
    errors and skating, the deepest a foot went below the floor, the motions scored."""
    if not per_motion:
        return {}
    def mean(key: str) -> float:
        values = np.array([m[key] for m in per_motion], np.float64)
        return float(np.nanmean(values)) if np.isfinite(values).any() else float("nan")
    return {"motions": len(per_motion), "end_pct": float(np.median([m["end_pct"] for m in per_motion])),
            "height_cm": mean("height_cm"), "height_feet_cm": mean("height_feet_cm"), "below_cm": max(m["below_cm"] for m in per_motion),
            "skate_cmps": mean("skate_cmps"), "true_skate_cmps": mean("true_skate_cmps")}
