"""Device emulator parts that run without a network: feeds and flag validation."""
from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from limbstream.body import FULL, PAPER10, load_layout
from limbstream.cli import emulate, flags
from limbstream.device.feeds import FeedRows, GeneratorFeed, LoopFeed, resample
from limbstream import kernel, quat, wire
from limbstream.sources import SEGMENTS, Motion
from limbstream.sources.generator import GeneratorSource


@pytest.mark.parametrize("seed", [0, 3, 11])
def test_generator_feed_is_continuous_across_staggered_chunks(seed):
    feed = GeneratorFeed(seed, 50.0)
    got = np.stack([feed.sample(k) for k in range(1600)])
    want = GeneratorSource(seed, 50.0).chunk(0, 1600)[1].astype(np.float32)
    assert np.array_equal(got, want)


@pytest.mark.parametrize("rates, layouts", [((50.0, 50.0), ("paper10",) * 2), ((50.0, 100.0), ("paper10",) * 2),
                                            ((50.0, 50.0), ("full",) * 2), ((50.0, 50.0), ("paper10", "full"))],
                         ids=["one gather", "chunks of two lengths", "full bodies", "two layouts"])
def test_feed_rows_are_each_feeds_sample_stacked(rates, layouts):
    rng = np.random.default_rng(4)
    q = quat.normalize(np.cumsum(rng.normal(0, 0.02, (90, 2, 4)), axis=0) + [1, 0, 0, 0])
    clip = Motion(np.arange(90) / 50.0, q, ("hip", "neck"), "short")

    def made() -> list:
        return [LoopFeed(clip, 50.0), GeneratorFeed(2, rates[0], layout=layouts[0]),
                GeneratorFeed(5, rates[1], layout=layouts[1]), LoopFeed(clip, 50.0, once=True)]
    feeds, plain = made(), made()
    rows = FeedRows(feeds)
    for k in [*range(0, 1300, 7), 3, 2000]:  # chunk after chunk, back to the first one, a jump ahead
        for count in (4, 3, 2):
            want = np.concatenate([f.sample(min(k, f.length - 1) if f.length else k) for f in plain[:count]])
            assert np.array_equal(rows.rows(k, count), want), (k, count)


def test_loop_feed_resamples_jittered_time_and_loops():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.015, 0.025, 300))
    q = quat.normalize(np.cumsum(rng.normal(0, 0.02, (300, 2, 4)), axis=0) + [1, 0, 0, 0])
    motion = Motion(t, q, ("hip", "neck"), "jitter")
    uniform = resample(motion, 50.0)
    assert np.allclose(np.diff(uniform.t), 0.02)
    ref = np.stack([quat.interpolate(t, q[:, s], uniform.t) for s in range(2)], axis=1)
    assert np.max(quat.angle_deg(uniform.q, ref)) < 1e-9
    loop = LoopFeed(motion, 50.0)
    assert loop.length is None
    assert np.array_equal(loop.sample(len(uniform.t) + 7), loop.sample(7))


def test_once_feed_ends_at_its_own_last_sample():
    rng = np.random.default_rng(1)
    q = quat.normalize(np.cumsum(rng.normal(0, 0.02, (137, 2, 4)), axis=0) + [1, 0, 0, 0])
    feed = LoopFeed(Motion(np.arange(137) / 50.0, q, ("hip", "neck"), "short"), 50.0, once=True)
    assert feed.length == 137
    assert np.array_equal(feed.sample(136), q[136].astype(np.float32))
    for k in (137, 138, 137 + 5, -1):
        with pytest.raises(IndexError, match="137-sample"):
            feed.sample(k)


def test_a_feed_can_start_into_its_clip_and_still_plays_all_of_it():
    rng = np.random.default_rng(2)
    q = quat.normalize(np.cumsum(rng.normal(0, 0.02, (100, 1, 4)), axis=0) + [1, 0, 0, 0])
    motion = Motion(np.arange(100) / 50.0, q, ("hip",), "short")
    feed = LoopFeed(motion, 50.0, start=0.25)
    assert np.array_equal(feed.sample(0), q[25].astype(np.float32))
    assert np.array_equal(feed.sample(75), q[0].astype(np.float32)) and np.array_equal(feed.sample(100), feed.sample(0))
    with pytest.raises(ValueError, match="start"):
        LoopFeed(motion, 50.0, start=1.0)


