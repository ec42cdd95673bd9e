"""The aggregator's frame rules on hand-made message sequences (no Zenoh): when exact frames
become final, what holds them back, and what they are flagged with."""
from __future__ import annotations

import math

import numpy as np

from limbstream import wire
from limbstream.body import PAPER10
from limbstream.sources import SEGMENTS
from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
from limbstream.services.aggregator.frames import FIRST_FRAME_WAIT_S
from limbstream.services.aggregator.track import HISTORY_WAIT_S

T0 = 1_700_000_000_000_000
STEP_US = 100_000  # one segment point every 100 ms
IDENTITY = (1.0, 0.0, 0.0, 0.0)


def aggregator() -> tuple[Aggregator, list[wire.PoseFrame]]:
    """An aggregator without a session whose published frames are decoded into a list."""
    agg = Aggregator(None, AggregatorSettings())
    sent: list[wire.PoseFrame] = []
    agg._publish = lambda subject, payload: sent.append(wire.decode_pose(payload))
    return agg, sent


def send(agg: Aggregator, segment: str, seqs, now: float, subject: str = "s01", stream: int = 1) -> None:
    """Segment points of sequence numbers ``seqs`` (point k at T0 + k * 100 ms), arriving at ``now``."""
    for k in seqs:
        point = wire.SegmentPoint(stream, k, 5 * k, T0 + k * STEP_US, IDENTITY)
        agg.on_point(wire.seg_key(subject, segment), wire.encode_point(point), now)


def exact(frames: list[wire.PoseFrame]) -> list[wire.PoseFrame]:
    return [f for f in frames if f.kind == wire.KIND_EXACT]


def online_subject(agg: Aggregator, subject: str = "s01") -> None:
    for segment in SEGMENTS:
        agg.on_alive(wire.alive_key(subject, segment), True)


def test_frames_wait_for_the_slowest_device():
    agg, sent = aggregator()
    online_subject(agg)
    for segment in SEGMENTS[:-1]:
        send(agg, segment, range(11), now=0.0)          # 0 .. 1.0 s
    send(agg, SEGMENTS[-1], range(6), now=0.0)           # 0 .. 0.5 s
    agg.advance(live=False, now=0.0)
    assert [f.t_us - T0 for f in exact(sent)] == list(range(0, 500_001, 20_000)), "50 Hz grid up to the slowest"
    send(agg, SEGMENTS[-1], range(6, 11), now=0.1)
    agg.advance(live=False, now=0.1)
    frames = exact(sent)
    assert [f.t_us - T0 for f in frames] == list(range(0, 1_000_001, 20_000)), "no frame twice, none skipped"
    assert [f.seq for f in frames] == list(range(51)) and all(f.flags == wire.FRAME_NO_ROOT for f in frames)  # paper10: no feet


def test_a_frame_time_between_the_devices_first_stamps_is_the_subjects_first_frame():
    """The devices of a subject begin their streams together, but each stamps its first sample on
    its own clock, and the stamps fall either side of a frame time (T0 + 20 ms). An aggregator
    running when they began builds the frames up to the earliest stamp (its watermark); one
    restarted then, from the devices' history, must begin with the next frame time, not skip it
    (FIRST_POINT_REACH): the frame holds each late device at its first point, unflagged."""
    agg, sent = aggregator()
    online_subject(agg)
    for i, segment in enumerate(SEGMENTS):
        skew = -60 + 15 * i  # -60 .. +75 us about the frame time
        for k in range(6):
            point = wire.SegmentPoint(1, k, 5 * k, T0 + 20_000 + skew + k * STEP_US, IDENTITY)
            agg.on_point(wire.seg_key("s01", segment), wire.encode_point(point), 0.0)
    agg.advance(live=False, now=0.0)
    frames = exact(sent)
    assert [f.t_us - T0 for f in frames[:2]] == [20_000, 40_000]
    assert not any(f.flags & wire.FRAME_MISSING for f in frames)


