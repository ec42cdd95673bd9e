"""The subject truth tap (docs/protocol.md, "Subject truth tap"): one message per subject and
batch holding its devices' truth-tap batches. Its codec (round trip, the documented layout,
malformed messages refused with a reason), the aggregator taking it in (bad ones counted and
dropped), and the same live figures as the per-device form on the same emulated run."""
from __future__ import annotations

import random
import struct

import numpy as np
import pytest
from support.stack import stack, wait_for_subscribers, wait_until  # noqa: F401  (fixture)

from limbstream import quat, wire, zconfig
from limbstream.calibration import SensorModel
from limbstream.device.clocks import ClockSettings
from limbstream.device.feeds import GeneratorFeed, LoopFeed
from limbstream.device.host import HostSettings
from limbstream.device_emulator.emulator import Emulator, EmulatorSettings
from limbstream.services.aggregator.aggregator import Aggregator
from limbstream.services.aggregator.settings import AggregatorSettings
from limbstream.services.outputs.subscription import Subscription
from limbstream.sources import Motion
from limbstream.sources.generator import GeneratorSource

T0 = 1_790_000_000_000_000


def batch(stream: int, first: int, n: int, seed: int = 0) -> bytes:
    """A version-3 truth-tap batch of ``n`` samples at 50 Hz from sample ``first``."""
    rng = np.random.default_rng(seed)
    t = T0 + (first + np.arange(n, dtype=np.int64)) * 20_000
    q = quat.normalize(rng.normal(size=(n, 4))).astype(np.float32)
    return wire.encode_raw(wire.RawBatch(stream, first, t, q, t + 7, q[::-1].copy()))


def test_a_truth_message_round_trips_and_has_the_documented_layout():
    hip, head = batch(3, 100, 25, 1), batch(4, 0, 7, 2)
    payload = wire.encode_truth(["hip", "head"], [hip, head])
    assert payload[:4] == struct.pack("<BBH", 1, 0, 2)  # version, flags, count
    assert payload[4:8] == b"\x03hip" and struct.unpack_from("<I", payload, 8)[0] == len(hip)
    assert payload[12:12 + len(hip)] == hip
    at = 12 + len(hip)
    assert payload[at:at + 5] == b"\x04head" and struct.unpack_from("<I", payload, at + 5)[0] == len(head)
    assert payload[at + 9:] == head
    assert wire.decode_truth(payload) == [("hip", hip), ("head", head)]
    assert wire.truth_batches(wire.truth_key("s01"), payload) == [(wire.raw_key("s01", "hip"), hip),
                                                                  (wire.raw_key("s01", "head"), head)]
    back = wire.decode_raw(wire.decode_truth(payload)[0][1])
    assert back.stream == 3 and back.first_index == 100 and back.own is not None
    with pytest.raises(wire.WireError) as err:
        wire.truth_batches(wire.pose_key("s01"), payload)
    assert err.value.reason == "key"
    for segments, batches in (([], []), (["hip", "hip"], [hip, hip]), (["a/b"], [hip]), (["hip"], [hip, head])):
        with pytest.raises(ValueError):
            wire.encode_truth(segments, batches)


GOOD = wire.encode_truth(["hip", "head"], [batch(3, 0, 5), batch(4, 0, 5)])
MALFORMED = {
    "empty": (b"", "size"),
    "short header": (GOOD[:3], "size"),
    "version 2": (b"\x02" + GOOD[1:], "version"),
    "no entries": (struct.pack("<BBH", 1, 0, 0), "size"),
    "too many entries": (struct.pack("<BBH", 1, 0, wire.MAX_TRUTH_ENTRIES + 1) + GOOD[4:], "size"),
    "cut in a name": (GOOD[:6], "size"),
    "cut in a size": (GOOD[:9], "size"),
    "cut in a batch": (GOOD[:-1], "size"),
    "a byte after": (GOOD + b"\x00", "size"),
    "count too high": (GOOD[:2] + struct.pack("<H", 3) + GOOD[4:], "size"),
    "empty name": (struct.pack("<BBHB", 1, 0, 1, 0) + struct.pack("<I", 1) + b"\x01", "segment"),
    "name not a chunk": (GOOD[:4] + b"\x03h/p" + GOOD[8:], "segment"),
    "name not ASCII": (GOOD[:4] + b"\x03h\xffp" + GOOD[8:], "segment"),
    "a name twice": (struct.pack("<BBH", 1, 0, 2) + 2 * wire.encode_truth(["hip"], [batch(3, 0, 5)])[4:], "segment"),
}


