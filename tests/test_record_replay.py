"""Outputs room: the subscription path, `limbstream record` and `limbstream replay`, with real
processes on loopback (tests/stack.py) and the mcap library reading the files back."""
from __future__ import annotations

import collections
import json
import os
import signal
import socket
import subprocess
import sys

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader
from mcap.writer import Writer
from support.stack import ROOT, stack, wait_for_subscribers, wait_until  # noqa: F401  (fixture)

from limbstream import quat, wire, zconfig
from limbstream.sources.bvh import load_bvh
from limbstream.services.outputs.replay import FIXED
from limbstream.services.outputs.recording import (TOPICS, Recording, RecordingError, RecordingWriter, envelope, open_envelope,
                                        skeleton_topic)
from limbstream.services.outputs.subscription import Subscription

CLIP_SAMPLES = 1146  # first clip of cmu_10seg_50hz.npz (01_01), the one subject s01 streams


def cli(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "limbstream.cli", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


def pose(seq: int, t_us: int = 1_700_000_000_000_000) -> wire.PoseFrame:
    return wire.PoseFrame(seq, t_us, wire.KIND_EXACT, 0, np.tile(np.float32([1, 0, 0, 0]), (10, 1)))


# ----------------------------------------------------------------------------- subscription


def test_subscription_decodes_matches_the_pattern_and_counts_bad_messages(stack):  # noqa: F811
    stack.router()
    with zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,))) as pub, \
            Subscription(zconfig.ZenohSettings(connect=(stack.endpoint,)), "a*", ("pose", "stats")) as sub:
        wait_for_subscribers(stack.endpoint, [wire.pose_key("a1"), wire.stats_key("a1")], "the subscription")
        pub.put(wire.pose_key("b1"), wire.encode_pose(pose(1)))  # outside the pattern
        pub.put(wire.pose_key("a1"), wire.encode_pose(pose(2)))
        pub.put(wire.pose_key("a2"), b"short")
        pub.put(wire.stats_key("a1"), b"{not json")
        pub.put(wire.stats_key("a2"), wire.encode_stats("a2", 1.0, [], seq=3))
        got = []
        wait_until(lambda: got.extend(sub.drain()) or len(got) == 2 and sum(sub.errors.values()) == 2, 10,
                   "2 items and 2 counted errors")
        assert [(i.kind, i.subject, i.segment) for i in got] == [("pose", "a1", None), ("stats", "a2", None)], got
        assert got[0].value.seq == 2 and got[1].value["seq"] == 3 and got[0].payload == wire.encode_pose(pose(2))
        assert dict(sub.errors) == {"pose_size": 1, "stats_json": 1}
        for seq in range(20):  # in order, one channel per kind
            pub.put(wire.pose_key("a1"), wire.encode_pose(pose(seq)))
        got = []
        wait_until(lambda: got.extend(sub.drain()) or len(got) == 20, 10, "20 frames")
        assert [i.value.seq for i in got] == list(range(20))
        assert sub.get(timeout=0.05) is None
        pub.put(wire.stats_key("a3"), wire.encode_stats("a3", 1.0, [], seq=4))
        item = sub.get(timeout=10)
        assert item is not None and item.kind == "stats" and item.subject == "a3"
    with pytest.raises(ValueError, match="subject pattern"):
        Subscription(zconfig.ZenohSettings(connect=(stack.endpoint,)), "a/b")
    with pytest.raises(ValueError, match="kinds"):
        Subscription(zconfig.ZenohSettings(connect=(stack.endpoint,)), "*", ("alive",))


# ----------------------------------------------------------------------------- record and replay


def finished(watch, subject: str):
    """The stats of the 10 devices of ``subject`` once all of them streamed the whole clip."""
    mine = [d for k, d in watch.poll().items() if k.startswith(subject + "/")]
    return len(mine) == 10 and all(d["final"] and d["error_samples"] == CLIP_SAMPLES for d in mine) and mine