def test_online_device_without_points_does_not_stall_its_subject():
    agg, sent = aggregator()
    online_subject(agg)
    for segment in SEGMENTS[:-1]:
        send(agg, segment, range(11), now=0.0)
    agg.advance(live=False, now=0.0)
    assert len(exact(sent)) == 51 and all(f.flags & wire.FRAME_MISSING for f in exact(sent))


def test_a_device_whose_stream_keeps_restarting_holds_a_subjects_first_frame_one_grace_period_at_most():
    """The first frame waits for every device's history, but a device that restarts its stream
    (seq 5 first, history pending) every 0.3 s must not keep the nine others from ever starting."""
    agg, sent = aggregator()
    online_subject(agg)
    for step in range(math.ceil(FIRST_FRAME_WAIT_S / 0.3) + 2):
        now = 0.3 * step
        for segment in SEGMENTS[:-1]:
            send(agg, segment, range(3 * step, 3 * step + 3), now=now)
        send(agg, SEGMENTS[-1], range(5, 8), now=now, stream=100 + step)
        agg.advance(live=False, now=now)
        if now < FIRST_FRAME_WAIT_S:
            assert not exact(sent), f"{now:.1f} s: still within the wait, history may come"
    frames = exact(sent)
    assert frames and frames[0].t_us == T0, "the first frame at the start of the nine clean streams"
    before = [f for f in frames if f.t_us < T0 + 5 * STEP_US]
    assert before and all(f.flags & wire.FRAME_MISSING for f in before), "before its first point: flagged"


def test_a_late_joined_stream_settles_when_its_history_query_ends_and_then_takes_no_earlier_point():
    """A stream first seen at seq 3 waits for its start; the end of the aggregator's query of
    the device's cache settles it at once (not after HISTORY_WAIT_S): frames start, and an
    earlier point arriving after that is a duplicate, not a change to frames already out."""
    agg, sent = aggregator()
    online_subject(agg)
    for segment in SEGMENTS[:-1]:
        send(agg, segment, range(11), now=0.0)
    late = agg.track("s01", SEGMENTS[-1])
    send(agg, SEGMENTS[-1], range(3, 11), now=0.0)
    agg.advance(live=False, now=0.1)
    assert late.wants_history() and not exact(sent), "its start may still come"
    send(agg, SEGMENTS[-1], range(1, 3), now=0.2)  # part of its start, from the cache
    agg.fusion.history_done(late)                  # the query ended: seq 0 is not in the cache
    agg.advance(live=False, now=0.2)
    assert not late.wants_history() and exact(sent), "settled: frames start"
    assert exact(sent)[0].t_us == T0 + STEP_US, "at the first point of the stream that came"
    send(agg, SEGMENTS[-1], [0], now=0.3)
    assert late.dropped == {"duplicate": 1}, dict(late.dropped)


def truth(agg: Aggregator, segment: str, k: int, now: float) -> None:
    """One truth-tap sample of ``segment`` at sample index 5 * k (T0 + k * 100 ms)."""
    batch = wire.RawBatch(1, 5 * k, np.array([T0 + k * STEP_US]), np.array([IDENTITY], np.float32))
    agg.on_raw(wire.raw_key("s01", segment), wire.encode_raw(batch), now)


def test_truth_before_a_late_joiners_first_point_waits_for_its_history_grace():
    """Points from seq 3 on (0-2 may still come as history): a truth sample before them is not
    judged until the grace period is over, even if no further message wakes the aggregator;
    then it is dropped (no reconstruction) instead of compared with a held point."""
    agg, _ = aggregator()
    online_subject(agg)
    late = agg.track("s01", SEGMENTS[-1])
    send(agg, SEGMENTS[-1], range(3, 11), now=0.0)
    truth(agg, SEGMENTS[-1], 1, now=0.0)
    agg.advance(live=False, now=0.5)
    assert not late.dropped and agg.fusion.scoring.exact.count[late.slot] == 0, "must wait for the history"
    agg.advance(live=False, now=HISTORY_WAIT_S + 0.01)  # time passes, no message
    assert late.dropped == {"raw_before_first_point": 1}, dict(late.dropped)