@pytest.mark.parametrize("name", list(MALFORMED))
def test_a_malformed_truth_message_is_refused_with_its_reason_and_counted_by_the_aggregator(name):
    payload, reason = MALFORMED[name]
    with pytest.raises(wire.WireError) as err:
        wire.decode_truth(payload)
    assert err.value.reason == reason
    agg = Aggregator(None, AggregatorSettings())
    agg.on_truth(wire.truth_key("s01"), GOOD, 0.0)  # the devices are known: nothing of the bad one is theirs
    assert sorted(t.id for t in agg.fusion.tracks) == ["s01/head", "s01/hip"] and not agg.bad_keys
    agg.on_truth(wire.truth_key("s01"), payload, 0.1)
    assert agg.bad_keys == {f"truth_{reason}": 1} and len(agg.fusion.tracks) == 2
    assert all(not t.dropped for t in agg.fusion.tracks)
    assert f"truth_{reason}" in wire.UNCHARGED


def test_a_bad_batch_in_a_truth_message_counts_on_its_device_and_the_others_are_taken():
    """A message that splits but holds a batch that does not decode: that batch is counted on its
    device as on its own ``raw`` key (or, device never seen, in bad_keys); the others go in."""
    agg = Aggregator(None, AggregatorSettings())
    agg.on_truth(wire.truth_key("s01"), GOOD, 0.0)
    bad = bytearray(batch(3, 5, 5))
    bad[0] = 9  # no such batch version
    agg.on_truth(wire.truth_key("s01"), wire.encode_truth(["hip", "head", "ghost"], [bytes(bad), batch(4, 5, 5), b"\x01"]),
                 0.1)
    hip, head = agg.known("s01", "hip"), agg.known("s01", "head")
    assert hip.dropped == {"raw_version": 1} and not head.dropped
    assert agg.bad_keys == {"raw_undecodable": 1} and len(agg.fusion.tracks) == 2
    agg.on_truth(wire.seg_key("s01", "hip"), GOOD, 0.2)  # not a truth key
    assert agg.bad_keys["key"] == 1


def test_a_raw_subscription_takes_both_forms_as_device_batches(stack):  # noqa: F811
    """Through a real router: the outputs' ``raw`` subscription (the recorder's) gives a subject
    truth message as the raw items of its batches (each its device's key and its batch's bytes),
    alongside a device's own raw message, and counts one that does not split."""
    stack.router()
    hip, head, knee = batch(3, 0, 5, 1), batch(4, 0, 5, 2), batch(5, 0, 5, 3)
    with zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,))) as pub, \
            Subscription(zconfig.ZenohSettings(connect=(stack.endpoint,)), "a*", ("raw",)) as sub:
        wait_for_subscribers(stack.endpoint, [wire.raw_key("a1", "hip"), wire.truth_key("a1")], "the subscription")
        pub.put(wire.truth_key("a1"), wire.encode_truth(["hip", "head"], [hip, head]))
        pub.put(wire.truth_key("a1"), b"\x01\x00\x00\x00")  # no entries
        pub.put(wire.raw_key("a2", "l_knee"), knee)
        first = sub.get(timeout=10)  # one item at a time: the message's second batch waits its turn
        got = [first] + [sub.get(timeout=10) for _ in range(2)]
        assert sub.get(timeout=0.2) is None
        assert sorted((i.kind, i.key, i.subject, i.segment, i.payload) for i in got) == sorted([
            ("raw", wire.raw_key("a1", "hip"), "a1", "hip", hip), ("raw", wire.raw_key("a1", "head"), "a1", "head", head),
            ("raw", wire.raw_key("a2", "l_knee"), "a2", "l_knee", knee)])
        assert all(isinstance(i.value, wire.RawBatch) for i in got)
        assert dict(sub.errors) == {"truth_size": 1}


class Recorder:
    """A publisher that keeps what it is given: (tick, key, payload) in the order of puts."""

    def __init__(self, key: str, sent: list, clock: list):
        self.key, self.sent, self.clock = key, sent, clock

    def put(self, payload) -> None:
        self.sent.append((self.clock[0], self.key, bytes(payload)))

    def undeclare(self) -> None:
        pass


def feeds() -> dict:
    """Generator subjects and a clip played once (its devices end mid-run: their taps flush alone)."""
    rng = np.random.default_rng(5)
    q = quat.normalize(np.cumsum(rng.normal(0, 0.05, (173, 10, 4)), axis=0) + [1, 0, 0, 0])
    clip = Motion(np.arange(173) / 50.0, q, GeneratorSource.segments, "clip")
    return {"s00": GeneratorFeed(2, 50.0), "s01": LoopFeed(clip, 50.0, once=True), "s02": GeneratorFeed(3, 50.0)}


