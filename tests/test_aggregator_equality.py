"""The aggregator's batched computation against the plain one it replaced (tests/support/reference_aggregator,
the code of 8cc7f27 that took messages one by one): the same messages, tick by tick, into both; the
same pose frames (bit for bit, or within 1e-6 of each quaternion and joint coordinate) and the same
stats values (within 1e-9 relative) must come out.

The input is a scripted stream of several subjects with every rule the aggregator has to keep:
v1 and v2 points, truth with and without reference times, a gap, a duplicate, time going back,
a restart and a stale point of the old stream, a stream's end (FINAL), a device going offline and
back, a late-joined device whose start comes later (history), a subject whose devices join late,
undecodable payloads of known and unknown devices, bad keys, device statuses (max_len, clock, link),
too many devices; and, in a second run, calibrations made from each stream's script (and one
refused)."""
from __future__ import annotations

import math
import random

import numpy as np
import pytest
from support.reference_aggregator.aggregator import ReferenceAggregator

from limbstream import calibration, kernel, quat, wire
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
from limbstream.sources.generator import GeneratorSource
from limbstream.wire import SEGMENTS

FS = 50.0
TICK_S = 1 / FS
T0 = 1_790_000_000_000_000
STEP_US = 20_000
WALL0 = 1_790_000_000.0


class Scenario:
    """Messages by arrival tick: ("seg" | "raw", key, payload), ("alive", key, online) or
    ("config", key, payload)."""

    def __init__(self, ticks: int, seed: int):
        self.ticks: list[list[tuple]] = [[] for _ in range(ticks)]
        self.rng = random.Random(seed)

    def at(self, tick: int, *message) -> None:
        if tick < len(self.ticks):
            self.ticks[tick].append(message)

    def shuffled(self) -> list[list[tuple]]:
        """Each tick's messages with the devices interleaved at random, each device's in order."""
        out = []
        for messages in self.ticks:
            rank = {}
            for m in messages:
                rank.setdefault(m[1], self.rng.random())
            out.append(sorted(messages, key=lambda m: rank[m[1]]))
        return out


def points_of(q: np.ndarray, rate: bool, stream: int = 1, threshold: float = 1e-2) -> list[wire.SegmentPoint]:
    """fastSW's segment points of one device's orientations (m, 4); v2 (with a rate) if ``rate``."""
    t = np.arange(len(q)) / FS
    idx = kernel.segment(t, q, threshold, 25).index
    out = []
    for n, k in enumerate(idx):
        omega = None
        if rate and k > 0:
            omega = tuple(float(v) for v in quat.through_rate(q[k - 1], q[k], -1 / FS).astype(np.float32))
        out.append(wire.SegmentPoint(stream, n, int(k), T0 + int(k) * STEP_US, tuple(map(float, q[k])), 0, omega))
    return out


