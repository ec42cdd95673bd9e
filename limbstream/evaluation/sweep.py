"""The threshold sweep of the paper's protocol: every stream segmented at each threshold, rebuilt
by SLERP and compared with its samples (the measures: :mod:`limbstream.evaluation`)."""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from limbstream import calibration, joints, kernel, quat, wire
from limbstream.sources import Motion
from limbstream.evaluation.live_model import _accepted, _segment_live

THRESHOLDS: np.ndarray = np.concatenate([[0.0], np.logspace(-6.0, 3.0, 205)])
"""The paper's sweep: 0 and 205 log-spaced values from 1e-6 to 1e3 (206 thresholds)."""

MAX_LEN = 1000
"""Largest segment length of the paper's protocol, samples."""

ICR_TARGETS: tuple[float, ...] = (0.05, 0.10, 0.25, 0.50)
"""ICRs of the comparison table."""

ALGORITHMS: tuple[str, ...] = ("fastsw", "sw", "cplr", "swing")
"""Algorithms evaluated by default (keys of :data:`limbstream.kernel.ALGORITHMS`)."""

CALIBRATIONS: tuple[tuple[str, ...], ...] = ((), ("rest",), ("rest", "mounting"))
"""The calibrations ``body_aad`` can be measured after: none, the rest pose alone, rest and
mounting pose (:mod:`limbstream.calibration`)."""

PREDICTORS: tuple[str, ...] = ("rate", "slope", "hold")
"""The rates a receiver extrapolates points with (live error); ``rate`` is fastSW's live rule's."""

KEYS: tuple[str, ...] = (
    "algorithm",
    "threshold",
    "live_bound",
    "predictor",
    "icr",
    "aad",
    "std",
    "p99",
    "max",
    "point_aad",
    "point_max",
    "live_aad",
    "live_p99",
    "live_max",
    "body_aad",
)
"""Fields of one result row, in output order."""

MEASURES: tuple[str, ...] = KEYS[5:]
"""The angular measures of a row, degrees."""


@dataclass(frozen=True)
class Stream:
    """One segment's orientation stream.

    Attributes
    ----------
    t : (m,) float64 seconds, increasing.
    q : (m, 4) float64 scalar-first quaternions (may hold non-finite rows: those are
        rejected by the kernels and left out of the deviation statistics): what the device
        compresses, its sensor's readings.
    name : str, "<motion>/<segment>".
    truth : (m, 4) float64 or None: the segment's true orientations when they differ from its
        sensor's readings (a sensor model, :mod:`limbstream.calibration`); the stream then starts
        with the calibration script, whose still windows are ``rest`` and ``mounting`` (sample
        slices; ``pose`` (4,): the segment in the mounting pose) and whose motion starts at
        sample ``motion_from``.
    rest_pose : what identity means for the motion's orientations (joint angles).
    """

    t: np.ndarray
    q: np.ndarray
    name: str
    truth: np.ndarray | None = None
    rest: slice | None = None
    mounting: slice | None = None
    pose: np.ndarray | None = None
    motion_from: int = 0
    rest_pose: str = wire.DEFAULT_REST_POSE


def streams_of(motions: Iterable[Motion], sensors: calibration.SensorModel | None = None) -> list[Stream]:
    """Every segment stream of every motion (S streams per motion); with a sensor model that is
    on, each motion preceded by the calibration script and seen through its sensors (drawn per
    motion)."""
    out = []
    for i, motion in enumerate(motions):
        if sensors is not None and sensors.on:
            out.extend(_sensor_streams(motion, sensors, i))
            continue
        for s, segment in enumerate(motion.segments):
            out.append(
                Stream(
                    np.asarray(motion.t, np.float64),
                    np.asarray(motion.q[:, s, :], np.float64),
                    f"{motion.name}/{segment}",
                    rest_pose=motion.rest_pose,
                )
            )
    return out