def emulated(by_subject: bool, clock: ClockSettings, ticks: int) -> tuple[list, list]:
    """(tick, key, payload) of every put of an emulator over ``ticks`` ticks and its finish, with
    the truth tap per subject or per device, its devices' sensors off their segments (their own
    orientations are not the truth); and its devices."""
    random.seed(11)  # the stream ids
    session = zconfig.open_session(zconfig.ZenohSettings(mode="peer", connect=()))
    try:
        e = Emulator(session, feeds(), EmulatorSettings(HostSettings(truth=True, truth_by_subject=by_subject),
                                                        clock=clock, sensors=SensorModel(20, 30, 0.0, seed=2)))
        e.declare()
        sent: list = []
        clock_now = [0]
        for d in e.devices:
            d.publisher = Recorder(wire.seg_key(d.subject, d.segment), sent, clock_now)
            d.raw_pub = None if by_subject else Recorder(wire.raw_key(d.subject, d.segment), sent, clock_now)
        for subject in e.host.truth_pubs:
            e.host.truth_pubs[subject] = Recorder(wire.truth_key(subject), sent, clock_now)
        e.clocks.boot(T0)
        e.start_us = T0
        e.clocks.start_grid(T0)
        for k in range(ticks):
            clock_now[0] = k
            e.step(k)
        e.finish()
        e.undeclare()
        return sent, [(d.subject, d.segment) for d in e.devices]
    finally:
        session.close()


def evaluated(sent: list, devices: list, ticks: int) -> dict:
    """The device stats of an aggregator given ``sent`` as it came, tick by tick."""
    agg = Aggregator(None, AggregatorSettings())
    agg._publish = lambda subject, payload: None  # frames are made, not sent
    for subject, segment in devices:
        agg.on_alive(wire.alive_key(subject, segment), True)
    by_tick: dict[int, list] = {}
    for tick, key, payload in sent:
        by_tick.setdefault(tick, []).append((key.rsplit("/", 1)[-1], key, payload))
    for tick in range(ticks + 60):
        now = tick / 50.0
        mine = by_tick.get(tick, [])
        for kind, take in (("seg", agg.take_points), ("raw", agg.take_raw), ("truth", agg.intake.take_truth)):
            keys = [key for what, key, _ in mine if what == kind]
            if keys:
                take(keys, [p for what, _, p in mine if what == kind], now)
        agg.advance(True, tick % 25 == 0, now)
    return {d["device"]: d for s in sorted({s for s, _ in devices}) for d in agg.subject_stats(s, now)["devices"]}


LIVE = ("live_err_deg", "live_p50_deg", "live_p99_deg", "live_max_deg", "live_own_p99_deg", "live_own_max_deg",
        "aad_deg", "aad_all_deg", "p99_deg", "max_deg", "error_samples", "samples", "points")


@pytest.mark.parametrize("clock", [ClockSettings(sync=False),
                                   ClockSettings(offset_ms=40, drift_ppm=3000, jitter_us=200, sync=False, seed=4)],
                         ids=["shared grid", "own clocks"])
def test_the_subject_truth_tap_gives_the_live_figures_of_the_per_device_one(clock):
    """The same emulated run (same streams, same samples) with its truth tap per device and per
    subject: the subject form sends one message per subject and batch and none per device, and
    the aggregator's live figures (live_*, live_own_*) and errors are equal, to the bit. The
    batches come at other ticks (subjects are staggered, not devices) and are cut elsewhere:
    what a sample is compared with does not depend on when its batch arrives. The live latency
    figures are left out: they are the wall clock's (none here)."""
    ticks = 600
    per_device, devices = emulated(False, clock, ticks)
    per_subject, same = emulated(True, clock, ticks)
    assert same == devices
    raws = sum(key.endswith("/raw") for _, key, _ in per_device)
    truths = [key for _, key, _ in per_subject if key.endswith("/truth")]
    assert not any(key.endswith("/raw") for _, key, _ in per_subject) and not any(
        key.endswith("/truth") for _, key, _ in per_device)
    # a message per subject and batch (600 ticks / 25, one more at the end), where there was one per device
    per_subject_count = {s: sum(key == wire.truth_key(s) for key in truths) for s in ("s00", "s01", "s02")}
    assert per_subject_count["s00"] <= ticks // 25 + 1 and per_subject_count["s02"] <= ticks // 25 + 1, per_subject_count
    assert abs(len(truths) - raws / 10) <= 3, (len(truths), raws)
    seg = [(key, p) for _, key, p in per_device if key.endswith("/seg")]
    assert seg == [(key, p) for _, key, p in per_subject if key.endswith("/seg")]  # the same points
    old, new = evaluated(per_device, devices, ticks), evaluated(per_subject, devices, ticks)
    assert set(old) == set(new) and len(old) == 30
    for device in old:
        assert old[device]["error_samples"] > 100 and old[device]["live_own_max_deg"] > 0, old[device]
        assert old[device]["error_samples"] == old[device]["samples"], old[device]
        assert {f: old[device][f] for f in LIVE} == {f: new[device][f] for f in LIVE}, device