def test_history_arriving_after_live_points_completes_the_stream():
    agg, _ = aggregator()
    online_subject(agg)
    late = agg.track("s01", SEGMENTS[-1])
    send(agg, SEGMENTS[-1], range(3, 11), now=0.0)
    truth(agg, SEGMENTS[-1], 1, now=0.0)
    send(agg, SEGMENTS[-1], range(3), now=0.2)           # the history of its start
    agg.advance(live=False, now=0.2)
    n = agg.fusion.store.n[late.slot]
    assert np.array_equal(agg.fusion.store.t[late.slot, :n], T0 + np.arange(11) * STEP_US), "inserted in order"
    assert late.points == 11 and not late.dropped, dict(late.dropped)
    assert agg.fusion.scoring.exact.count[late.slot] == 1, "the truth sample is judged against the full stream"


def test_truth_arriving_before_its_streams_first_point_is_kept_for_it():
    """Truth and points travel on different keys: a truth batch may come first. It waits for its
    stream's first point and is then judged; truth of a stream that has ended is dropped."""
    agg, _ = aggregator()
    online_subject(agg)
    track = agg.track("s01", SEGMENTS[0])
    truth(agg, SEGMENTS[0], 1, now=0.0)                    # stream 1, before any of its points
    assert not track.dropped and len(track.held_raw) == 1
    send(agg, SEGMENTS[0], range(11), now=0.0)
    agg.advance(live=False, now=0.1)
    assert not track.dropped and not track.held_raw, dict(track.dropped)
    assert agg.fusion.scoring.exact.count[track.slot] == 1, "the early truth sample is judged"

    restarted = wire.SegmentPoint(2, 0, 0, T0 + 20 * STEP_US, IDENTITY)  # the device rebooted: stream 2
    agg.on_point(wire.seg_key("s01", SEGMENTS[0]), wire.encode_point(restarted), 0.2)
    truth(agg, SEGMENTS[0], 2, now=0.2)                    # a late batch of stream 1
    assert track.dropped == {"raw_other_stream": 1} and not track.held_raw, dict(track.dropped)


def test_offline_device_does_not_hold_frames_back_and_they_are_flagged():
    agg, sent = aggregator()
    online_subject(agg)
    for segment in SEGMENTS:
        send(agg, segment, range(6), now=0.0)
    agg.advance(live=False, now=0.0)
    before = len(exact(sent))
    agg.on_alive(wire.alive_key("s01", SEGMENTS[0]), False)
    for segment in SEGMENTS[1:]:
        send(agg, segment, range(6, 11), now=0.1)
    agg.advance(live=False, now=0.1)
    later = exact(sent)[before:]
    assert [f.t_us - T0 for f in later] == list(range(520_000, 1_000_001, 20_000))
    assert all(f.flags & wire.FRAME_MISSING for f in later), "the held segment is flagged"
    stats = {d["segment"]: d for d in agg.fusion.device_stats([agg.subjects["s01"]], 0.1)[0]}
    assert stats[SEGMENTS[0]]["online"] is False and stats[SEGMENTS[1]]["online"] is True


def test_lost_points_flag_the_frames_they_span_as_gap():
    agg, sent = aggregator()
    online_subject(agg)
    for segment in SEGMENTS:
        send(agg, segment, [k for k in range(11) if segment != SEGMENTS[2] or k not in (4, 5)], now=0.0)
    agg.advance(live=False, now=0.0)
    frames = exact(sent)
    gap = np.array([bool(f.flags & wire.FRAME_GAP) for f in frames])
    t = np.array([f.t_us - T0 for f in frames])
    assert agg.track("s01", SEGMENTS[2]).gaps == 2
    assert np.array_equal(gap, (t > 300_000) & (t < 600_000)), "GAP exactly between the points around the loss"


SPIN = (0.0, 0.0, 2.0)  # rad/s about z


