"""The threshold sweep of the paper's protocol: every stream segmented at each threshold, rebuilt
by SLERP and compared with its samples (the measures: :mod:`limbstream.evaluation`)."""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from limbstream import calibration, joints, kernel, quat, wire
from limbstream.body import FULL, PAPER10, Layout
from limbstream.sources import Motion
from limbstream.sources.bvh_positions import BvhPositions
from limbstream.evaluation.fusion import FIGURES, EarthTruth, pooled_error
from limbstream.evaluation import body as bodies_of
from limbstream.evaluation import positions as positions_of
from limbstream.evaluation import translation
from limbstream.evaluation.live_model import accepted, segment_live

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
    "live_bound_deg",
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
    *(f"{stage}_{figure}" for stage in ("fusion", "chain") for figure in FIGURES),
    "joint_aad",
    "pos_cm",
)
"""Fields of one result row, in output order."""

MEASURES: tuple[str, ...] = KEYS[5:]
"""The measures of a row: degrees, ``pos_cm`` centimetres."""

EXTRAS: tuple[str, ...] = ("joint_kinds", "joints", "positions", "translation", "heading_stopped")
"""A row's figures per joint (:func:`evaluate_threshold`), where scored."""


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
    earth : a raw sensor's stream (``q``: its device's orientation at the device's samples, Y
        up): the reference of its fusion and chain errors (BROAD's metric), None for others.
    source : the source file's own joint positions (``Motion.positions``), if it has them.
    source_offset_s : the source's time minus the stream's, s (NaN: unknown).
    layout : the body layout of its motion (:func:`.body.layout_of`), whose bodies it is put
        together into (None: ``paper10``).
    full_scale : an emulated raw sensor's share of raw samples read at its part's full scale
        (clipped: :meth:`limbstream.imu.ImuModel.at_full_scale`), 0 for others.
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
    earth: EarthTruth | None = None
    source: BvhPositions | None = None
    source_offset_s: float = 0.0
    layout: Layout | None = None
    full_scale: float = 0.0


def streams_of(motions: Iterable[Motion], sensors: calibration.SensorModel | None = None,
               layout: Layout | None = None) -> list[Stream]:
    """Every segment stream of every motion (S streams per motion); with a sensor model that is
    on, each motion preceded by the calibration script and seen through its sensors (drawn per
    motion). Their bodies are of ``layout`` (None: each motion's own, :func:`.body.layout_of`)."""
    out = []
    for i, motion in enumerate(motions):
        if sensors is not None and sensors.on:
            out.extend(_sensor_streams(motion, sensors, i, bodies_of.layout_of(motion, layout)))
            continue
        for s, segment in enumerate(motion.segments):
            out.append(
                Stream(
                    np.asarray(motion.t, np.float64),
                    np.asarray(motion.q[:, s, :], np.float64),
                    f"{motion.name}/{segment}",
                    rest_pose=motion.rest_pose,
                    layout=bodies_of.layout_of(motion, layout),
                    **positions_of.source_of(motion),
                )
            )
    return out


def _sensor_streams(motion: Motion, sensors: calibration.SensorModel, index: int, layout: Layout) -> list[Stream]:
    """A motion's streams as its sensors report them, after the calibration script."""
    t = np.asarray(motion.t, np.float64)
    fs = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else wire.DEVICE_RATE_HZ
    q, rest, mounting = calibration.with_script(motion.q, fs, motion.segments)
    start = len(q) - len(t)
    t = np.concatenate([t[0] - np.arange(start, 0, -1) / fs, t]) if len(t) else np.arange(len(q)) / fs
    draws = sensors.draw(len(motion.segments), stream=index)
    pose = calibration.mounting_pose(motion.segments)
    return [Stream(t, draws.report(s, t - t[0], q[:, s]), f"{motion.name}/{segment}", truth=q[:, s], rest=rest,
                   mounting=mounting, pose=pose[s], motion_from=start, rest_pose=motion.rest_pose, layout=layout,
                   **positions_of.source_of(motion))
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
            self.accepted[self.start[j] + accepted(s.t, np.asarray(s.q, np.float64))] = True
        self.fusion = self.earth_errors(self.q)  # the devices' own samples against the truth

    def earth_errors(self, q: np.ndarray) -> dict[str, float]:
        """BROAD's figures (:func:`pooled_error`) of pooled orientations ``q`` (n, 4), Y up (the
        samples or a reconstruction), over the streams with an ``earth`` reference."""
        parts = [(quat.multiply(_EARTH, q[self.start[j]:self.start[j + 1]]), s.t, s.earth)
                 for j, s in enumerate(self.streams) if s.earth is not None]
        return pooled_error(parts) if parts else dict.fromkeys(FIGURES, math.nan)


_EARTH = quat.conjugate(quat.Z_UP_TO_Y_UP)
"""Turns limbstream's world (Y up) back into a filter's earth frame (Z up)."""


def _stats(dev: np.ndarray) -> tuple[float, float, float, float]:
    """mean, std, p99, max of (n,) degrees; NaN if empty."""
    if dev.size == 0:
        return (math.nan,) * 4
    return float(dev.mean()), float(dev.std()), float(np.percentile(dev, 99)), float(dev.max())


@dataclass
class _Points:
    """The segment points of every stream of a pool at one threshold: per stream with points, their
    time keys on the pool's shared axis, unit quaternions and deviations from the samples; with
    ``live``, what the live view needs (sample positions they are known from, quaternions, times,
    rates, owners); and how many."""

    key: list[np.ndarray] = field(default_factory=list)
    q: list[np.ndarray] = field(default_factory=list)
    dev: list[np.ndarray] = field(default_factory=list)
    owners: list[int] = field(default_factory=list)
    live_pos: list[np.ndarray] = field(default_factory=list)
    live_q: list[np.ndarray] = field(default_factory=list)
    live_t: list[np.ndarray] = field(default_factory=list)
    live_omega: list[np.ndarray] = field(default_factory=list)
    live_owner: list[np.ndarray] = field(default_factory=list)
    n: int = 0


def _segment_pool(pool: _Pool, algorithm: str, threshold: float, max_len: int, live_bound_deg: float,
                  predictor: str | None) -> _Points:
    """Every stream of ``pool`` segmented (:func:`segment_live`; ``predictor`` None: no live view)."""
    pts = _Points()
    for j, stream in enumerate(pool.streams):
        if len(stream.t) == 0:
            continue
        index, seg_t, seg_q, known, omega = segment_live(stream.t, stream.q, algorithm, threshold, max_len,
                                                         live_bound_deg, predictor)
        k = len(seg_t)
        if k == 0:  # every sample rejected: nothing to rebuild this stream from
            continue
        pts.n += k
        if predictor is not None and omega is not None:
            pts.live_pos.append(pool.start[j] + known)
            pts.live_q.append(quat.normalize(seg_q))
            pts.live_t.append(seg_t)
            pts.live_omega.append(omega)
            pts.live_owner.append(np.full(k, j))
        pts.dev.append(quat.angle_deg(stream.q[index], seg_q))
        q_points = quat.normalize(seg_q)
        key = seg_t - pool.t0[j] + pool.offset[j]
        if k == 1:  # a single point: hold it (zero-length span)
            key, q_points = np.repeat(key, 2), np.repeat(q_points, 2, axis=0)
        pts.key.append(key)
        pts.q.append(q_points)
        pts.owners.append(j)
    return pts


def _reconstruct(pool: _Pool, pts: _Points) -> tuple[np.ndarray, np.ndarray]:
    """(mask, recon): the samples of the streams with points, and their reconstruction by SLERP
    between the points of their own stream."""
    keys = np.concatenate(pts.key)
    q_points = np.concatenate(pts.q)
    counts = np.array([len(p) for p in pts.key])
    have = np.zeros(len(pool.streams), bool)
    first = np.zeros(len(pool.streams), np.int64)
    have[pts.owners] = True
    first[pts.owners] = np.concatenate([[0], np.cumsum(counts)[:-1]])
    last = first.copy()
    last[pts.owners] += counts - 1
    mask = pool.valid & have[pool.stream_of]
    sample_key = pool.key[mask]
    owner = pool.stream_of[mask]
    k = np.searchsorted(keys, sample_key, side="right") - 1
    k = np.clip(k, first[owner], last[owner] - 1)  # stay inside the sample's own stream
    span = keys[k + 1] - keys[k]
    u = np.clip((sample_key - keys[k]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    return mask, quat.slerp(q_points[k], q_points[k + 1], u)


def _mean_max(values: np.ndarray) -> tuple[float, float]:
    return (float(values.mean()), float(values.max())) if values.size else (math.nan, math.nan)


def evaluate_threshold(
    pool: _Pool, algorithm: str, threshold: float, max_len: int = MAX_LEN, live_bound_deg: float = 0.0,
    predictor: str = "rate", live: bool = False, poses: Sequence[str] = CALIBRATIONS[-1], angles: bool = False,
    heading: bool = False, dump_to: Path | None = None,
) -> dict:
    """Segment every stream of ``pool`` at one threshold (and live bound) and measure the result
    (the live error only if ``live``: it costs about as much as the reconstruction; else the
    ``live_*`` fields are NaN). Streams with a truth (a sensor model) are calibrated from their
    reconstruction with ``poses`` (one of :data:`CALIBRATIONS`) for ``body_aad``, and with
    ``heading`` their bodies' headings are then held by the joints (:mod:`.body`). The row's
    ``joint_aad`` and ``joint_kinds`` are the joint error (:func:`.body.joint_figures`), its
    ``pos_cm`` and ``positions`` the joint position error (:func:`.positions.position_figures`). With
    ``angles`` the row also holds ``joints``: per joint angle the error figures of the
    (calibrated) reconstruction's angles against the truth's (:func:`limbstream.joints.pooled_errors`).
    With ``dump_to`` (a folder) each body is written there (:func:`.body.dump`).

    Returns
    -------
    dict with the fields of :data:`KEYS` (degrees for the angular measures, cm for ``pos_cm``)
    and the :data:`EXTRAS`.
    """
    if live_bound_deg > 0 and algorithm != "fastsw":
        raise ValueError(f"the live rule is fastSW's, not {algorithm!r}'s")
    pts = _segment_pool(pool, algorithm, threshold, max_len, live_bound_deg, predictor if live else None)
    icr = pts.n / pool.n_samples if pool.n_samples else math.nan
    row = {"algorithm": algorithm, "threshold": float(threshold), "live_bound_deg": float(live_bound_deg),
           "predictor": predictor if live else None, "icr": icr}
    fusion = {f"fusion_{k}": v for k, v in pool.fusion.items()}
    if not pts.key:
        return row | dict.fromkeys(MEASURES, math.nan) | fusion
    errors = (_live_errors(pool, np.concatenate(pts.live_pos), np.concatenate(pts.live_q), np.concatenate(pts.live_t),
                           np.concatenate(pts.live_omega), np.concatenate(pts.live_owner))
              if live and pts.live_pos else np.zeros(0))
    mask, recon = _reconstruct(pool, pts)
    aad, std, p99, mx = _stats(quat.angle_deg(pool.q_unit[mask], recon))
    rec = np.full((pool.n_samples, 4), np.nan)
    rec[mask] = recon
    calibrated = _calibrated(pool, rec, poses)
    bodies = bodies_of.bodies(pool, rec, calibrated)
    for b in bodies if heading else ():
        bodies_of.correct_heading(b)
        for k, j in b.streams.items():
            if j in calibrated:
                calibrated[j] = (b.estimated[:, k], *calibrated[j][1:])
    body = (np.concatenate([quat.angle_deg(c[ok], t[ok]) for c, t, ok in calibrated.values()])
            if calibrated else np.zeros(0))
    row["joint_aad"], row["joint_kinds"] = bodies_of.joint_figures(bodies)
    stopped = [{"motion": b.name, "at_s": b.stopped_s, "joints": b.contradicted} for b in bodies if b.contradicted]
    if stopped:  # motions whose joints contradict their constraints: heading correction stopped
        row["heading_stopped"] = stopped
    places = [positions_of.positions_of(b) for b in bodies]
    row["pos_cm"], row["positions"] = positions_of.position_figures(places)
    moved = [f for b, p in zip(bodies, places) if (f := translation.translation_of(b, p)) is not None]
    if moved:  # only motions with a root path that travels have figures
        row["translation"] = moved
    if angles:
        widest = FULL if any(b.layout == FULL for b in bodies) else PAPER10  # full's angles hold paper10's
        row["joints"] = joints.pooled_errors([(b.estimated, b.truth, b.rest_pose, b.layout) for b in bodies], widest)
    if dump_to is not None:
        for b, place in zip(bodies, places):
            bodies_of.dump(b, dump_to, "joints" if heading else "off", place)
    pdev = np.concatenate(pts.dev)
    point_aad, point_max = _mean_max(pdev[np.isfinite(pdev)])
    live_aad, live_max = _mean_max(errors)
    chain = {f"chain_{k}": v for k, v in pool.earth_errors(rec).items()}
    row |= {
        "aad": aad, "std": std, "p99": p99, "max": mx, "point_aad": point_aad, "point_max": point_max,
        "live_aad": live_aad, "live_p99": float(np.percentile(errors, 99)) if errors.size else math.nan,
        "live_max": live_max, "body_aad": float(body.mean()) if body.size else math.nan,
    } | fusion | chain
    return {k: row[k] for k in KEYS} | {k: row[k] for k in EXTRAS if k in row}


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
               if "rest" in poses and s.rest is not None else calibration.Calibration.none())
        motion, truth = r[s.motion_from:], s.truth[s.motion_from:]
        ok = np.isfinite(motion).all(axis=1) & np.isfinite(truth).all(axis=1)
        calibrated = np.full(motion.shape, np.nan)
        calibrated[ok] = cal.apply(motion[ok])
        out[j] = (calibrated, truth, ok)
    return out


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
    thresholds: Sequence[float] | np.ndarray = THRESHOLDS,
    max_len: int = MAX_LEN,
    live_bound_deg: Sequence[float] | None = None,
    predictor: str = "rate",
    poses: Sequence[str] = CALIBRATIONS[-1],
    progress: Callable[[int, int], None] | None = None,
    angles: bool = False,
    heading: bool = False,
    dump_to: Path | None = None,
) -> list[dict]:
    """Run the protocol: one row per (algorithm, live bound, threshold), in that order.

    Parameters
    ----------
    motions : Motion objects (every segment stream is used) or :class:`Stream` objects.
    algorithms : keys of :data:`limbstream.kernel.ALGORITHMS`.
    thresholds : (T,) thresholds, >= 0, each algorithm's own unit.
    max_len : largest segment length, samples.
    live_bound_deg : fastSW live rule bounds, degrees in [0, 180) (0: the plain rules; a bound
        above 0 needs algorithms == ["fastsw"]); None: the plain rules, and no live error
        (the ``live_*`` fields are NaN).
    predictor : the points' rates for the live error, one of :data:`PREDICTORS`.
    poses : the calibration before ``body_aad`` (streams with a truth), one of :data:`CALIBRATIONS`.
    progress : called with (rows done, rows in all) after each row.
    angles : also score the joint angles (each row's ``joints``, :func:`evaluate_threshold`).
    heading : hold the calibrated bodies' headings by their joints (:func:`evaluate_threshold`).
    dump_to : a folder to write each body into (one row only: its files would be overwritten by
        the next row's).

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
    live = live_bound_deg is not None
    for bound in live_bound_deg or ():
        if kernel.LIVE_BOUND.check(bound) > 0 and set(algorithms) != {"fastsw"}:
            raise ValueError(f"a live bound needs algorithms ['fastsw'], got {list(algorithms)}")
    pool = _Pool(streams)
    if tuple(poses) not in CALIBRATIONS:
        raise ValueError(f"calibration must be one of {CALIBRATIONS}, got {tuple(poses)}")
    runs = [(a, bound, th) for a in algorithms for bound in (live_bound_deg or (0.0,)) for th in thresholds]
    if dump_to is not None and len(runs) != 1:
        raise ValueError(f"a dump holds one row's orientations, not {len(runs)} rows' (one algorithm, live bound "
                         "and threshold)")
    rows = []
    for a, bound, th in runs:
        rows.append(evaluate_threshold(pool, a, th, max_len, bound, predictor, live, poses, angles, heading, dump_to))
        if progress is not None:
            progress(len(rows), len(runs))
    return rows


def at_icr(
    rows: Sequence[dict], algorithm: str, targets: Sequence[float] = ICR_TARGETS,
    live_bound_deg: float | None = None,
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
        and (live_bound_deg is None or r.get("live_bound_deg", 0.0) == live_bound_deg)
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
        for measure in MEASURES:
            row[measure] = float(np.interp(np.log(c), x, curve(measure))) if inside else math.nan
        th = (
            float(np.exp(np.interp(np.log(c), x, curve("threshold", log=True))))
            if inside
            else math.nan
        )
        row["threshold"] = th
        out.append(row)
    return out
