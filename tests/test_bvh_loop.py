"""A BVH walk looped on its own cycle with its root travelling on (limbstream.sources.bvh_loop),
checked through an independent BVH reader, and ``eval --loop-minutes`` scoring root translation
over the looped walk."""
from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np
import pytest
from support.bvh import read_bvh_positions, write_bvh

from limbstream import cli, quat
from limbstream.cli import emulate
from limbstream.calibration import yaw
from limbstream.sources import load
from limbstream.sources.bvh import parse_bvh
from limbstream.sources import bvh_loop
from limbstream.sources.bvh_loop import looped_clip, looped_motion


def test_a_looped_walk_replays_its_cycle_turned_and_moved_on(cmu_bvh_dir, tmp_path):
    clip = parse_bvh(cmu_bvh_dir / "02_01.bvh")
    loop = looped_clip(clip, 12.0)
    out = loop.clip
    i, j, period = loop.i, loop.j, loop.j - loop.i
    assert out.n_frames == round(12.0 / clip.frame_time) and period * clip.frame_time >= 0.5 * clip.n_frames * clip.frame_time
    assert loop.mismatch_m < 0.5  # file units (unit_m 1): CMU's 0.056 m each, under 3 cm
    np.testing.assert_array_equal(out.motion[:j], clip.motion[:j])  # the first pass is the file's
    rows = np.arange(j, out.n_frames)
    src = i + (rows - j) % period
    np.testing.assert_array_equal(out.motion[rows, 6:], clip.motion[src, 6:])  # every joint but the root as it was
    # the file's joints, read independently: each pass is the file's pose turned about the vertical
    # and carried on, its root's path unbroken at the seams
    (tmp_path / "in.bvh").write_text(write_bvh(clip))
    (tmp_path / "loop.bvh").write_text(write_bvh(out))
    orig, looped = read_bvh_positions(tmp_path / "in.bvh"), read_bvh_positions(tmp_path / "loop.bvh")
    root = clip.joints[0]
    names = [n for n in clip.joints if n != root]
    for k in range(1, (out.n_frames - j) // period):
        a, b = j + k * period, j + k * period + period // 2  # two frames of pass k
        want = np.stack([orig[n][src[b - j]] - orig[n][src[a - j]] for n in names])
        got = np.stack([looped[n][b] - looped[n][a] for n in names])
        want[:, 1] -= (orig[root][j, 1] - orig[root][i, 1]) * (b - a) / period  # the height's ramp along the pass
        # the same motion within the pass, turned by one angle about the vertical (least squares)
        (wx, wz), (gx, gz) = want[:, [0, 2]].T, got[:, [0, 2]].T
        angle = np.arctan2((wz * gx - wx * gz).sum(), (wx * gx + wz * gz).sum())
        np.testing.assert_allclose(got, quat.rotate(yaw(angle), want), atol=1e-4 * np.abs(want).max())
    path = looped[root]
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert steps.max() <= 1.05 * np.linalg.norm(np.diff(orig[root], axis=0), axis=1).max()
    walked = np.linalg.norm(path[-1, [0, 2]] - path[0, [0, 2]])
    assert walked > 8.0  # 12 s of a straight walk at about 1.3 m/s, not on the spot


def test_a_clip_without_a_root_path_or_too_short_is_refused(cmu_bvh_dir):
    clip = parse_bvh(cmu_bvh_dir / "02_01.bvh")
    still = dataclasses.replace(clip, channels=(tuple(c for c in clip.channels[0] if c.endswith("rotation")),)
                                + clip.channels[1:], motion=clip.motion[:, 3:])
    with pytest.raises(ValueError, match="no joint carries a path to loop on"):
        looped_clip(still, 10.0)
    with pytest.raises(ValueError, match="too short"):
        looped_clip(dataclasses.replace(clip, motion=clip.motion[:100]), 10.0)
    [motion] = load(cmu_bvh_dir / "02_01.bvh", layout="full")
    with pytest.raises(ValueError, match="no BVH file"):
        looped_motion(dataclasses.replace(motion, root=None), 10.0, "full")


def test_eval_loops_a_walk_with_its_root_travelling(cmu_bvh_dir, tmp_path, capsys):
    out = tmp_path / "rows.json"
    code = cli.main(["eval", str(cmu_bvh_dir / "131_01.bvh"), "--algorithms", "fastsw", "--thresholds", "9e-4",
                     "--max-len", "25", "--layout", "full", "--loop-minutes", "1", "--json", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "loop(131_01): the file's frames" in captured.err and "root walking on" in captured.err
    assert "131_01: the file's own joints" in captured.out.replace("loop(131_01)", "131_01")
    [row] = json.loads(out.read_text())
    [moved] = row["translation"]
    assert moved["motion"] == "loop(131_01)"
    assert 40 < moved["path_m"] < 90  # a minute of walking
    assert moved["end_pct"] < 3.0 and moved["below_cm"] < 2.0


def test_a_long_clip_is_searched_coarsely_then_frame_by_frame(cmu_bvh_dir, monkeypatch):
    clip = parse_bvh(cmu_bvh_dir / "131_01.bvh")
    exact = bvh_loop.loop_frames(clip, 0, 4.0)
    monkeypatch.setattr(bvh_loop, "SEARCH_FRAMES", 120)  # every 9th frame, then refined
    coarse = bvh_loop.loop_frames(clip, 0, 4.0)
    assert coarse[:2] == exact[:2] and coarse[1] - coarse[0] >= round(4.0 / clip.frame_time)


def test_a_path_under_a_static_root_is_looped_there(cmu_bvh_dir, tmp_path):
    """An exporter's static root above the pelvis (no channels): the pelvis carries the path and is
    what the loop moves on; the root stays where it is."""
    path = tmp_path / "floor.bvh"
    path.write_text(write_bvh(parse_bvh(cmu_bvh_dir / "02_01.bvh"), floor_root="Floor"))
    clip = parse_bvh(path)
    assert clip.joints[:2] == ("Floor", "Hips") and bvh_loop.moving_root(clip) == 1
    (tmp_path / "loop.bvh").write_text(write_bvh(looped_clip(clip, 12.0).clip))
    looped = read_bvh_positions(tmp_path / "loop.bvh")
    assert np.all(looped["Floor"] == 0.0)
    assert np.linalg.norm(looped["Hips"][-1, [0, 2]] - looped["Hips"][0, [0, 2]]) > 8.0


def test_a_clip_too_short_for_a_loop_is_looped_as_any_other(cmu_bvh_dir, tmp_path):
    """Half a second of a walk: no cycle to loop on, so ``emulate`` plays it as it plays any clip
    (starting again from its first frame), not refuse it."""
    clip = parse_bvh(cmu_bvh_dir / "02_01.bvh")
    (tmp_path / "short.bvh").write_text(write_bvh(dataclasses.replace(clip, motion=clip.motion[:60])))
    [motion] = load(tmp_path / "short.bvh", layout="full")
    assert motion.root is not None and not bvh_loop.walks_on(motion)
    parser = argparse.ArgumentParser()
    emulate.add_arguments(parser)
    [feed] = emulate.build_feeds(parser.parse_args(["--source", str(tmp_path / "short.bvh"), "--layout", "full",
                                                    "--subjects", "1"])).values()
    assert feed.motion.name == "short" and len(feed.q) == len(motion.t)