def test_bank_advances_only_the_streams_still_running():
    """The emulator's ended devices are the bank's last slots: update(n rows) leaves the others as they are."""
    rng = np.random.default_rng(2)
    y = quat.normalize(np.cumsum(rng.normal(0, 0.05, (200, 3, 4)), axis=0) + [1, 0, 0, 0]).astype(np.float32)
    ticks = (np.arange(200) * 20_000).astype(np.uint32)
    bank = kernel.SegmenterBank(3, threshold=1e-3, max_len=25)
    got = [[], [], []]

    def take(j, point):
        if point is not None:
            got[j].append(int(point[0]))
    for k in range(200):
        n = 3 if k < 120 else 1  # streams 1 and 2 end after sample 119
        status, index, _ = bank.update(np.full(n, ticks[k]), y[k, :n])
        assert len(status) == len(index) == n
        for j in np.flatnonzero(status == kernel.POINT):
            got[j].append(int(index[j]))
        if k == 119:
            take(1, bank.flush(1))
            take(2, bank.flush(2))
    take(0, bank.flush(0))
    for j, m in ((0, 200), (1, 120), (2, 120)):
        want = kernel.segment(ticks[:m] / 1e6, y[:m, j], 1e-3, 25).index.tolist()
        assert got[j] == want, f"stream {j}: last points {got[j][-3:]} vs offline {want[-3:]}"
    assert bank.flush(1) is None and bank.flush(2) is None  # nothing was fed after their end
    with pytest.raises(ValueError, match="n <= 3"):
        bank.update(np.zeros(4, np.uint32), np.zeros((4, 4), np.float32))