def deliver(sc: Scenario, subject: str, segment: str, points: list[wire.SegmentPoint], delay: int = 1,
            jitter: bool = True) -> None:
    """Each point in the tick after its sample (now and then one later), in order."""
    tick = 0
    for p in points:
        late = jitter and sc.rng.random() < 0.3
        tick = max(tick, (p.t_us - T0) // STEP_US + delay + late)
        sc.at(tick, "seg", wire.seg_key(subject, segment), wire.encode_point(p))


def truth(sc: Scenario, subject: str, segment: str, q: np.ndarray, ref: bool, stream: int = 1) -> None:
    """Truth batches of 25 samples, each in the tick after its last sample."""
    for b in range(0, len(q) - 25 + 1, 25):
        t_us = T0 + np.arange(b, b + 25, dtype=np.int64) * STEP_US
        batch = wire.RawBatch(stream, b, t_us, q[b:b + 25], t_us + 3_000 if ref else None)
        sc.at(b + 26, "raw", wire.raw_key(subject, segment), wire.encode_raw(batch))


def faults(sc: Scenario, subject: str, pts: dict[str, list[wire.SegmentPoint]], m: int) -> None:
    """The anomalies of one subject (its points by segment, changed in place)."""
    pts["l_shank"] = [p for p in pts["l_shank"] if p.seq not in (5, 6)]                    # a gap
    dup = pts["r_shank"][4]
    sc.at((dup.t_us - T0) // STEP_US + 4, "seg", wire.seg_key(subject, "r_shank"), wire.encode_point(dup))
    back = pts["r_shank"][8]
    sc.at((back.t_us - T0) // STEP_US, "seg", wire.seg_key(subject, "r_shank"),
          wire.encode_point(wire.SegmentPoint(1, back.seq, back.index, T0, back.q)))       # time going back
    half = m // 2
    thigh = pts["l_thigh"]
    first = next(i for i, p in enumerate(thigh) if p.index >= half)
    thigh[first:] = [wire.SegmentPoint(2, i, p.index - half, p.t_us, p.q, 0, p.omega)     # a restart
                     for i, p in enumerate(thigh[first:])]
    sc.at(half + 40, "seg", wire.seg_key(subject, "l_thigh"), wire.encode_point(pts["l_thigh"][first - 1]))
    end = [p for p in pts["r_thigh"] if p.index < 0.7 * m]
    pts["r_thigh"] = end + [wire.SegmentPoint(1, end[-1].seq + 1, end[-1].index, end[-1].t_us, end[-1].q,
                                              wire.FLAG_FINAL)]                                # its end
    sc.at(int(0.4 * m), "alive", wire.alive_key(subject, "l_lowerarm"), False)
    sc.at(int(0.6 * m), "alive", wire.alive_key(subject, "l_lowerarm"), True)
    late = pts["r_lowerarm"]                                                               # joined late
    for p in late[:8]:
        sc.at((late[8].t_us - T0) // STEP_US + 25, "seg", wire.seg_key(subject, "r_lowerarm"), wire.encode_point(p))
    pts["r_lowerarm"] = late[8:]
    good = wire.encode_point(pts["neck"][3])
    bad_q = wire.encode_point(wire.SegmentPoint(1, 3, 0, T0, (math.nan, 0.0, 0.0, 0.0)))
    long_q = wire.encode_point(wire.SegmentPoint(1, 3, 0, T0, (1.1, 0.0, 0.0, 0.0)))
    for i, payload in enumerate((good[:-1], bad_q, long_q, b"\x09" + good[1:], b"")):
        sc.at(30 + i, "seg", wire.seg_key(subject, "neck"), payload)
    sc.at(31, "seg", wire.seg_key("ghost", "neck"), bad_q)
    sc.at(32, "seg", "limbstream/ghost/neck/seg/more", good)
    sc.at(33, "raw", wire.raw_key("ghost", "hip"), b"\x01")
    sc.at(34, "seg", wire.raw_key(subject, "hip"), good)


def statuses(sc: Scenario, subject: str, tick: int) -> None:
    """Device statuses (as config replies): other max_len, clocks, one bridged device's link."""
    for j, segment in enumerate(SEGMENTS):
        clock = wire.ClockStatus(0.5 * j, 1.5, j % 2 == 0, {"late": j}) if j < 5 else None
        link = wire.LinkStatus("aa:bb/0", 80.0, -60.0, 0.01, 99.0) if segment == "hip" else None
        status = wire.DeviceStatus(wire.device_id(subject, segment), wire.DeviceConfig(max_len=10 + j), 1, 0, 0,
                                   clock, "tpose" if j == 0 else "standing", link)
        sc.at(tick, "config", wire.config_key(subject, segment), wire.encode_status(status))


def plain_scenario(subjects: int = 5, seconds: float = 8.0, seed: int = 1) -> list[list[tuple]]:
    m = int(seconds * FS)
    sc = Scenario(m + 60, seed)
    for s in range(subjects):
        name = f"s{s:02d}"
        q = GeneratorSource(s + 1, FS).chunk(0, m)[1].astype(np.float32)
        join = int(0.3 * m) if s == 3 else 0
        for segment in SEGMENTS:
            sc.at(join, "alive", wire.alive_key(name, segment), True)
        pts = {seg: points_of(q[:, j], rate=s % 2 == 1) for j, seg in enumerate(SEGMENTS)}
        if s == 0:
            faults(sc, name, pts, m)
        if s == 1:
            statuses(sc, name, 10)
        for j, seg in enumerate(SEGMENTS):
            deliver(sc, name, seg, [p for p in pts[seg] if p.index >= join])
            if s <= 2:
                truth(sc, name, seg, q[:, j], ref=s < 2)
    return sc.shuffled()


def calibrated_scenario(seconds: float = 10.0, seed: int = 2) -> list[list[tuple]]:
    """Two subjects whose streams begin with the calibration script, read through strapped
    sensors (truth in a world turned 40 deg); a third device joins mid-stream and is refused."""
    from limbstream.sources.generator import generate

    motion = generate(seconds, FS, seed=seed)
    q, _, _ = calibration.with_script(motion.q, FS)
    m = len(q)
    sc = Scenario(m + 60, seed)
    truth_q = quat.multiply(calibration.yaw(np.radians(40.0)), q).astype(np.float32)
    for s in range(2):
        name = f"c{s}"
        sensors = calibration.SensorModel(mounting_deg=90, heading_deg=180, seed=4 + s).draw(len(SEGMENTS))
        for j, seg in enumerate(SEGMENTS):
            sc.at(0, "alive", wire.alive_key(name, seg), True)
            reading = sensors.report(j, np.arange(m) / FS, q[:, j]).astype(np.float32)
            deliver(sc, name, seg, points_of(reading, rate=s == 1, threshold=9e-4))
            truth(sc, name, seg, truth_q[:, j], ref=True)
    sc.at(0, "alive", wire.alive_key("c2", "hip"), True)
    deliver(sc, "c2", "hip", points_of(q[:, 9].astype(np.float32), rate=False, threshold=9e-4)[5:])
    return sc.shuffled()


DRAIN_ORDER = ("alive", "seg", "raw", "config")
"""The order a drain takes a tick's messages in, kind by kind (each kind in arrival order)."""


def feed_reference(agg: ReferenceAggregator, messages: list[tuple], now: float) -> None:
    """A tick's messages, one by one."""
    for kind in DRAIN_ORDER:
        for _, key, value in (m for m in messages if m[0] == kind):
            if kind == "seg":
                agg.on_point(key, value, now)
            elif kind == "raw":
                agg.on_raw(key, value, now)
            elif kind == "alive":
                agg.on_alive(key, value)
            else:
                agg.on_config(key, value)


def feed(agg: Aggregator, messages: list[tuple], now: float) -> None:
    """A tick's messages as a drain takes them: the segment points as one batch, the truth
    batches as another."""
    for kind in DRAIN_ORDER:
        mine = [m for m in messages if m[0] == kind]
        if kind in ("seg", "raw") and mine:
            (agg.take_points if kind == "seg" else agg.take_raw)([m[1] for m in mine], [m[2] for m in mine], now)
        for _, key, value in mine if kind in ("alive", "config") else ():
            if kind == "alive":
                agg.on_alive(key, value)
            else:
                agg.on_config(key, value)


def run_both(ticks: list[list[tuple]], calibrate: bool, live_every: int, max_devices: int = 10_000):
    """Both aggregators through the scenario; (reference's published, new's published) as
    [(key, payload)] in publication order."""
    ref = ReferenceAggregator(calibrate_on_start=calibrate, max_devices=max_devices)
    new = Aggregator(None, AggregatorSettings(calibrate_on_start=calibrate, max_devices=max_devices,
                                              heading_correction=False))
    sent: list[tuple[str, bytes]] = []
    new._publish = lambda subject, payload: sent.append((wire.pose_key(subject), payload))
    new._publish_stats = lambda subject, payload: sent.append((wire.stats_key(subject), payload))
    jitter = random.Random(7)
    for k, messages in enumerate(ticks):
        now = 0.003 + k * TICK_S
        wall = WALL0 + now + jitter.uniform(0.0, 0.004)  # the publication clock is not the arrival clock
        feed_reference(ref, messages, now)
        feed(new, messages, now)
        live, prune = k % live_every == 0, k % 25 == 0
        ref.advance(live, prune, now, wall)
        new.advance(live, prune, now, wall=wall)
        ref.publish_stats(now, wall, k % 50, 50)
        new.publish_stats(now, k % 50, 50, wall=wall)
    return ref.sent, sent


def by_key(sent: list[tuple[str, bytes]]) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    for key, payload in sent:
        out.setdefault(key, []).append(payload)
    return out


def same_number(a, b, rel: float = 1e-9) -> bool:
    if a is None or b is None:
        return a is b
    if isinstance(a, float) or isinstance(b, float):
        return math.isclose(a, b, rel_tol=rel, abs_tol=1e-12)
    return a == b and type(a) is type(b)


def compare_frames(key: str, old: list[bytes], new: list[bytes]) -> None:
    assert len(old) == len(new), f"{key}: {len(old)} frames, now {len(new)}"
    for i, (a, b) in enumerate(zip(old, new)):
        if a == b:
            continue
        fa, fb = wire.decode_pose(a), wire.decode_pose(b)
        where = f"{key} frame {i} (kind {fa.kind}, seq {fa.seq})"
        # (NO_ROOT came after the plain aggregator: every paper10 frame carries it now)
        assert fb.flags & wire.FRAME_NO_ROOT and not fa.flags & wire.FRAME_NO_ROOT, where
        assert (fa.seq, fa.t_us, fa.kind, fa.flags) == (fb.seq, fb.t_us, fb.kind, fb.flags & ~wire.FRAME_NO_ROOT), where
        assert np.abs(fa.q - fb.q).max() <= 1e-6, (where, fa.q, fb.q)
        assert np.abs(fa.joints - fb.joints).max() <= 1e-6, (where, fa.joints, fb.joints)


LATER_FIELDS = {"joint_aad_deg", "live_missed", "heading_offset_deg", "heading_rate_dpm", "heading_confidence", "layout"}
"""Figures added after the plain aggregator (tests/test_aggregator_scoring.py checks them)."""


def compare_stats(key: str, old: list[bytes], new: list[bytes]) -> None:
    assert len(old) == len(new), f"{key}: {len(old)} stats messages, now {len(new)}"
    for a, b in zip(old, new):
        sa, sb = wire.decode_stats(a), wire.decode_stats(b)
        for name in ("subject", "seq", *(f.name for f in wire.SUBJECT_FIELDS if f.name not in LATER_FIELDS)):
            assert same_number(sa.get(name), sb.get(name)), (key, sa["seq"], name, sa.get(name), sb.get(name))
        for name in ("subjects", "points", "raw_batches", "frames", "bad_keys"):
            assert sa["aggregator"][name] == sb["aggregator"][name], (key, name, sa["aggregator"], sb["aggregator"])
        assert [d["device"] for d in sa["devices"]] == [d["device"] for d in sb["devices"]], key
        for da, db in zip(sa["devices"], sb["devices"]):
            for f in (f for f in wire.DEVICE_FIELDS if f.name not in LATER_FIELDS):
                va, vb = da[f.name], db[f.name]
                if f.name == "calibration_age_s":  # wall-clock age
                    assert (va is None) == (vb is None), (key, da["device"], va, vb)
                else:
                    assert same_number(va, vb), (key, sa["seq"], da["device"], f.name, va, vb)


def check_same(old_sent, new_sent) -> None:
    old, new = by_key(old_sent), by_key(new_sent)
    assert all(p[0] == wire.STATS_VERSION for k, p in new_sent if k.endswith("/stats")), "compact stats"
    assert sorted(old) == sorted(new), (sorted(old), sorted(new))
    for key in old:
        (compare_stats if key.endswith("/stats") else compare_frames)(key, old[key], new[key])


@pytest.mark.parametrize("live_every", [1, 5])
def test_the_batched_aggregator_publishes_what_the_plain_one_did(live_every):
    ticks = plain_scenario()
    old, new = run_both(ticks, calibrate=False, live_every=live_every, max_devices=45)
    assert sum(k.endswith("/pose") for k, _ in old) > 1000 and sum(k.endswith("/stats") for k, _ in old) > 30
    check_same(old, new)


def test_the_batched_aggregator_calibrates_and_scores_as_the_plain_one_did():
    old, new = run_both(calibrated_scenario(), calibrate=True, live_every=1)
    stats = wire.decode_stats([p for k, p in old if k == wire.stats_key("c0")][-1])
    assert all(d["calibrated"] for d in stats["devices"]) and abs(stats["facing_deg"] - 40.0) < 1.0, stats
    refused = wire.decode_stats([p for k, p in old if k == wire.stats_key("c2")][-1])["devices"][0]
    assert "never arrived" in refused["calibration_refused"], refused
    check_same(old, new)