def spinning_subject() -> tuple[Aggregator, list[wire.PoseFrame]]:
    """An online subject at T0, arrived at 0: the first segment's point (v2) spins at SPIN, the
    others are v1 points at rest."""
    agg, sent = aggregator()
    online_subject(agg)
    point = wire.SegmentPoint(1, 0, 0, T0, IDENTITY, 0, SPIN)
    agg.on_point(wire.seg_key("s01", SEGMENTS[0]), wire.encode_point(point), 0.0)
    for segment in SEGMENTS[1:]:
        send(agg, segment, range(1), now=0.0)
    return agg, sent


def test_live_frames_extrapolate_open_segments_with_the_point_rate():
    """Live frames: a segment whose newest point carries a rate (v2) is extrapolated with
    quat.predict to the subject's device time "now" (newest device time + arrival clock since),
    a v1 point is held, a segment whose later point is known is exact; the live error per truth
    sample is the prediction from the points at or before it (0 here for the rate device, the
    rotation for the held one) and the live stats rows are filled."""
    from limbstream import quat

    agg, sent = spinning_subject()
    spin = SPIN
    agg.advance(live=True, now=0.1)
    live = [f for f in sent if f.kind == wire.KIND_LIVE]
    assert len(live) == 1 and live[0].t_us == T0 + 100_000, "device now: newest time + 100 ms of arrival clock"
    expected = quat.predict(np.array(IDENTITY), np.array(spin), 0.1)
    assert quat.angle_deg(live[0].q[0].astype(np.float64), expected) < 1e-3, "extrapolated with its rate"
    assert quat.angle_deg(live[0].q[1].astype(np.float64), np.array(IDENTITY)) < 1e-6, "v1 point held"
    turned = quat.predict(np.array(IDENTITY), np.array(spin), 0.05).astype(np.float32)
    for segment in SEGMENTS[:2]:  # truth at T0 + 50 ms follows the spin
        batch = wire.RawBatch(1, 2, np.array([T0 + STEP_US // 2]), turned[None, :])
        agg.on_raw(wire.raw_key("s01", segment), wire.encode_raw(batch), 0.1)
    for segment in SEGMENTS:  # later points make the truth final, and the segment before them exact
        send(agg, segment, range(1, 3), now=0.2)
    agg.advance(live=True, now=0.2)
    stats = {d["segment"]: d for d in agg.fusion.device_stats([agg.subjects["s01"]], 0.2)[0]}
    assert stats[SEGMENTS[0]]["live_max_deg"] < 1e-3, stats[SEGMENTS[0]]
    assert abs(stats[SEGMENTS[1]]["live_p50_deg"] - 5.7248) < 0.01, "held: the 0.1 rad turn"
    assert stats[SEGMENTS[1]]["live_err_deg"] == stats[SEGMENTS[1]]["live_p99_deg"] == stats[SEGMENTS[1]]["live_max_deg"]
    assert np.isfinite(stats[SEGMENTS[0]]["live_latency_p50_ms"]) and np.isfinite(stats[SEGMENTS[0]]["live_latency_p99_ms"])
    wire.encode_stats("s01", 0.0, list(stats.values()), {})  # every row declared


def test_live_frames_stop_extrapolating_a_device_that_went_silent():
    """An online device whose points stop: its newest point is extrapolated for at most its
    max segment length (max_len samples at the frame rate, by then it has sent a point) plus
    OVERDUE_GRACE_S; later live frames hold it at that point and are flagged MISSING. The horizon
    follows the max_len the device reports."""
    from limbstream import quat
    from limbstream.services.aggregator.frames import OVERDUE_GRACE_S

    agg, sent = spinning_subject()
    spin = SPIN
    horizon_s = wire.MAX_LEN.default / AggregatorSettings().rate + OVERDUE_GRACE_S

    def newest_live() -> wire.PoseFrame:
        return [f for f in sent if f.kind == wire.KIND_LIVE][-1]

    agg.advance(live=True, now=0.5)  # within the horizon: extrapolated, not flagged
    frame = newest_live()
    assert (frame.t_us - T0) / 1e6 < horizon_s and not frame.flags & wire.FRAME_MISSING
    assert quat.angle_deg(frame.q[0].astype(np.float64), quat.predict(np.array(IDENTITY), np.array(spin), 0.5)) < 1e-3

    for segment in SEGMENTS[1:]:  # the others go on; segment 0 is silent
        send(agg, segment, range(1, 11), now=1.0)
    agg.advance(live=True, now=1.0)
    frame = newest_live()
    assert (frame.t_us - T0) / 1e6 > horizon_s
    assert frame.flags & wire.FRAME_MISSING, "overdue device flagged"
    assert quat.angle_deg(frame.q[0].astype(np.float64), np.array(IDENTITY)) < 1e-6, "held at its newest point"

    track = agg.subjects["s01"].tracks[SEGMENTS[0]]
    agg.fusion.set_config(track, wire.DeviceConfig(max_len=100))  # 2 s segments: not overdue yet
    agg.advance(live=True, now=1.0)
    frame = newest_live()
    assert not frame.flags & wire.FRAME_MISSING
    expected = quat.predict(np.array(IDENTITY), np.array(spin), (frame.t_us - T0) / 1e6)
    assert quat.angle_deg(frame.q[0].astype(np.float64), expected) < 1e-3


def test_a_frame_stage_takes_each_ticks_frames_of_every_subject_before_they_are_encoded():
    """The place for work on whole frames (joint angles from the live frames, say): every tick's
    frame batch, all subjects at once, orientations in float64; what it returns is published."""
    agg, sent = aggregator()
    online_subject(agg)
    online_subject(agg, "s02")
    batches, published = [], []

    def stage(batch):
        batches.append(batch)
        live = batch.group(wire.KIND_LIVE, PAPER10)
        return [(wire.subject_key(SUBJECTS[i], "stats"), "stats", bytes([i])) for i in live.owner.tolist()]

    agg.frame_stages = [stage]
    agg._put = lambda key, kind, payload: published.append((key, kind, payload))
    for subject in SUBJECTS:
        for segment in SEGMENTS:
            send(agg, segment, range(6), now=0.0, subject=subject)
    agg.advance(live=True, now=0.1)
    batch = batches[-1]
    exact_frames = batch.group(wire.KIND_EXACT, PAPER10).frames
    assert exact_frames.q.dtype == np.float64 and exact_frames.q.shape == (len(exact(sent)), len(SEGMENTS), 4)
    assert sorted(set(batch.exact_owner.tolist())) == [0, 1] and batch.group(wire.KIND_LIVE, PAPER10).owner.tolist() == [0, 1]
    assert published == [(wire.stats_key(s), "stats", bytes([i])) for i, s in enumerate(SUBJECTS)]


SUBJECTS = ("s01", "s02")


def test_one_drain_with_a_devices_old_stream_its_new_one_and_its_start_late_keeps_each_row_in_order():
    """Points of one drain taken by the full rules are stored together at the drain's end, except a
    device's own, stored before its row changes: a new stream of that device drops the old one's, an
    earlier point of its stream's start is inserted in time order after its later ones."""
    agg, _ = aggregator()
    online_subject(agg)
    a, b = SEGMENTS[0], SEGMENTS[1]
    drain = [(a, 1, k) for k in range(3)] + [(b, 1, k) for k in range(2)] + [(a, 2, k) for k in range(4, 7)] \
        + [(b, 1, 2), (a, 2, 0), (a, 2, 1)]  # a's new stream, then its start (history) late in the same drain
    keys = [wire.seg_key("s01", seg) for seg, _, _ in drain]
    payloads = [wire.encode_point(wire.SegmentPoint(stream, k, 5 * k, T0 + k * STEP_US, IDENTITY))
                for _, stream, k in drain]
    agg.take_points(keys, payloads, 0.0)
    store = agg.fusion.store
    for seg, expected in ((a, [0, 1, 4, 5, 6]), (b, [0, 1, 2])):
        slot = agg.track("s01", seg).slot
        assert np.array_equal(store.t[slot, :store.n[slot]], T0 + np.array(expected) * STEP_US), seg