def parse(*argv):
    parser = argparse.ArgumentParser()
    emulate.add_arguments(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize("argv, words", [
    (["--subjects", "0"], "--subjects"), (["--rate", "-5"], "--rate"), (["--raw-batch", "0"], "--raw-batch"),
])
def test_bad_flags_give_clear_errors(argv, words):
    with pytest.raises(SystemExit, match=words):
        emulate.validate(parse(*argv))  # (the device tunables are refused while parsing: tests/test_bounds.py)


def test_missing_source_file_is_a_clear_error(tmp_path):
    args = parse("--source", str(tmp_path / "nope.bvh"))
    with pytest.raises(SystemExit, match="nope.bvh"):
        emulate.run(args)


def test_subject_names_are_key_chunks():
    assert emulate.subject_names(3, 9) == ["s09", "s10", "s11"]
    with pytest.raises(ValueError):
        emulate.subject_names(1, 1, prefix="a/b")


@pytest.mark.parametrize("argv, words", [
    (["--layout", "fullest"], "--layout: layout must be one of paper10, full or a .toml/.json file, got 'fullest'"),
    (["--layout", "examples/layouts/suit17.toml"], "layout suit17: the generator moves no segment 'l_clavicle'"),
    (["--layout", "full", "--body", "examples/bodies/nope.toml"], "nope.toml"),
])
def test_a_layout_the_generator_cannot_move_is_a_clear_error(argv, words):
    with pytest.raises((SystemExit, flags.FlagError)) as caught:
        emulate.run(parse(*argv, "--duration", "0.1"))
    assert words in str(caught.value)


def test_a_motion_files_segments_must_be_in_the_layout(tmp_path):
    """A motion file streams its own segments: ``--layout`` names the body they announce."""
    path = tmp_path / "clip.npz"
    q = np.tile([1.0, 0.0, 0.0, 0.0], (50, len(SEGMENTS), 1))
    np.savez(path, clip_a=q, fs=50.0, segment_names=np.array(SEGMENTS), rest_pose=np.array("standing"))
    with pytest.raises(SystemExit, match="--layout full: the source .*clip.npz moves segment neck, not in the layout"):
        emulate.run(parse("--source", str(path), "--layout", "full", "--duration", "0.1"))
    args = parse("--source", str(path), "--layout", "paper10", "--height-m", "1.6", "--subjects", "1")
    [feed] = emulate.build_feeds(args).values()
    assert feed.segments == SEGMENTS and feed.body.layout is PAPER10 and feed.body.height_m == 1.6


def test_a_layout_files_devices_announce_its_body_and_one_without_height_fractions_needs_body(tmp_path):
    """A layout file's subjects announce its default body (its layout whole on the wire), or the
    one ``--height-m``/``--body`` give; a file that sizes no bone by height is refused up front
    unless ``--body`` gives its bones."""
    rows = FULL.part("leg3", ("hip", "l_thigh", "l_shank")).to_dict()["segments"]
    path = tmp_path / "leg3.json"
    path.write_text(json.dumps({"name": "leg3", "segments": rows}))
    [feed] = emulate.build_feeds(parse("--subjects", "1", "--layout", str(path))).values()
    assert feed.body.layout == load_layout(path) and feed.body.height_m == 1.75
    assert wire.encode_body(feed.body)["layout"] == load_layout(path).to_dict()
    [feed] = emulate.build_feeds(parse("--subjects", "1", "--layout", str(path), "--height-m", "1.6")).values()
    assert feed.body.layout == load_layout(path) and feed.body.height_m == 1.6
    for row in rows:
        row.pop("height_fraction")
        row.get("offset", {}).pop("height_fraction", None)
    path.write_text(json.dumps({"name": "leg3", "segments": rows}))
    with pytest.raises(flags.FlagError, match="gives no height fraction for bone 'hip'.*give its bones with --body FILE"):
        emulate.run(parse("--layout", str(path), "--duration", "0.1"))
    bones = tmp_path / "me.toml"
    bones.write_text("hip = 0.2\nl_hip = 0.1\nl_thigh = 0.4\nl_shank = 0.4\n")
    [feed] = emulate.build_feeds(parse("--subjects", "1", "--layout", str(path), "--body", str(bones))).values()
    assert feed.body.lengths == {"hip": 0.2, "l_hip": 0.1, "l_thigh": 0.4, "l_shank": 0.4}


def test_generator_feeds_of_a_layout_and_the_body_they_announce():
    [feed] = emulate.build_feeds(parse("--subjects", "1", "--layout", "full")).values()
    assert feed.segments == FULL.segment_names and feed.body.layout is FULL and feed.body.height_m == 1.75
    assert feed.sample(3).shape == (15, 4)
    [feed] = emulate.build_feeds(parse("--subjects", "1")).values()
    assert feed.segments == FULL.segment_names and feed.body.layout is FULL  # full: the default
    [feed] = emulate.build_feeds(parse("--subjects", "1", "--layout", "paper10")).values()
    assert feed.segments == SEGMENTS and feed.body is None  # paper10's default adult
    [feed] = emulate.build_feeds(parse("--subjects", "1", "--layout", "full", "--height-m", "1.9")).values()
    assert feed.body.layout is FULL and feed.body.height_m == 1.9
    [feed] = emulate.build_feeds(parse("--subjects", "1", "--layout", "full", "--imu", "raw")).values()
    assert feed.segments == FULL.segment_names


def test_a_bvh_walk_plays_looped_on_its_own_cycle_and_once_as_it_is(cmu_bvh_dir):
    """``emulate --source 02_01.bvh``: the walk is looped on its own cycle, each pass turned and
    carried on (limbstream.sources.bvh_loop), so the devices' orientations have no seam where it
    loops; ``--once`` plays the file as it is."""
    clip = str(cmu_bvh_dir / "02_01.bvh")
    [feed] = emulate.build_feeds(parse("--source", clip, "--layout", "full", "--subjects", "1")).values()
    motion = feed.motion
    assert motion.name == "loop(02_01)" and abs(motion.t[-1] - emulate.LIVE_LOOP_S) < 0.1
    steps = quat.angle_deg(motion.q[1:], motion.q[:-1]).max(axis=0)  # (S,) largest turn between samples
    [plain] = emulate.build_feeds(parse("--source", clip, "--layout", "full", "--subjects", "1", "--once")).values()
    assert plain.motion.name == "02_01" and plain.motion.t[-1] < 3.0
    own = quat.angle_deg(plain.motion.q[1:], plain.motion.q[:-1]).max(axis=0)
    wrap = quat.angle_deg(plain.motion.q[0], plain.motion.q[-1])  # a clip played again from its start
    assert (steps <= np.maximum(own, 20.0)).all() and steps.max() < wrap.max() / 4, (steps, own, wrap)


def test_the_subjects_of_one_clip_share_its_arrays(cmu_bvh_dir):
    """``emulate --source clip --subjects 3``: each subject plays the clip from its own place in it,
    and all three hold one copy of its samples (raw sensors: one of its readings)."""
    args = parse("--source", str(cmu_bvh_dir / "02_01.bvh"), "--layout", "full", "--subjects", "3")
    feeds = list(emulate.build_feeds(args).values())
    assert feeds[0].q is feeds[1].q is feeds[2].q
    assert len({f.offset for f in feeds}) == 3
    assert np.array_equal(feeds[1].sample(0), feeds[0].sample(feeds[1].offset))
    raw = list(emulate.build_feeds(parse("--source", str(cmu_bvh_dir / "02_01.bvh"), "--layout", "full",
                                         "--subjects", "2", "--imu", "raw")).values())
    assert raw[0].readings_feed is raw[1].readings_feed and raw[0] is not raw[1]
