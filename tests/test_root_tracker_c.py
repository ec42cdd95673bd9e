"""The root tracker in C (RootTracker.frames, firmware_c/host/lsw_root.c) against its numpy
reference (RootTracker.step, taken rank by rank as the aggregator took it): the same roots
(within 1e-9 m), contact bits, flags and state, frame for frame, on random walks of several rows
with every kind of frame the tracker knows, and on real clips' feet."""
from __future__ import annotations

import ctypes
import sys
from pathlib import Path

import numpy as np
import pytest
from test_root_bad_input import fall
from test_root_translation import FS, NAMES, gait

from limbstream.body.translation import RootTracker
from limbstream.wire import FRAME_OFF_FEET

ARRAYS = ("root", "velocity", "pace", "anchor", "anchor_xyz", "t", "height", "points", "seen", "refused")
POINTS = (*NAMES, "l_knee", "r_knee", "l_fingertip")
FLIGHT, COAST = -1, -3


def by_step(tracker: RootTracker, owner, t, points, usable, commit):
    """The numpy reference: each row's 1st frames in one step, then its 2nd, ... (rows distinct)."""
    root, bits, flags = np.zeros((len(owner), 3)), np.zeros(len(owner), np.int64), np.zeros(len(owner), np.int64)
    rank = np.zeros(len(owner), np.int64)
    for row in np.unique(owner):
        at = np.flatnonzero(owner == row)
        rank[at] = np.arange(len(at))
    for r in range(int(rank.max()) + 1 if len(owner) else 0):
        at = np.flatnonzero(rank == r)
        root[at], bits[at], flags[at] = tracker.step(owner[at], t[at], points[at], commit, usable[at])
    return root, bits, flags


def assert_same(c: RootTracker, ref: RootTracker, got, want) -> None:
    assert np.abs(got[0] - want[0]).max(initial=0.0) <= 1e-9
    assert np.array_equal(got[1], want[1]) and np.array_equal(got[2], want[2])
    for name in ARRAYS:
        a, b = getattr(c, name), getattr(ref, name)
        if a.dtype.kind == "f":
            assert np.abs(a - b).max(initial=0.0) <= 1e-9, name
        else:
            assert np.array_equal(a, b), name


def state(tracker: RootTracker) -> list[np.ndarray]:
    return [getattr(tracker, name).copy() for name in ARRAYS]


def jump(n: int) -> np.ndarray:
    """(n, 7, 3) points of a body that, every 2 s, crouches, pushes off at about 1.5 m/s, flies (its legs held
    straight, 1 m below the root) and lands: the points root-relative."""
    t = np.arange(n) / FS
    leg = np.interp(t % 2.0, [0.0, 0.5, 0.8, 0.9, 1.2, 1.5, 2.0], [0.95, 0.95, 0.85, 1.0, 1.0, 0.95, 0.95])
    _, points, truth = fall(1)
    world = points[0] + truth[0]  # standing: its points in the room
    return world[None] - np.stack([np.zeros(n), leg, np.zeros(n)], axis=1)[:, None]


