"""Heading correction in the aggregator (services/aggregator/heading.py), fed by hand tick by
tick as a drain feeds it: calibrated devices whose headings drift get their heading held by the
joints before fusion; the subject's joint error (``joint_aad_deg``) shows it, the devices' stats
show each correction, its rate and confidence; a device that restarts rejoins with its correction
learnt afresh, never the stale one; ``off`` leaves the frames as calibrated."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from limbstream import calibration, kernel, quat, wire
from limbstream.heading import HeadingCorrection
from limbstream.heading.joints import Layout, joint_errors_deg
from limbstream.heading.settings import Settings
from limbstream.heading.simulate import zero_pose_along_x
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
from limbstream.sources.generator import generate
from limbstream.wire import SEGMENTS

FS = 50.0
T0 = 1_790_000_000_000_000
STEP_US = 20_000
SECONDS = 60.0
RESTART_S = 45.0
RESTARTED = "r_shank"
DRIFT_DPS = 0.1


def stream(reading: np.ndarray, first: int, stream_id: int) -> list[tuple[int, bytes]]:
    """(arrival tick, payload) of the live-mode segment points of one device's readings (m, 4),
    whose samples start at tick ``first``."""
    t = np.arange(len(reading)) / FS
    seg = kernel.segment(t, reading, 9e-4, 25, live_bound_deg=5.0)
    out = []
    for n, k in enumerate(seg.index.tolist()):
        omega = tuple(float(v) for v in quat.through_rate(reading[k - 1], reading[k], -1 / FS)) if k else None
        point = wire.SegmentPoint(stream_id, n, k, T0 + (first + k) * STEP_US, tuple(map(float, reading[k])), 0, omega)
        out.append((first + k + 1, wire.encode_point(point)))
    return out


def truth(q: np.ndarray, first: int, stream_id: int) -> list[tuple[int, bytes]]:
    """(arrival tick, payload) of truth batches of 25 samples of ``q`` (m, 4) from tick ``first``,
    with reference times."""
    out = []
    for b in range(0, len(q) - 24, 25):
        t_us = T0 + (first + np.arange(b, b + 25, dtype=np.int64)) * STEP_US
        out.append((first + b + 26, wire.encode_raw(wire.RawBatch(stream_id, b, t_us, q[b:b + 25].astype(np.float32),
                                                                   t_us))))
    return out


SUBJECTS = (("s01", SEGMENTS, RESTART_S), ("s02", ("l_shank", "r_shank", "l_thigh", "r_thigh", "hip"), None))
"""The subjects of the sessions: (name, the segments that have a device, when the right shank
restarts or None). s02 is a lower body alone (pelvis, thighs, shanks: no arms, no neck) that never
restarts; both wear the same sensors on the same motion, in one aggregator."""
LOWER_BODY = SUBJECTS[1][1]


def session(heading: bool, subjects=SUBJECTS, seconds: float = SECONDS, mislabelled: tuple[str, ...] = ()):
    """Subjects of one motion, their sensors strapped at up to 90 deg with headings anywhere and
    drifting (up to DRIFT_DPS), the calibration script first; a subject's right shank restarts
    at its restart time (s; None: never) with a new stream that begins with the script again (its
    heading elsewhere), with heading correction ``heading`` or none; only a subject's segments
    have a device; the subjects ``mislabelled`` wear the motion as a source whose zero pose has
    every bone along +X labelled as its rest pose gives it
    (:func:`limbstream.heading.simulate.zero_pose_along_x`). Returns the aggregator, each subject's exact frames as (t_us, q (10, 4)), its
    stats each second (by subject name), and the truth (m, 10, 4) by tick."""
    motion = generate(seconds, FS, seed=21)
    q, _, _ = calibration.with_script(motion.q, FS)
    wrong, _, _ = calibration.with_script(zero_pose_along_x(motion.q, motion.segments, motion.rest_pose), FS)
    m = len(q)
    sensors = calibration.SensorModel(90, 180, DRIFT_DPS, seed=5).draw(len(SEGMENTS))
    t = np.arange(m) / FS
    events: dict[int, list[tuple[str, str, bytes]]] = {}
    for name, segments, restart in subjects:
        k = round((restart or seconds) * FS)
        worn = wrong if name in mislabelled else q
        for j, seg in enumerate(SEGMENTS):
            if seg not in segments:
                continue
            reading = sensors.report(j, t, worn[:, j])
            parts = [(0, reading, worn[:, j], 1)]
            if seg == RESTARTED and restart is not None:  # the restart: the script again, a new filter heading
                again, _, _ = calibration.with_script(motion.q[k:, None, j], FS, (seg,))
                later = calibration.SensorModel(90, 180, DRIFT_DPS, seed=9).draw(len(SEGMENTS))
                parts = [(0, reading[:k], q[:k, j], 1),
                         (k, later.report(j, np.arange(len(again)) / FS, again[:, 0])[:m - k], again[:m - k, 0], 2)]
            for first, r, true, sid in parts:
                for tick, payload in stream(r, first, sid):
                    events.setdefault(tick, []).append(("seg", wire.seg_key(name, seg), payload))
                for tick, payload in truth(true, first, sid):
                    events.setdefault(tick, []).append(("raw", wire.raw_key(name, seg), payload))
    agg = Aggregator(None, AggregatorSettings(calibrate_on_start=True, heading_correction=heading))
    exact: dict[str, list[tuple[int, np.ndarray]]] = {name: [] for name, _, _ in subjects}
    agg._publish = lambda subject, payload: exact[subject].extend(
        [(f.t_us, f.q)] if (f := wire.decode_pose(payload)).kind == wire.KIND_EXACT else [])
    for name, segments, _ in subjects:
        for seg in segments:
            agg.on_alive(wire.alive_key(name, seg), True)
    stats: dict[str, list[dict]] = {name: [] for name, _, _ in subjects}
    for tick in range(m + 30):
        now = tick / FS
        mine = events.get(tick, [])
        for kind in ("seg", "raw"):
            keys = [key for what, key, _ in mine if what == kind]
            if keys:
                (agg.take_points if kind == "seg" else agg.take_raw)(
                    keys, [p for what, _, p in mine if what == kind], now)
        agg.advance(True, tick % 25 == 0, now)
        if tick % 50 == 49:
            for name in stats:
                stats[name].append(agg.subject_stats(name, now))
    return agg, exact, stats, q


@pytest.fixture(scope="module")
def runs():
    """The session without and with heading correction (``off``, ``joints``); what the estimator
    took for s01 in the ``joints`` one (its ``take`` spied on): ``seen``, (q (R, 10, 4), present
    (R, 10)) per call."""
    seen: list[tuple[HeadingCorrection, np.ndarray, np.ndarray, np.ndarray]] = []
    real = HeadingCorrection.take

    def take(self, rows, q, present=None):
        seen.append((self, np.asarray(rows).copy(), q.copy(), present.copy()))
        return real(self, rows, q, present)

    out = {"off": session(False)}
    HeadingCorrection.take = take  # type: ignore[method-assign]
    try:
        out["joints"] = session(True)
    finally:
        HeadingCorrection.take = real  # type: ignore[method-assign]
    agg = out["joints"][0]
    pose, row = agg.fusion.heading.place[agg.subjects["s01"].index]
    est = agg.fusion.heading.estimators[pose]
    return out | {"seen": [(q[rows == row], present[rows == row]) for e, rows, q, present in seen if e is est]}


def frames_of(exact: list[tuple[int, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """(ticks (F,), orientations (F, 10, 4) float64) of exact frames."""
    return np.array([(t - T0) // STEP_US for t, _ in exact]), np.array([f for _, f in exact], np.float64)


def test_the_frames_are_the_calibrated_ones_turned_by_what_the_joints_hold(runs):
    """Each exact frame's segment is its calibrated reconstruction turned about the vertical; the
    turns of a frame average 0 over its corrected devices; the estimator learnt from every frame
    since the devices were calibrated; the joints are nearer the truth for it."""
    _, off_frames, off_stats, q = runs["off"]
    agg, on_frames, on_stats, _ = runs["joints"]
    ticks, off = frames_of(off_frames["s01"])
    ticks_on, on = frames_of(on_frames["s01"])
    assert np.array_equal(ticks, ticks_on)
    turn = quat.multiply(on, quat.conjugate(off))  # world-frame turn of each segment
    assert np.abs(turn[..., [1, 3]]).max() < 1e-5  # about the vertical only
    angle = 2 * np.degrees(np.arctan2(turn[..., 2], turn[..., 0]))
    taken = int(agg.fusion.heading.taken[agg.subjects["s01"].index])
    learnt = slice(len(ticks) - taken, round((RESTART_S - 1) * FS))  # every frame since calibration, all devices
    assert taken > 0.8 * len(ticks) and np.abs(angle[:learnt.start]).max() < 1e-3
    assert np.abs(angle[learnt].mean(axis=1)).max() < 1e-3 and np.abs(angle[learnt]).max() > 1.0
    layout = Layout.of(SEGMENTS)
    late = (ticks > (SECONDS - 10) * FS) & (ticks < len(q))
    no_knee = [j for j, name in enumerate(layout.joints) if name != "knee_r"]  # (the restarted shank's)
    before = joint_errors_deg(off[late], q[ticks[late]], layout)[:, no_knee].mean()
    after = joint_errors_deg(on[late], q[ticks[late]], layout)[:, no_knee].mean()
    assert after < 0.85 * before, (before, after)
    assert on_stats["s01"][-1]["joint_aad_deg"] < off_stats["s01"][-1]["joint_aad_deg"], (on_stats["s01"][-1],
                                                                                      off_stats["s01"][-1])


def test_the_estimator_learns_from_the_calibrated_frames_exactly(runs):
    """What the estimator takes is each exact frame's calibrated reconstruction (the turn put on
    after SLERP taken off again), where the device is corrected and present."""
    _, off_frames, _, _ = runs["off"]
    ticks, off = frames_of(off_frames["s01"])
    q = np.concatenate([s[0] for s in runs["seen"]])  # (one subject: its frames in order)
    present = np.concatenate([s[1] for s in runs["seen"]])
    agg = runs["joints"][0]
    assert len(q) == agg.fusion.heading.taken[agg.subjects["s01"].index]
    mine = off[len(off) - len(q):]  # the frames since calibration
    before = ticks[len(off) - len(q):] < (RESTART_S - 1) * FS
    assert before.sum() > 1000 and present[before].all()
    assert quat.angle_deg(q[present], mine[present]).max() < 1e-4
    shank = SEGMENTS.index(RESTARTED)  # absent from its restart until calibrated again
    assert not present[~before][100:200, shank].any() and present[-1].all()


def test_the_devices_stats_say_each_correction(runs):
    off_stats = runs["off"][2]["s01"]
    stats = runs["joints"][2]["s01"]
    devices = {d["segment"]: d for d in stats[round(RESTART_S) - 2]["devices"]}
    assert all(d["calibrated"] for d in devices.values())
    offsets = np.array([d["heading_offset_deg"] for d in devices.values()])
    assert np.isfinite(offsets).all() and abs(offsets.mean()) < 1e-3 and np.abs(offsets).max() > 1.0, offsets
    assert all(0.0 < d["heading_confidence"] <= 1.0 and d["heading_rate_dpm"] is not None for d in devices.values())
    assert all(d["heading_offset_deg"] is None for d in off_stats[-1]["devices"])
    assert off_stats[-1]["joint_aad_deg"] is not None


def test_a_restarted_device_rejoins_with_its_correction_learnt_afresh(runs):
    stats = runs["joints"][2]["s01"]
    shank = [next(d for d in s["devices"] if d["segment"] == RESTARTED) for s in stats]
    at = round(RESTART_S) - 1
    assert shank[at - 1]["stream"] == 1 and shank[at + 1]["stream"] == 2
    assert abs(shank[at - 1]["heading_offset_deg"]) > 0.5  # a correction learnt before the restart
    assert shank[at + 1]["heading_offset_deg"] is None  # not corrected until calibrated again (script: 5.5 s)
    back = next(i for i in range(at + 1, len(shank)) if shank[i]["calibrated"])
    thigh = next(d for d in stats[back]["devices"] if d["segment"] == "r_thigh")
    assert abs(shank[back]["heading_offset_deg"] - thigh["heading_offset_deg"]) < 1.0  # from none, not the old one
    assert shank[-1]["heading_confidence"] > 0.0


def test_a_lower_body_alone_is_corrected(runs):
    """Pelvis, thighs and shanks only (no arms, no neck: s02): their devices are corrected (the
    turns averaging 0 over the five) and their knees' and hips' error against the truth is lower
    for it."""
    figures = {}
    for heading, run in ((False, "off"), (True, "joints")):
        _, exact, by_subject, q = runs[run]
        stats = by_subject["s02"]
        ticks, frames = frames_of(exact["s02"])
        late = (ticks > (SECONDS - 10) * FS) & (ticks < len(q))
        layout = Layout.of(LOWER_BODY)
        have = [SEGMENTS.index(s) for s in LOWER_BODY]
        figures[heading] = joint_errors_deg(frames[late][:, have], q[ticks[late]][:, have], layout).mean()
        devices = stats[-1]["devices"]
        assert sorted(d["segment"] for d in devices) == sorted(LOWER_BODY)
        offsets = [d["heading_offset_deg"] for d in devices]
        if heading:
            assert all(o is not None for o in offsets) and abs(np.mean(offsets)) < 1e-3, offsets
            assert stats[-1]["joint_aad_deg"] is not None
        else:
            assert all(o is None for o in offsets)
    assert figures[True] < 0.85 * figures[False], figures


@pytest.mark.parametrize("saved", [True, False], ids=["kept", "not kept"])
def test_a_calibration_kept_from_before_keeps_its_joints_headings_known_as_its_age_allows(tmp_path, saved):
    """An aggregator restarted with its calibration file, its subject's frames already learnt
    from when the right shank's stream comes: the shank's calibration comes back, and so does what
    it tells of its joint's heading, widened by the heading's drift since it was made
    (``delta0_deg`` and ``rate0_dps`` per second; 30 s ago: 1.8 deg), not half a turn either way
    (learning the knee from nothing turned the leg by up to 9 deg in the live test of this,
    tests/test_calibration.py). A shank whose calibration was not kept has its knee anywhere."""
    made = {"stream": 1, "made_at": time.time() - 30.0} | calibration.Calibration(("rest",), np.array([1.0, 0, 0, 0]),
                                                                                 0.0).as_dict()
    kept = [s for s in SEGMENTS if saved or s != RESTARTED]
    path = tmp_path / "calibrations.json"
    path.write_text(json.dumps({f"s01/{s}": made for s in kept}))
    agg = Aggregator(None, AggregatorSettings(calibrate_on_start=True, calibration_file=str(path)))
    agg._publish = lambda subject, payload: None
    still = wire.encode_point(wire.SegmentPoint(1, 0, 0, T0, (1.0, 0.0, 0.0, 0.0)))
    first = [s for s in SEGMENTS if s != RESTARTED]
    for seg in SEGMENTS:
        agg.on_alive(wire.alive_key("s01", seg), True)
    for tick in range(100):
        point = wire.encode_point(wire.SegmentPoint(1, tick, tick, T0 + tick * STEP_US, (1.0, 0.0, 0.0, 0.0)))
        agg.take_points([wire.seg_key("s01", s) for s in first], [point] * len(first), tick / FS)
        agg.advance(True, tick % 25 == 0, tick / FS)
    where = agg.fusion.heading.place[agg.subjects["s01"].index]
    assert where is not None, "no frame learnt from yet"
    agg.take_points([wire.seg_key("s01", RESTARTED)], [still], 100 / FS)
    devices = {d["segment"]: d for d in agg.subject_stats("s01", 100 / FS)["devices"]}
    assert devices[RESTARTED]["calibrated"] is saved
    est = agg.fusion.heading.estimators[where[0]]
    sd = dict(zip(est.layout.joints, np.degrees(est.filters.delta_sd()[where[1]])))
    known = np.hypot(Settings().delta0_deg, 30.0 * Settings().rate0_dps)  # (+ the test's seconds: 0.05 deg each)
    assert sd["knee_r"] == pytest.approx(known if saved else 180.0, abs=0.1), sd