def pooled_aad(devices) -> float:
    return sum(d["aad_all_deg"] * d["error_samples"] for d in devices) / sum(d["error_samples"] for d in devices)


def exact_frames(sub: Subscription, frames: dict) -> dict:
    for item in sub.drain():
        if item.value.kind == wire.KIND_EXACT:
            frames.setdefault(item.subject, {})[item.value.t_us] = item.value
    return frames


def test_record_then_replay_rebuilds_the_same_frames(stack, watch, cmu_npz, tmp_path):  # noqa: F811
    """A CMU clip streamed once is recorded by a recorder started before the devices and by one
    started after they finished (history); the first recording replayed into a fresh aggregator
    gives the same exact frames, AAD and ICR; the second holds the same segment points and truth."""
    live, late = tmp_path / "live.mcap", tmp_path / "late.mcap"
    stack.aggregator("--subjects", "s01")
    stack.aggregator("--subjects", "r-*")
    recorder = stack.start("record", "record", str(live), "--connect", stack.endpoint)
    frames_sub = Subscription(watch.session, "*", ("pose",))
    keys = [k for seg in wire.SEGMENTS for k in (wire.seg_key("s01", seg), wire.raw_key("s01", seg))]
    wait_for_subscribers(stack.endpoint, keys + [wire.pose_key("s01")], "the recorder and aggregator",
                         on_fail=stack.logs)
    stack.emulator(1, 10.0, "--source", str(cmu_npz), "--once")
    original = wait_until(lambda: finished(watch, "s01"), 60, "s01 to finish its clip", on_fail=stack.logs)

    late_recorder = stack.start("record", "record", str(late), "--connect", stack.endpoint, "--no-skeleton")

    def recorded(path, kind):
        try:
            return [e for e in Recording(path).entries([kind])]
        except RecordingError:
            return []
    # every FINAL point in the live recording's flushed chunks: then stop it (SIGTERM closes it properly)
    wait_until(lambda: sum(wire.decode_point(e.payload).flags & wire.FLAG_FINAL for e in recorded(live, "seg")) == 10,
               15, "the live recorder to hold the 10 final points", on_fail=stack.logs)
    wait_until(lambda: len(recorded(late, "seg")) == sum(d["points"] for d in original), 15,
               "the late recorder to get every point from the devices' caches", on_fail=stack.logs)
    # (the recorder asks the devices' config statuses every 5 s: the clip may end before its second poll)
    wait_until(lambda: len({e.key for e in recorded(live, "config")}) == 10, 15,
               "the live recorder to hold every device's config status", on_fail=stack.logs)
    for child in (recorder, late_recorder):
        child.signal(signal.SIGTERM)
        assert child.popen.wait(20) == 0, stack.logs()
    log = recorder.log.read_text()
    assert "recording " in log and " MB " in log and "msg/s" in log and "record: {" in log, log

    # properly closed: the mcap library reads the summary
    with open(live, "rb") as f:
        summary = make_reader(f).get_summary()
    counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    points = sum(d["points"] for d in original)
    assert counts[TOPICS["seg"]] == points, counts
    assert counts[TOPICS["raw"]] >= 10 * CLIP_SAMPLES // 25 and counts[TOPICS["pose"]] > 0, counts
    assert counts[TOPICS["config"]] >= 10 and counts[skeleton_topic("s01")] > 0, counts
    angles = [wire.decode_angles(e.payload) for e in Recording(live).entries(["angles"])]  # the live frames' joint angles
    assert len(angles) == counts[TOPICS["angles"]] > 0 and angles[-1].calibration.name == "segments", counts
    assert {s.name for s in summary.schemas.values()} >= {"limbstream.seg", "foxglove.SceneUpdate"}
    # the emulator's truth came a message per subject: recorded per device, as recordings always held it
    assert {wire.parse_device_key(e.key)[2] for e in Recording(live).entries(["raw"])} == {"raw"}
    seg_of = {(e.key, e.payload) for e in Recording(live).entries(["seg", "raw"])}
    assert seg_of == {(e.key, e.payload) for e in Recording(late).entries(["seg", "raw"])}

    # replay into a fresh aggregator (subjects r-*), 4x faster
    replay = stack.start("replay", "replay", str(live), "--connect", stack.endpoint, "--subject-prefix", "r-",
                         "--speed", "4", "--hold", "30")
    rebuilt = wait_until(lambda: finished(watch, "r-s01"), 60, "r-s01 to finish", on_fail=stack.logs)
    a, b = pooled_aad(original), pooled_aad(rebuilt)
    print(f"\nexact-frame AAD recorded {a:.6f} deg, replayed {b:.6f} deg; points {points}")
    assert abs(a - b) < 0.01
    assert {d["segment"]: (d["points"], d["samples"]) for d in original} == \
        {d["segment"]: (d["points"], d["samples"]) for d in rebuilt}  # ICR equal
    assert all(set(d["dropped_by_reason"]) <= {"duplicate"} and d["gaps"] == 0 for d in rebuilt), rebuilt
    frames: dict = {}

    def replayed_frames():
        exact_frames(frames_sub, frames)
        return len(frames.get("r-s01", {})) >= len(frames.get("s01", {})) > 1000
    wait_until(replayed_frames, 30, "the replayed exact frames")
    common = sorted(set(frames["s01"]) & set(frames["r-s01"]))
    assert len(common) >= 1000, len(common)
    q1 = np.stack([frames["s01"][t].q for t in common]).astype(float)
    q2 = np.stack([frames["r-s01"][t].q for t in common]).astype(float)
    assert float(np.max(quat.angle_deg(q1, q2))) < 0.01
    frames_sub.close()
    replay.signal(signal.SIGTERM)
    assert replay.popen.wait(20) == 0

    # --loop: every pass a new stream of each device, later in time, taken without complaint
    looped = stack.start("replay", "replay", str(live), "--connect", stack.endpoint, "--subject-prefix", "r-l",
                         "--speed", "10", "--loop")

    def passes():
        mine = [d for k, d in watch.poll().items() if k.startswith("r-ls01/")]
        # (a pass's stream starts its error window over: its first samples lie on its first point, error 0)
        return len(mine) == 10 and all(d["restarts"] >= 2 and d["error_samples"] and d["aad_deg"] for d in mine) and mine
    again = wait_until(passes, 60, "three passes of r-ls01", on_fail=stack.logs)
    # no point lost or refused; truth batches that meet another pass's stream at a pass boundary
    # are counted and dropped by the aggregator, as at any device restart
    assert all(d["gaps"] == 0 and set(d["dropped_by_reason"]) <= {"raw_other_stream"} for d in again), \
        [(d["gaps"], d["dropped_by_reason"]) for d in again]
    # the 60-s error window holds whole and partial passes of the clip, so its mean is not the clip's
    # AAD (that equality is checked above, for one pass); every pass is evaluated, within the clip's range
    window = sum(d["aad_deg"] for d in again) / 10
    print(f"looped: 60-s window AAD {window:.4f} deg (mean over devices)")
    clip_max = max(d["max_deg"] for d in original)
    assert all(0 < d["aad_deg"] <= clip_max for d in again), [(d["aad_deg"], clip_max) for d in again]
    looped.signal(signal.SIGTERM)
    assert looped.popen.wait(20) == 0
    # export of the live recording: the recorded exact frames as BVH, read back by limbstream's loader
    bvh = tmp_path / "s01.bvh"
    result = subprocess.run([sys.executable, "-m", "limbstream.cli", "export", str(live), "--subject", "s01",
                             "-o", str(bvh)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    back = load_bvh(bvh, fs=None, drop_first=False)
    kept = {f.t_us: f for f in map(wire.decode_pose, (e.payload for e in Recording(live).entries(["pose"])))
            if f.kind == wire.KIND_EXACT}
    assert len(back.t) == (max(kept) - min(kept)) // 20_000 + 1 == len(kept)  # no gap in this recording
    in_file = np.stack([kept[t].q for t in sorted(kept)]).astype(float)
    assert float(np.max(quat.angle_deg(back.q, in_file))) < 0.01


def test_killed_recorder_leaves_a_file_readable_up_to_its_last_chunk(stack, tmp_path):  # noqa: F811
    stack.router()
    stack.aggregator()
    stack.emulator(2, 1.0)
    killed, stopped = tmp_path / "killed.mcap", tmp_path / "stopped.mcap"
    victim = stack.start("record", "record", str(killed), "--connect", stack.endpoint)

    def complete_chunks():
        count = 0
        try:
            with open(killed, "rb") as f:
                for record in StreamReader(f, emit_chunks=True).records:
                    count += isinstance(record, Chunk)
        except (McapError, OSError):
            pass
        return count
    wait_until(lambda: complete_chunks() >= 3, 30, "three flushed chunks", on_fail=stack.logs)
    # started once points flow: its history query brings the devices' cached points at once
    timed = stack.start("record", "record", str(stopped), "--connect", stack.endpoint, "--duration", "3")
    os.killpg(victim.popen.pid, signal.SIGKILL)
    victim.popen.wait(10)
    with open(killed, "rb") as f:  # the mcap library: records up to the end of the last chunk, then an error
        messages, topics = [], {}  # (the end of the file, or the chunk in progress whose length was never written)
        with pytest.raises(McapError):
            for record in StreamReader(f).records:
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message):
                    messages.append(topics[record.channel_id])
    assert len(messages) >= 100
    rec = Recording(killed)
    kinds = collections.Counter(e.kind for e in rec.entries())
    assert rec.truncated and kinds["seg"] > 0 and kinds["pose"] > 0, (rec.truncated, kinds)
    assert sum(kinds.values()) == sum(1 for t in messages if t.startswith("/limbstream/"))
    # cut in the middle of a chunk: still read up to the chunk before
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(killed.read_bytes()[: killed.stat().st_size - 100])
    rec = Recording(cut)
    assert sum(1 for _ in rec.entries()) > 0 and rec.truncated.startswith("cut inside a record"), rec.truncated

    # --duration: closed properly, with a summary
    wait_until(lambda: timed.returncode is not None, 30, "the --duration recorder to stop")
    assert timed.returncode == 0, stack.logs()
    said = next(json.loads(line.removeprefix("record: ")) for line in reversed(timed.tail())
                if line.startswith("record: "))["messages"]
    with open(stopped, "rb") as f:
        assert make_reader(f).get_summary().statistics.message_count > 0
    rec = Recording(stopped)
    assert not rec.truncated and said["seg"] > 0, (rec.truncated, said)
    assert collections.Counter(e.kind for e in rec.entries()) == collections.Counter(said)  # what it says it wrote


def test_a_broken_recording_replays_into_an_aggregator_that_counts_and_drops(stack, watch, tmp_path):  # noqa: F811
    """Payloads, keys and envelopes that break the contract go out as recorded (or are skipped):
    the aggregator's decoders count and drop them, it keeps running, the good points get through."""
    path = tmp_path / "broken.mcap"
    writer = RecordingWriter(path, skeleton=False)
    key, t0 = wire.seg_key("s01", "hip"), 1_800_000_000_000_000
    for seq in range(3):
        point = wire.SegmentPoint(7, seq, 10 * seq, t0 + 200_000 * seq, (1.0, 0.0, 0.0, 0.0))
        writer.add("seg", key, wire.encode_point(point), 1_000_000 * seq)
    writer.add("seg", key, b"short", 3_000_000)
    writer.add("seg", key, b"\x01" * 36, 3_000_001)  # version 1, quaternion far from unit
    writer.add("raw", wire.raw_key("s01", "hip"), b"\x01\x00", 3_000_002)
    writer.add("seg", "limbstream/s01/seg", b"x" * 36, 3_000_003)  # not a device key
    writer.channels["seg"].log(b"\x09", log_time=3_000_004)  # not an envelope
    writer.close()
    stack.aggregator()
    wait_for_subscribers(stack.endpoint, [key], "the aggregator", on_fail=stack.logs)
    replay = stack.start("replay", "replay", str(path), "--connect", stack.endpoint, "--hold", "5")

    def counted():
        d = watch.poll().get("s01/hip")
        return d and d["points"] == 3 and {"version", "non_unit", "raw_size"} <= set(d["dropped_by_reason"]) and d
    d = wait_until(counted, 30, "the good points in, the bad ones counted",
                   on_fail=lambda: f"{watch.devices.get('s01/hip')}{stack.logs()}")
    assert d["online"] and stack.procs[0].alive()
    assert replay.popen.wait(30) == 0
    log = replay.log.read_text()
    assert "refused by the contract" in log and "seg_version" in log and "seg_key" in log, log
    assert all(c.alive() for c in stack.procs if c.name != "replay"), stack.logs()


def test_replayed_devices_answer_status_with_the_recorded_settings_and_refuse_changes(stack, tmp_path):  # noqa: F811
    """A replayed device answers a config query with the settings the recording gave it up to the
    replayed moment (its recorded status; else its stats row) and its stream and points as
    replayed; one the recording says nothing of answers with an error; a change is refused."""
    path = tmp_path / "settings.mcap"
    t0, s = 1_800_000_000_000_000, 1_000_000_000  # device time (us); one second of receive time (ns)
    messages = []  # (receive time, kind, key, payload), written in receive order as a recorder does
    for k in range(10):  # a point per second from three devices
        for segment in ("hip", "neck", "l_shank"):
            point = wire.SegmentPoint(7, k, 50 * k, t0 + 1_000_000 * k, (1.0, 0.0, 0.0, 0.0))
            messages.append((s + k * s, "seg", wire.seg_key("s01", segment), wire.encode_point(point)))
    clock = wire.ClockStatus(1.5, 0.4, True, {})
    for at, threshold in ((0, 0.005), (int(7.5 * s), 0.007)):  # the hip's status, changed after 7.5 s
        status = wire.DeviceStatus("s01/hip", wire.DeviceConfig(threshold=threshold, max_len=30), 7, 0, 0, clock)
        messages.append((s + at, "config", wire.config_key("s01", "hip"), wire.encode_status(status)))
    row = {"device": "s01/neck", "segment": "neck", "threshold": 0.02, "max_len": 40, "live_bound_deg": 5.0}
    messages.append((s + 1, "stats", wire.stats_key("s01"), wire.encode_stats("s01", 1.0, [row])))
    writer = RecordingWriter(path, skeleton=False)
    for log_ns, kind, key, payload in sorted(messages, key=lambda m: m[0]):
        writer.add(kind, key, payload, log_ns)
    writer.close()
    stack.router()
    stack.start("replay", "replay", str(path), "--connect", stack.endpoint, "--subject-prefix", "r-", "--hold", "30")
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    try:
        def ask(key: str, payload: bytes | None = None) -> dict[str, dict]:
            """{device or "error": answer} of a get on ``key``."""
            out = {}
            for reply in session.get(key, payload=payload, timeout=5.0):
                if reply.ok is not None:
                    out[wire.parse_device_key(str(reply.ok.key_expr))[1]] = wire.decode_status(reply.ok.payload.to_bytes())
                else:
                    out.setdefault("error", []).append(json.loads(reply.err.payload.to_bytes())["error"])
            return out
        every = wire.device_selector("config", "r-s01")
        first = wait_until(lambda: (a := ask(every)) and {"hip", "neck"} <= set(a) and a, 20,
                           "the replayed devices to answer", on_fail=stack.logs)
        hip, neck = first["hip"], first["neck"]
        assert hip.device == "r-s01/hip" and hip.config == wire.DeviceConfig(threshold=0.005, max_len=30), hip
        assert hip.stream == 7 and hip.points >= 1 and hip.samples == 50 * (hip.points - 1) + 1 and hip.clock == clock
        assert neck.config == wire.DeviceConfig(threshold=0.02, max_len=40, live_bound_deg=5.0), neck
        assert first["error"] == ["replayed device r-s01/l_shank: the recording holds no settings of it (yet)"], first
        # a change is refused, and changes nothing
        refused = ask(wire.config_key("r-s01", "hip"), wire.encode_config({"threshold": 0.1}))
        assert refused == {"error": [FIXED]}, refused
        # the recorded change at 8 s, and every point replayed
        later = wait_until(lambda: (a := ask(wire.config_key("r-s01", "hip"))) and a["hip"].points == 10 and a, 30,
                           "the hip's last point replayed", on_fail=stack.logs)["hip"]
        assert later.config.threshold == 0.007 and later.samples == 451, later
    finally:
        session.close()


# ----------------------------------------------------------------------------- bad input


def one_line_error(result: subprocess.CompletedProcess, *words: str) -> str:
    """The one line of error (besides the line that says where the command connects)."""
    err = "\n".join(line for line in result.stderr.strip().splitlines() if ": connecting to " not in line)
    assert result.returncode == 2, (result.returncode, result.stdout, err)
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, (word, err)
    return err


def test_bad_recordings_and_paths_are_one_line_errors(tmp_path):
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_message(w.register_channel("/camera", "json", 0), 1, b"{}", 1)
        w.finish()
    one_line_error(cli("replay", str(foreign)), "foreign.mcap", "not a limbstream recording", "/camera")
    text = tmp_path / "notes.mcap"
    text.write_text("hello")
    one_line_error(cli("replay", str(text)), "notes.mcap", "not an MCAP file")
    one_line_error(cli("replay", str(tmp_path / "absent.mcap")), "absent.mcap", "no such file")
    # a recording cut before its first chunk ended
    rec = tmp_path / "rec.mcap"
    writer = RecordingWriter(rec, skeleton=False)
    writer.add("seg", wire.seg_key("s01", "hip"), wire.encode_point(wire.SegmentPoint(1, 0, 0, 0, (1, 0, 0, 0))), 1)
    writer.close()
    stub = tmp_path / "stub.mcap"
    stub.write_bytes(rec.read_bytes()[:60])
    one_line_error(cli("replay", str(stub)), "stub.mcap", "truncated")
    one_line_error(cli("record", str(tmp_path / "no" / "such" / "dir.mcap"), "--duration", "1"), "dir.mcap",
                   "cannot write")
    one_line_error(cli("record", str(tmp_path / "x.mcap"), "--subjects", "a/b"), "--subjects")
    one_line_error(cli("replay", str(rec), "--speed", "0"), "--speed")
    one_line_error(cli("replay", str(rec), "--subject-prefix", "a/"), "--subject-prefix")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        endpoint = f"tcp/127.0.0.1:{taken.getsockname()[1]}"
        one_line_error(cli("record", str(tmp_path / "y.mcap"), "--listen", endpoint, "--duration", "1"),
                       "--listen", endpoint, "in use")
        one_line_error(cli("replay", str(rec), "--listen", endpoint), "--listen", "in use")
    assert not (tmp_path / "y.mcap").exists()


def test_envelope_round_trip_and_refusals():
    key = wire.seg_key("s01", "hip")
    assert open_envelope(envelope(key, b"\x01\x02")) == (key, b"\x01\x02")
    for bad in (b"", b"\x05\x00ab", b"\x02\x00\xff\xfe"):
        with pytest.raises(wire.WireError) as info:
            open_envelope(bad)
        assert info.value.reason == "envelope"