def _sensor_streams(motion: Motion, sensors: calibration.SensorModel, index: int) -> list[Stream]:
    """A motion's streams as its sensors report them, after the calibration script."""
    t = np.asarray(motion.t, np.float64)
    fs = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else 50.0
    q, rest, mounting = calibration.with_script(motion.q, fs, motion.segments)
    start = len(q) - len(t)
    t = np.concatenate([t[0] - np.arange(start, 0, -1) / fs, t]) if len(t) else np.arange(len(q)) / fs
    draws = sensors.draw(len(motion.segments), stream=index)
    pose = calibration.mounting_pose(motion.segments)
    return [Stream(t, draws.report(s, t - t[0], q[:, s]), f"{motion.name}/{segment}", truth=q[:, s], rest=rest,
                   mounting=mounting, pose=pose[s], motion_from=start, rest_pose=motion.rest_pose)
            for s, segment in enumerate(motion.segments)]


class _Pool:
    """All streams concatenated, for one vectorised reconstruction per (algorithm, threshold).

    Stream j's samples occupy ``start[j]:start[j + 1]``; its time axis is shifted to
    ``t - t[0] + offset[j]`` so that one ``searchsorted`` serves every stream at once.
    """

    def __init__(self, streams: Sequence[Stream]):
        if not streams:
            raise ValueError("no streams to evaluate")
        self.streams = list(streams)
        lengths = np.array([len(s.t) for s in streams])
        self.start = np.concatenate([[0], np.cumsum(lengths)])
        spans = np.array([s.t[-1] - s.t[0] if len(s.t) else 0.0 for s in streams])
        gap = float(np.nanmax(spans)) + 1.0 if len(spans) else 1.0
        self.offset = np.arange(len(streams)) * gap
        self.t0 = np.array([s.t[0] if len(s.t) else 0.0 for s in streams])
        self.key = np.concatenate([s.t - s.t[0] + o for s, o in zip(streams, self.offset)])
        self.t = np.concatenate([s.t for s in streams])
        self.q = np.concatenate([s.q for s in streams]) if streams else np.zeros((0, 4))
        self.stream_of = np.repeat(np.arange(len(streams)), lengths)
        norm = np.linalg.norm(self.q, axis=1)
        self.valid = np.isfinite(norm) & (norm > 0) & np.isfinite(self.key)
        self.q_unit = np.where(
            self.valid[:, None], self.q / np.where(self.valid, norm, 1.0)[:, None], 0.0
        )
        self.n_samples = int(lengths.sum())
        self.accepted = np.zeros(self.n_samples, bool)  # what a kernel accepts (time increasing too)
        for j, s in enumerate(streams):
            self.accepted[self.start[j] + _accepted(s.t, np.asarray(s.q, np.float64))] = True


def _stats(dev: np.ndarray) -> tuple[float, float, float, float]:
    """mean, std, p99, max of (n,) degrees; NaN if empty."""
    if dev.size == 0:
        return (math.nan,) * 4
    return float(dev.mean()), float(dev.std()), float(np.percentile(dev, 99)), float(dev.max())