def motion(kind: int, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Times (n,) s and points (n, 7, 3) of one row: a walk, a fall, a jump or standing, jittered,
    with bad frames (non-finite points or times, repeated or earlier times) among them."""
    if kind == 0:
        feet, _ = gait(n)
        points = np.concatenate([feet, np.array([[0.1, -0.5, 0.0], [-0.1, -0.5, 0.0], [0.3, -0.3, 0.2]])
                                 [None].repeat(n, axis=0)], axis=1)
    elif kind == 1:
        points = fall(n)[1]
    else:
        points = jump(n) if kind == 2 else jump(n)[:1].repeat(n, axis=0)
    points = points + rng.normal(0.0, 0.002, points.shape)
    t = np.arange(n) / FS + rng.uniform(0.0, 0.004, n)
    for k in rng.choice(n, n // 15, replace=False):
        what = rng.integers(5)
        if what == 0:
            points[k, rng.integers(7), rng.integers(3)] = np.nan
        elif what == 1:
            points[k, rng.integers(7), 1] = np.inf
        elif what == 2:
            t[k] = np.nan
        elif k:
            t[k] = t[k - 1] if what == 3 else t[k - 1] - rng.uniform(0.01, 0.5)
    return t, points


def taken_by(order: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(len(rows),) how many frames of each of ``rows`` ``order`` holds (the next one's index)."""
    return np.array([(order == r).sum() for r in rows])


def usable_of(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 7) bool: a foot's points missing for stretches, single points now and then, sometimes
    both feet (a frame without a usable foot point)."""
    use = np.ones((n, 7), bool)
    for _ in range(2):
        a = int(rng.integers(n))
        side = slice(0, 2) if rng.integers(2) else slice(2, 4)
        use[a:a + int(rng.integers(10, 80)), side] = False
    use &= rng.random((n, 7)) > 0.03
    use[rng.choice(n, 3), :4] = False
    return use


@pytest.mark.parametrize("seed", range(4))
def test_interleaved_rows_match_the_numpy_step(seed):
    """Rows of walks, falls, jumps and standing, their frames interleaved and cut into batches
    of any size, two rows joining halfway (their first frames among the others' later ones);
    between batches, live frames (no commit)."""
    rng = np.random.default_rng(seed)
    rows, n = 8, 300
    motions = [motion(row % 4, n, rng) for row in range(rows)]
    usable = [usable_of(n, rng) for _ in range(rows)]
    early = rng.permutation(np.repeat(np.arange(rows - 2), n))  # each row's frames in turn, interleaved
    half = len(early) // 2
    order = np.concatenate([early[:half], rng.permutation(np.concatenate([early[half:],
                                                                          np.repeat([rows - 2, rows - 1], n)]))])
    taken = np.zeros(rows, np.int64)
    frame = np.empty(len(order), np.int64)  # each frame's index among its row's
    for i, row in enumerate(order):
        frame[i], taken[row] = taken[row], taken[row] + 1
    c, ref = RootTracker(rows - 2, POINTS), RootTracker(rows - 2, POINTS)
    anchors, flags = [], []
    start = 0
    while start < len(order):
        stop = start + int(rng.integers(1, 40))
        if stop > half:  # new subjects' rows
            c.grow(rows)
            ref.grow(rows)
        owner, k = order[start:stop], frame[start:stop]
        t = np.array([motions[r][0][i] for r, i in zip(owner, k)])
        points = np.stack([motions[r][1][i] for r, i in zip(owner, k)])
        use = np.stack([usable[r][i] for r, i in zip(owner, k)])
        got = c.frames(owner, t, points, use, True)
        assert_same(c, ref, got, by_step(ref, owner, t, points, use, True))
        anchors.append(ref.anchor.copy())
        flags.append(got[2])
        live = rng.choice(len(c.t), int(rng.integers(1, len(c.t) + 1)), replace=False)
        t_live = ref.t[live] + rng.uniform(-0.01, 0.05, len(live))
        nexts = np.minimum(taken_by(order[:stop], live), n - 1)  # each live row's next frame
        p_live = np.stack([motions[r][1][i] for r, i in zip(live, nexts)])
        use_live = rng.random((len(live), 7)) > 0.1
        before = state(c)
        assert_same(c, ref, c.frames(live, t_live, p_live, use_live, False),
                     by_step(ref, live, t_live, p_live, use_live, False))
        assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(state(c), before))
        start = stop
    seen = np.concatenate(anchors)
    assert (seen == FLIGHT).any() and (seen == COAST).any() and (seen >= 4).any()  # flights, coasting, off feet
    assert (np.concatenate(flags) & FRAME_OFF_FEET).any() and (ref.refused > 0).all()


def test_final_and_live_frames_in_one_call_give_what_two_calls_give():
    """A tick's frames of several rows in one call, commit per frame (the aggregator's exact frames,
    several a row, then one live frame a row): the roots, bits and flags of a call with the final
    frames and then one with the live frames, and the same state (moved by the final frames only)."""
    rng = np.random.default_rng(11)
    rows, n, per = 4, 200, 5
    motions = [motion(row % 4, n, rng) for row in range(rows)]
    usable = [usable_of(n, rng) for _ in range(rows)]
    one, two = RootTracker(rows, POINTS), RootTracker(rows, POINTS)
    for start in range(0, n - per, per):
        owner = np.repeat(np.arange(rows), per)  # each row's frames oldest first
        k = np.tile(np.arange(start, start + per), rows)
        live_k = np.full(rows, start + per)
        t = np.concatenate([[motions[r][0][i] for r, i in zip(owner, k)], [motions[r][0][i] for r, i in enumerate(live_k)]])
        points = np.stack([motions[r][1][i] for r, i in zip(owner, k)] + [motions[r][1][i] for r, i in enumerate(live_k)])
        use = np.stack([usable[r][i] for r, i in zip(owner, k)] + [usable[r][i] for r, i in enumerate(live_k)])
        final = np.arange(len(t)) < len(owner)
        got = one.frames(np.concatenate([owner, np.arange(rows)]), t, points, use, final)
        want = [two.frames(owner, t[final], points[final], use[final], True),
                two.frames(np.arange(rows), t[~final], points[~final], use[~final], False)]
        for g, w_final, w_live in zip(got, *want):
            assert np.array_equal(g, np.concatenate([w_final, w_live]))
        assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(state(one), state(two)))
    assert (one.refused > 0).any() and (one.anchor >= 0).any()


@pytest.mark.parametrize("clip", ["131_01", "05_06"])
def test_a_real_clips_feet_match_the_numpy_step(cmu_bvh_dir, clip):
    """A clip's heels and toes (bench/root_translation.py), three rows of it interleaved: whole,
    a foot missing for a stretch, and starting later."""
    root_dir = Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root_dir / "bench"))
    try:
        import root_translation
    finally:
        sys.path.remove(str(root_dir / "bench"))
    t, truth, feet = root_translation.file_feet(cmu_bvh_dir / f"{clip}.bvh")
    rel = feet - truth[:, None]
    n = len(t)
    use = np.ones((3, n, 4), bool)
    use[1, n // 3:n // 2, :2] = False
    owner = np.tile(np.arange(3), n)
    k = np.repeat(np.arange(n), 3)
    keep = (owner != 2) | (k >= n // 4)
    owner, k = owner[keep], k[keep]
    c, ref = RootTracker(3, NAMES), RootTracker(3, NAMES)
    for start in range(0, len(owner), 97):
        o, i = owner[start:start + 97], k[start:start + 97]
        args = (o, t[i], rel[i], use[o, i])
        assert_same(c, ref, c.frames(*args, commit=True), by_step(ref, *args, commit=True))
    assert np.abs(ref.root[0] - c.root[0]).max() <= 1e-9 and c.anchor[0] >= 0


def test_frames_refuse_rows_out_of_range_and_too_many_points():
    tracker = RootTracker(2, NAMES)
    with pytest.raises(ValueError, match="rows must be in 0..1"):
        tracker.frames(np.array([2]), np.zeros(1), np.zeros((1, 4, 3)))
    with pytest.raises(ValueError, match="at most 128 points"):
        RootTracker(1, tuple(f"j{i}" for i in range(129))).frames(np.array([0]), np.zeros(1), np.zeros((1, 129, 3)))


def test_the_root_structs_have_the_c_sizes():
    """LswRootState and LswRootConst (lsw_abi.h 13, 14) as the binding copies them."""
    from limbstream.kernel._lib import RootConst, RootState, _lib
    assert [_lib.lsw_abi_size(k) for k in (13, 14)] == [ctypes.sizeof(RootState), ctypes.sizeof(RootConst)]
