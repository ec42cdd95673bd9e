"""Scale-out on loopback, real processes: meshed routers and aggregators sharded by subject."""
from __future__ import annotations

import json

import numpy as np
import pytest
import zenoh
from support.stack import free_port, stack, wait_for_subscribers, wait_until  # noqa: F401  (fixture)

from limbstream import evaluation, wire, zconfig
from limbstream.sources import load_npz


class Tap:
    """A client session that collects exact pose frames and the latest stats of every subject."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.poses = self.session.declare_subscriber(wire.subject_selector("pose"), zenoh.handlers.FifoChannel(1 << 15))
        self.stats_sub = self.session.declare_subscriber(wire.subject_selector("stats"), zenoh.handlers.FifoChannel(4096))
        self.frames: dict[str, list[wire.PoseFrame]] = {}
        self.stats: dict[str, dict] = {}

    def poll(self) -> None:
        while (sample := self.poses.try_recv()) is not None:
            subject, _ = wire.parse_subject_key(str(sample.key_expr))
            frame = wire.decode_pose(sample.payload.to_bytes())
            if frame.kind == wire.KIND_EXACT:
                self.frames.setdefault(subject, []).append(frame)
        while (sample := self.stats_sub.try_recv()) is not None:
            data = wire.decode_stats(sample.payload.to_bytes())
            self.stats[data["subject"]] = data

    def devices(self, subject: str) -> list[dict]:
        return self.stats.get(subject, {}).get("devices", [])

    def close(self) -> None:
        self.session.close()


@pytest.fixture
def tap_factory():
    taps: list[Tap] = []

    def make(endpoint: str) -> Tap:
        taps.append(Tap(endpoint))
        return taps[-1]
    yield make
    for t in taps:
        t.close()


def test_devices_and_aggregator_on_two_meshed_routers(stack, tap_factory, cmu_npz):  # noqa: F811
    """Router B connects to router A; a clip streams from A to an aggregator on B: frames stay exact."""
    motion = load_npz(cmu_npz)[0]
    m = len(motion.t)
    stack.router()
    port_b = free_port()
    endpoint_b = f"tcp/127.0.0.1:{port_b}"
    router_b = stack.start("router-b", "router", "--listen", endpoint_b, "--connect", stack.endpoint)
    stack._wait_port(port_b, router_b, 20.0)
    tap = tap_factory(endpoint_b)
    stack.start("aggregate", "aggregate", "--connect", endpoint_b)
    # The clip plays once: the aggregator's subscriptions must reach router A before it starts.
    wait_for_subscribers(stack.endpoint, [wire.seg_key("s01", "hip"), wire.raw_key("s01", "hip")],
                         "the aggregator on router B to subscribe through router A", on_fail=stack.logs)
    stack.emulator(1, 10.0, "--source", str(cmu_npz), "--once", "--max-len", "25")  # connects to router A

    def finished():
        tap.poll()
        mine = tap.devices("s01")
        return len(mine) == 10 and all(d["final"] and d["error_samples"] == m for d in mine) and mine
    def report():
        seen = [(d["segment"], d["final"], d["samples"], d["error_samples"]) for d in tap.devices("s01")]
        return f"\n(segment, final, samples, error_samples) of {m}: {seen}" + stack.logs()
    mine = wait_until(finished, 90, "every device of s01 to finish its clip through both routers",
                      on_fail=report)

    expected = evaluation.evaluate([motion], ["fastsw"], [1e-2], max_len=25)[0]
    pooled = sum(d["aad_all_deg"] * d["error_samples"] for d in mine) / sum(d["error_samples"] for d in mine)
    print(f"\nacross two routers: exact-frame AAD {pooled:.4f} deg vs offline {expected['aad']:.4f} deg")
    assert abs(pooled - expected["aad"]) < 0.05, (pooled, expected)
    for d in mine:
        assert d["samples"] == m and d["gaps"] == 0 and set(d["dropped_by_reason"]) <= {"duplicate"}, d
        # the device's own counters, asked from router B's side through the mesh
        reply = next(iter(tap.session.get(wire.config_key("s01", d["segment"]), timeout=5.0)))
        own = json.loads(reply.ok.payload.to_bytes())
        assert own["points"] == d["points"], (own, d)
    assert sum(d["points"] for d in mine) / (10 * m) == pytest.approx(expected["icr"], abs=1e-12)

    frames = tap.frames["s01"]
    t = np.array([f.t_us for f in frames])
    assert len(frames) > 0.9 * m, f"{len(frames)} exact frames for {m} samples"
    assert np.all(np.diff(t) == 20_000), "exact frames off the 50 Hz grid"
    assert [f.seq for f in frames] == list(range(frames[0].seq, frames[0].seq + len(frames)))
    assert not any(f.flags & (wire.FRAME_GAP | wire.FRAME_MISSING) for f in frames)


def test_two_aggregators_shard_subjects(stack, tap_factory):  # noqa: F811
    """Two rooms, roomA-s01..s02 and roomB-s01..s02, one aggregator each: --subjects 'roomA-s*'
    (a partial-name pattern) and --subjects roomB-s01,roomB-s02 (names). Each subject is served
    by exactly one aggregator."""
    shards = (("roomA-s01", "roomA-s02"), ("roomB-s01", "roomB-s02"))
    selectors = ("roomA-s*", ",".join(shards[1]))
    subjects = sorted(s for shard in shards for s in shard)
    stack.router()
    tap = tap_factory(stack.endpoint)
    for room in ("roomA-s", "roomB-s"):
        stack.emulator(2, 1.0, "--no-truth", "--subject-prefix", room)
    stack.aggregator("--subjects", selectors[0])

    # Phase 1: only the first shard runs. Its subjects stream; the others get nothing meanwhile.
    def first_shard_streams():
        tap.poll()
        return all(len(tap.frames.get(s, [])) >= 100 and len(tap.devices(s)) == 10 for s in shards[0])
    wait_until(first_shard_streams, 60, f"exact frames of {shards[0]}", on_fail=stack.logs)
    stray = {s: len(tap.frames.get(s, [])) for s in shards[1]} | {s: s in tap.stats for s in shards[1]}
    assert not any(stray.values()), f"the first aggregator served subjects outside its shard: {stray}"

    # Phase 2: the second shard joins; together they cover every subject.
    before = {s: len(tap.frames.get(s, [])) for s in subjects}
    stack.aggregator("--subjects", selectors[1])

    def all_stream():
        tap.poll()
        return all(len(tap.frames.get(s, [])) >= before[s] + 100 and len(tap.devices(s)) == 10 for s in subjects)
    wait_until(all_stream, 60, f"exact frames of every subject {subjects}", on_fail=stack.logs)

    # None twice: two publishers of one subject would repeat frame times and restart the counters.
    for s in subjects:
        frames = tap.frames[s]
        t = np.array([f.t_us for f in frames])
        assert len(np.unique(t)) == len(t), f"{s}: {len(t) - len(np.unique(t))} frame times published twice"
        assert np.all(np.diff(t) == 20_000), f"{s}: exact frames off the 50 Hz grid"
        assert [f.seq for f in frames] == list(range(frames[0].seq, frames[0].seq + len(frames))), s
        assert all(d["online"] and d["gaps"] == 0 for d in tap.devices(s)), [
            (d["device"], d["online"], d["gaps"]) for d in tap.devices(s)]