def evaluate_threshold(
    pool: _Pool, algorithm: str, threshold: float, max_len: int = MAX_LEN, live_bound: float = 0.0,
    predictor: str = "rate", live: bool = False, poses: Sequence[str] = CALIBRATIONS[-1], angles: bool = False,
) -> dict:
    """Segment every stream of ``pool`` at one threshold (and live bound) and measure the result
    (the live error only if ``live``: it costs about as much as the reconstruction; else the
    ``live_*`` fields are NaN). Streams with a truth (a sensor model) are calibrated from their
    reconstruction with ``poses`` (one of :data:`CALIBRATIONS`) for ``body_aad``. With ``angles``
    the row also holds ``joints``: per joint angle the error figures of the (calibrated)
    reconstruction's angles against the truth's (:func:`limbstream.joints.pooled_errors`).

    Returns
    -------
    dict with the fields of :data:`KEYS` (degrees for the angular measures), and ``joints``.
    """
    if live_bound > 0 and algorithm != "fastsw":
        raise ValueError(f"the live rule is fastSW's, not {algorithm!r}'s")
    point_key, point_q, point_dev, owners = [], [], [], []
    live_pos, live_q, live_t, live_omega, live_owner = [], [], [], [], []
    n_points = 0
    for j, stream in enumerate(pool.streams):
        if len(stream.t) == 0:
            continue
        index, seg_t, seg_q, known, omega = _segment_live(stream, algorithm, threshold, max_len,
                                                          live_bound, predictor if live else None)
        k = len(seg_t)
        if k == 0:  # every sample rejected: nothing to rebuild this stream from
            continue
        n_points += k
        if live:
            live_pos.append(pool.start[j] + known)
            live_q.append(quat.normalize(seg_q))
            live_t.append(seg_t)
            live_omega.append(omega)
            live_owner.append(np.full(k, j))
        point_dev.append(quat.angle_deg(stream.q[index], seg_q))
        q_points = quat.normalize(seg_q)
        key = seg_t - pool.t0[j] + pool.offset[j]
        if k == 1:  # a single point: hold it (zero-length span)
            key, q_points = np.repeat(key, 2), np.repeat(q_points, 2, axis=0)
        point_key.append(key)
        point_q.append(q_points)
        owners.append(j)
    icr = n_points / pool.n_samples if pool.n_samples else math.nan
    row = {"algorithm": algorithm, "threshold": float(threshold), "live_bound": float(live_bound),
           "predictor": predictor if live else None, "icr": icr}
    if not point_key:
        return row | dict.fromkeys(MEASURES, math.nan)
    errors = _live_errors(pool, np.concatenate(live_pos), np.concatenate(live_q), np.concatenate(live_t),
                          np.concatenate(live_omega), np.concatenate(live_owner)) if live else np.zeros(0)

    keys = np.concatenate(point_key)
    q_points = np.concatenate(point_q)
    counts = np.array([len(p) for p in point_key])
    have = np.zeros(len(pool.streams), bool)
    first = np.zeros(len(pool.streams), np.int64)
    have[owners] = True
    first[owners] = np.concatenate([[0], np.cumsum(counts)[:-1]])
    last = first.copy()
    last[owners] += counts - 1

    mask = pool.valid & have[pool.stream_of]
    sample_key = pool.key[mask]
    owner = pool.stream_of[mask]
    k = np.searchsorted(keys, sample_key, side="right") - 1
    k = np.clip(k, first[owner], last[owner] - 1)  # stay inside the sample's own stream
    span = keys[k + 1] - keys[k]
    u = np.clip((sample_key - keys[k]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    recon = quat.slerp(q_points[k], q_points[k + 1], u)
    dev = quat.angle_deg(pool.q_unit[mask], recon)
    aad, std, p99, mx = _stats(dev)
    rec = np.full((pool.n_samples, 4), np.nan)
    rec[mask] = recon
    calibrated = _calibrated(pool, rec, poses)
    body = (np.concatenate([quat.angle_deg(c[ok], t[ok]) for c, t, ok in calibrated.values()])
            if calibrated else np.zeros(0))
    if angles:
        row["joints"] = joints.pooled_errors(_bodies(pool, rec, calibrated))
    pdev = np.concatenate(point_dev)
    pdev = pdev[np.isfinite(pdev)]
    return row | {
        "aad": aad,
        "std": std,
        "p99": p99,
        "max": mx,
        "point_aad": float(pdev.mean()) if pdev.size else math.nan,
        "point_max": float(pdev.max()) if pdev.size else math.nan,
        "live_aad": float(errors.mean()) if errors.size else math.nan,
        "live_p99": float(np.percentile(errors, 99)) if errors.size else math.nan,
        "live_max": float(errors.max()) if errors.size else math.nan,
        "body_aad": float(body.mean()) if body.size else math.nan,
    }


def _calibrated(pool: _Pool, rec: np.ndarray,
                poses: Sequence[str]) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per stream with a truth: its calibrated reconstruction (from ``rec`` (n, 4), the pooled
    reconstruction, NaN where none) over the motion after the calibration script, the truth there
    (each (m, 4)) and where both are finite (m,) bool. The calibration is made from the
    reconstruction in the script's still windows, as the system would (CalibrationError if it
    cannot be)."""
    out = {}
    for j, s in enumerate(pool.streams):
        if s.truth is None:
            continue
        r = rec[pool.start[j]:pool.start[j + 1]]
        cal = (calibration.calibrate(r, s.rest, s.mounting if "mounting" in poses else None, s.pose, s.name)
               if "rest" in poses else calibration.Calibration.none())
        motion, truth = r[s.motion_from:], s.truth[s.motion_from:]
        ok = np.isfinite(motion).all(axis=1) & np.isfinite(truth).all(axis=1)
        calibrated = np.full(motion.shape, np.nan)
        calibrated[ok] = cal.apply(motion[ok])
        out[j] = (calibrated, truth, ok)
    return out


def _bodies(pool: _Pool, rec: np.ndarray, calibrated: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]):
    """(estimate, truth, rest_pose) per motion, each (m, 10, 4) in SEGMENTS order: the streams of
    one motion (``<motion>/<segment>``) put together; without a truth (no sensor model) the
    reconstruction is the estimate and the samples the truth."""
    motions: dict[str, tuple[np.ndarray, np.ndarray, str]] = {}
    for j, s in enumerate(pool.streams):
        motion, _, segment = s.name.rpartition("/")
        if segment not in wire.SEGMENTS:
            continue
        estimate, truth, _ = calibrated[j] if j in calibrated else (rec[pool.start[j]:pool.start[j + 1]], s.q, None)
        if motion not in motions:
            empty = np.full((len(truth), len(wire.SEGMENTS), 4), np.nan)
            motions[motion] = (empty, empty.copy(), s.rest_pose)
        motions[motion][0][:, wire.SEGMENTS.index(segment)] = estimate
        motions[motion][1][:, wire.SEGMENTS.index(segment)] = truth
    return motions.values()


def _live_errors(pool: _Pool, known: np.ndarray, q_points: np.ndarray, t_points: np.ndarray,
                 omega: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """Live error (degrees) of every sample of the pool a kernel accepts (finite, time increasing)
    that has a point known by then.

    known : (K,) pooled sample positions from which each point is known, by stream then time;
    q_points (K, 4) unit, t_points (K,) seconds (stream time), omega (K, 3) rad/s, owner (K,).
    """
    position = np.flatnonzero(pool.valid & pool.accepted)
    j = np.searchsorted(known, position, side="right") - 1
    stream = pool.stream_of[position]
    ok = (j >= 0) & (owner[np.maximum(j, 0)] == stream)
    position, j = position[ok], j[ok]
    view = quat.predict(q_points[j], omega[j], pool.t[position] - t_points[j])
    return quat.angle_deg(view, pool.q_unit[position])


def evaluate(
    motions: Iterable[Motion] | Sequence[Stream],
    algorithms: Sequence[str] = ALGORITHMS,
    thresholds: Sequence[float] = THRESHOLDS,
    max_len: int = MAX_LEN,
    live_bounds: Sequence[float] | None = None,
    predictor: str = "rate",
    poses: Sequence[str] = CALIBRATIONS[-1],
    progress: Callable[[int, int], None] | None = None,
    angles: bool = False,
) -> list[dict]:
    """Run the protocol: one row per (algorithm, live bound, threshold), in that order.

    Parameters
    ----------
    motions : Motion objects (every segment stream is used) or :class:`Stream` objects.
    algorithms : keys of :data:`limbstream.kernel.ALGORITHMS`.
    thresholds : (T,) thresholds, >= 0, each algorithm's own unit.
    max_len : largest segment length, samples.
    live_bounds : fastSW live rule bounds, degrees in [0, 180) (0: the plain rules; a bound
        above 0 needs algorithms == ["fastsw"]); None: the plain rules, and no live error
        (the ``live_*`` fields are NaN).
    predictor : the points' rates for the live error, one of :data:`PREDICTORS`.
    poses : the calibration before ``body_aad`` (streams with a truth), one of :data:`CALIBRATIONS`.
    progress : called with (rows done, rows in all) after each row.
    angles : also score the joint angles (each row's ``joints``, :func:`evaluate_threshold`).

    Returns
    -------
    list of dict with the fields of :data:`KEYS`; deviations in degrees, pooled over all
    samples of all streams.
    """
    items = list(motions)
    streams = [s for s in items if isinstance(s, Stream)] + streams_of(
        m for m in items if isinstance(m, Motion)
    )
    for name in algorithms:
        if name not in kernel.ALGORITHMS:
            raise ValueError(f"algorithm must be one of {sorted(kernel.ALGORITHMS)}, got {name!r}")
    if predictor not in PREDICTORS:
        raise ValueError(f"predictor must be one of {', '.join(PREDICTORS)}, got {predictor!r}")
    live = live_bounds is not None
    for bound in live_bounds or ():
        if kernel.LIVE_BOUND.check(bound) > 0 and set(algorithms) != {"fastsw"}:
            raise ValueError(f"a live bound needs algorithms ['fastsw'], got {list(algorithms)}")
    pool = _Pool(streams)
    if tuple(poses) not in CALIBRATIONS:
        raise ValueError(f"calibration must be one of {CALIBRATIONS}, got {tuple(poses)}")
    runs = [(a, bound, th) for a in algorithms for bound in (live_bounds or (0.0,)) for th in thresholds]
    rows = []
    for a, bound, th in runs:
        rows.append(evaluate_threshold(pool, a, th, max_len, bound, predictor, live, poses, angles))
        if progress is not None:
            progress(len(rows), len(runs))
    return rows


def at_icr(
    rows: Sequence[dict], algorithm: str, targets: Sequence[float] = ICR_TARGETS,
    live_bound: float | None = None,
) -> list[dict]:
    """Measures of one algorithm (and live bound, unless None) interpolated at given ICRs
    (linear in log ICR).

    Rows with equal ICR are averaged first; a target outside the swept ICR range gives NaN.

    Returns
    -------
    list of dict: ``algorithm``, ``icr`` (the target), the :data:`MEASURES` and ``threshold``
    (interpolated in log threshold, NaN where a bracketing threshold is 0).
    """
    own = [
        r for r in rows if r["algorithm"] == algorithm and np.isfinite(r["icr"]) and r["icr"] > 0
        and (live_bound is None or r.get("live_bound", 0.0) == live_bound)
    ]
    out = []
    if not own:
        return [
            {"algorithm": algorithm, "icr": c, "threshold": math.nan}
            | dict.fromkeys(MEASURES, math.nan)
            for c in targets
        ]
    icr = np.array([r["icr"] for r in own])
    unique, inverse = np.unique(icr, return_inverse=True)
    x = np.log(unique)

    def curve(field: str, log: bool = False) -> np.ndarray:
        values = np.array([r.get(field, math.nan) for r in own], np.float64)
        if log:
            with np.errstate(divide="ignore"):
                values = np.log(values)
        sums = np.bincount(inverse, weights=values, minlength=len(unique))
        return sums / np.bincount(inverse, minlength=len(unique))

    for c in targets:
        row = {"algorithm": algorithm, "icr": float(c)}
        inside = unique[0] <= c <= unique[-1]
        for field in MEASURES:
            row[field] = float(np.interp(np.log(c), x, curve(field))) if inside else math.nan
        th = (
            float(np.exp(np.interp(np.log(c), x, curve("threshold", log=True))))
            if inside
            else math.nan
        )
        row["threshold"] = th
        out.append(row)
    return out
