"""Device emulator parts that run without a network: feeds and flag validation."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from device_emulator import main as emulate
from device_emulator.feeds import GeneratorFeed, LoopFeed, resample
from limbstream import quat
from limbstream.sources import Motion
from limbstream.sources.generator import GeneratorSource


@pytest.mark.parametrize("seed", [0, 3, 11])
def test_generator_feed_is_continuous_across_staggered_chunks(seed):
    feed = GeneratorFeed(seed, 50.0)
    got = np.stack([feed.sample(k) for k in range(1600)])
    want = GeneratorSource(seed, 50.0).chunk(0, 1600)[1].astype(np.float32)
    assert np.array_equal(got, want)


def test_loop_feed_resamples_jittered_time_and_loops():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.015, 0.025, 300))
    q = quat.normalize(np.cumsum(rng.normal(0, 0.02, (300, 2, 4)), axis=0) + [1, 0, 0, 0])
    motion = Motion(t, q, ("hip", "neck"), "jitter")
    uniform = resample(motion, 50.0)
    assert np.allclose(np.diff(uniform.t), 0.02)
    ref = np.stack([quat.interpolate(t, q[:, s], uniform.t) for s in range(2)], axis=1)
    assert np.max(quat.angle_deg(uniform.q, ref)) < 1e-9
    feed = LoopFeed(motion, 50.0, once=True)
    assert feed.length == len(uniform.t)
    assert np.array_equal(feed.sample(feed.length), feed.sample(0))


def parse(*argv):
    parser = argparse.ArgumentParser()
    emulate.add_arguments(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize("argv, words", [
    (["--subjects", "0"], "--subjects"), (["--rate", "-5"], "--rate"), (["--max-len", "0"], "--max-len"),
    (["--threshold", "-1"], "--threshold"), (["--raw-batch", "0"], "--raw-batch"),
])
def test_bad_flags_give_clear_errors(argv, words):
    with pytest.raises(SystemExit, match=words):
        emulate.validate(parse(*argv))


def test_missing_source_file_is_a_clear_error(tmp_path):
    args = parse("--source", str(tmp_path / "nope.bvh"))
    with pytest.raises(SystemExit, match="nope.bvh"):
        emulate.run(args)


def test_subject_names_are_key_chunks():
    assert emulate.subject_names(3, 9) == ["s09", "s10", "s11"]
    with pytest.raises(ValueError):
        emulate.subject_names(1, 1, prefix="a/b")
