"""Root translation on bad input (docs/body.md, "Root translation"): a layout without feet has none
(its frames say so and keep the origin), a foot device offline mid-walk leaves the root on the
other foot and resumes without a jump, a fall puts the lowest body point on the floor, and a frame
with a non-finite point or a time going back never reaches the root."""
from __future__ import annotations

import argparse
import threading

import numpy as np
import pytest
from support.stack import free_port
from test_aggregator_layouts import T0, aggregator, device, frames_of
from test_root_translation import FS, NAMES, gait, standing

from limbstream import wire
from limbstream.body import FULL, PAPER10, Body, layout_from_dict
from limbstream.body.translation import BodyPoints, RootTracker, has_feet
from limbstream.services.aggregator.rooting import Rooting
from limbstream.sources.generator import GeneratorSource
from limbstream.wire import CONTACTS

LEFT = (1 << CONTACTS.index("l_heel")) | (1 << CONTACTS.index("l_toe"))


def walk(layout, n: int, seed: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray, Body]:
    """Times (n,) us, orientations (n, S, 4) and joints (n, J, 3) of the generator's walk on
    ``layout`` (a layout file's: its segments of the walk on full), and the body drawing them."""
    t_us = (np.arange(n) * 20_000).astype(np.int64)
    body = Body.from_height(layout, 1.75)
    builtin = layout.name if layout.name in wire.LAYOUT_CODES else "full"
    q = GeneratorSource(seed, activities=["walking"], layout=builtin).orientations(t_us / 1e6)
    q = q[:, [FULL.segment_names.index(s) for s in layout.segment_names]] if builtin != layout.name else q
    return t_us, q, body.positions(q, False, dtype=np.float64), body


def state(tracker: RootTracker) -> list[np.ndarray]:
    return [a.copy() for a in (tracker.root, tracker.velocity, tracker.pace, tracker.anchor, tracker.anchor_xyz,
                               tracker.t, tracker.height, tracker.points, tracker.seen)]


def test_a_layout_without_feet_has_no_root_translation():
    """paper10, and a layout file's lower body without feet: frames at the origin without contacts,
    flagged NO_ROOT (no feet taken flat below the ankles); a full body is tracked as before."""
    no_feet = layout_from_dict(FULL.part("legs", ("hip", "l_thigh", "l_shank", "r_thigh", "r_shank")).to_dict())
    assert not has_feet(PAPER10) and not has_feet(no_feet) and has_feet(FULL)
    with pytest.raises(ValueError, match="layout paper10 has no feet"):
        BodyPoints(PAPER10)
    rooting = Rooting()
    for layout in (PAPER10, no_feet):
        t_us, q, joints, body = walk(layout, 100)
        root, contacts, flags = rooting.place(np.zeros(100, np.int64), t_us, q, joints, layout, [body], 0, True)
        assert not root.any() and not contacts.any() and (flags == wire.FRAME_NO_ROOT).all()
    t_us, q, joints, body = walk(FULL, 100)
    root, contacts, flags = rooting.place(np.zeros(100, np.int64), t_us, q, joints, FULL, [body], 0, True)
    assert root[:, 1].min() > 0.8 and contacts.all() and not flags.any()
    frame = wire.PoseFrames(np.arange(1), t_us[:1], wire.KIND_EXACT, np.array([wire.FRAME_NO_ROOT]), q[:1].astype(np.float32),
                            joints[:1].astype(np.float32), FULL, np.array([[0.0, 0.9, 0.0]]))[0]
    back = wire.decode_pose(wire.encode_pose(frame))
    assert not back.has_root and back.to_json("s01")["no_root"] and not back.to_json("s01")["off_feet"]


def test_up_and_eval_say_in_one_line_that_a_layout_without_feet_has_no_root(cmu_bvh_dir, tmp_path, capsys):
    """``up`` says why at its start; ``eval`` prints that line where the translation table would be."""
    from limbstream import cli
    from limbstream.cli import up as up_cli

    note = "root translation off: the paper10 layout has no feet (--layout full has them)"
    for argv, said in ((["--layout", "paper10"], True), ([], False)):  # (full by default)
        parser = argparse.ArgumentParser()
        up_cli.add_arguments(parser)
        args = parser.parse_args([*argv, "--no-sync", "--no-dashboard", "--router", f"tcp/127.0.0.1:{free_port()}",
                                  "--status-file", str(tmp_path / "status.json")])
        stop = threading.Event()
        stop.set()  # stopped before the first part starts
        assert up_cli.run(args, stop) == 130
        lines = capsys.readouterr().out.splitlines()
        assert (f"limbstream up: {note}" in lines) == said, lines
    code = cli.main(["eval", str(cmu_bvh_dir / "131_01.bvh"), "--algorithms", "fastsw", "--thresholds", "9e-4",
                     "--max-len", "25"])
    text = capsys.readouterr().out
    assert code == 0 and text.count(note) == 1 and "root translation from" not in text, text


def test_a_foot_missing_mid_walk_leaves_the_root_on_the_other_foot():
    """A walk whose left foot's points are held for 3 s (a device offline): not used, the root
    stands on the right foot and goes on at its pace between its steps, without a step of more
    than the walk's own, the left foot's contacts clear; the path as with both feet."""
    n = int(15 * FS)
    points, truth = gait(n)
    t = np.arange(n) / FS
    gone = (t >= 6.0) & (t < 9.0)
    held = points.copy()
    held[gone, :2] = points[np.flatnonzero(gone)[0] - 1, :2]  # the segment held at its last point
    usable = np.ones((n, 4), bool)
    usable[gone, :2] = False
    root, bits, _ = RootTracker(1, NAMES).track(t, held, usable=usable)
    steps = np.linalg.norm(np.diff(root, axis=0), axis=1)
    assert steps.max() < 0.024 + 1e-9  # the walk's own step per frame (1.2 m/s at 50 Hz)
    assert np.abs(root[:, 1] - 0.95).max() < 1e-9 and not (bits[gone] & LEFT).any()
    err = np.linalg.norm((root - root[0])[:, [0, 2]] - (truth - truth[0])[:, [0, 2]], axis=1)
    assert err.max() < 0.01, err.max()


def test_a_foot_device_offline_mid_walk_through_the_aggregator():
    """The generator's walk on full, the l_foot device offline from 3 s to 6 s: those frames are
    MISSING with the left foot's contacts clear, the root moves on without a step over 4 cm, and
    the path differs from the one with the device on by at most 15 % of the way walked meanwhile."""
    n, off, on = 500, 150, 300
    q = GeneratorSource(5, activities=["walking"], layout="full").orientations(np.arange(n) / 50.0)
    foot = FULL.segment_index["l_foot"]
    paths = []
    for drop in (True, False):
        agg, sent = aggregator()
        for segment in FULL.segment_names:
            device(agg, "w01", segment, Body.default(FULL))
        for k in range(n):
            if drop and k in (off, on):
                agg.on_alive(wire.alive_key("w01", "l_foot"), k == on)
            for s, segment in enumerate(FULL.segment_names):
                if not (drop and s == foot and off <= k < on):
                    point = wire.SegmentPoint(1, k, k, T0 + k * 20_000, tuple(q[k, s]), omega=(0.0, 0.0, 0.0))
                    agg.on_point(wire.seg_key("w01", segment), wire.encode_point(point), 0.0)
            if k % 10 == 9:
                agg.advance(live=True, now=0.0)
        frames = [f for _, f in frames_of(sent, "w01")]
        assert len(frames) == n
        paths.append(np.array([f.root for f in frames]))
        if drop:
            missing = np.array([f.flags & wire.FRAME_MISSING != 0 for f in frames])
            assert missing[off:on].all() and not missing[:off].any() and not missing[on:].any()
            assert not any(f.contacts & LEFT for f in frames[off:on]) and any(f.contacts for f in frames[off:on])
    dropped, whole = paths
    assert np.linalg.norm(np.diff(dropped, axis=0), axis=1).max() < 0.04
    meanwhile = np.linalg.norm(whole[on, [0, 2]] - whole[off, [0, 2]])
    assert np.linalg.norm(dropped[-1, [0, 2]] - whole[-1, [0, 2]]) < 0.15 * meanwhile


def fall(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A body that kneels, lies down with its legs off the floor, gets up: times (n,) s, its points
    (heels, toes, knees, a fingertip) root-relative (n, 7, 3), the true root (n, 3). Some point
    is on the floor in every frame; the points move only up and down in the room."""
    t = np.arange(n) / FS

    def ramp(a: float, b: float) -> np.ndarray:
        return np.clip((t - a) / (b - a), 0.0, 1.0)
    down = ramp(1.0, 2.0) - ramp(4.5, 5.5)    # the knees and the hand go to the floor, then back up
    legs = ramp(2.0, 2.5) - ramp(4.0, 4.5)    # the feet rise off it while lying
    world = np.zeros((n, 7, 3))
    world[:, :4, 0] = [0.1, 0.1, -0.1, -0.1]
    world[:, :4, 2] = [-0.05, 0.15, -0.05, 0.15]
    world[:, :4, 1] = 0.12 * legs[:, None]
    world[:, 4:6, 0], world[:, 4:6, 2] = [0.1, -0.1], 0.3
    world[:, 4:6, 1] = 0.45 * (1 - down[:, None]) + 0.06 * legs[:, None]
    world[:, 6] = np.stack([0.3 + 0 * t, 0.35 * (1 - down), 0.8 + 0 * t], axis=1)
    root = np.stack([0 * t, 0.95 - 0.75 * down, 0.2 * down], axis=1)
    return t, world - root[:, None], root


def test_a_fall_puts_the_lowest_body_point_on_the_floor_and_flags_it():
    n = int(7 * FS)
    t, points, truth = fall(n)
    names = (*NAMES, "l_knee", "r_knee", "l_fingertip")
    root, bits, flags = RootTracker(1, names).track(t, points)
    world_y = root[:, 1:2] + points[:, :, 1]
    assert np.abs(world_y.min(axis=1)).max() < 1e-9  # never buried, never floating
    assert np.abs(root - truth).max() < 0.02
    off = flags & wire.FRAME_OFF_FEET != 0
    feet_up = points[:, :4, 1].min(axis=1) > points[:, 4:, 1].min(axis=1) + 0.05
    assert off.any() and np.array_equal(off, feet_up) and not (bits[off]).any()
    assert np.linalg.norm(np.diff(root, axis=0), axis=1).max() < 0.03  # no jump, in or out
    assert (t[~off & (bits != 0)] > 5.0).any() and abs(root[-1, 1] - 0.95) < 1e-9  # back on its feet


@pytest.mark.parametrize("bad", ["nan", "same time", "earlier"])
def test_a_bad_frame_never_reaches_the_root(bad):
    """A frame with a non-finite point, or a time not after the row's last, gets the last good
    root and leaves the state as it was (counted), in the tracker and through Rooting.place."""
    tracker = RootTracker(2, NAMES)
    points = standing(20, np.random.default_rng(4), 0.002)
    points[:, :, 2] -= np.linspace(0.0, 0.2, 20)[:, None]  # the feet slide back: the root moves on
    for k in range(10):
        tracker.step(np.array([0, 1]), np.array([k / FS] * 2), points[[k, k]])
    before = state(tracker)
    frame, at = points[10:11].copy(), np.array([10 / FS])
    if bad == "nan":
        frame[0, 2, 0] = np.nan
    else:
        at = np.array([9 / FS if bad == "same time" else 3 / FS])
    root, bits, flags = tracker.step(np.array([1]), at, frame)
    assert np.array_equal(root, before[0][[1]]) and not bits.any() and not flags.any()
    assert all(np.array_equal(a, b) for a, b in zip(state(tracker), before))
    assert tracker.refused.tolist() == [0, 1]
    root, _, _ = tracker.step(np.array([1]), np.array([10 / FS]), points[10:11])
    assert 0.005 < root[0, 2] - before[0][1, 2] < 0.05  # the next good frame goes on from there

    t_us, q, joints, body = walk(FULL, 60)
    rooting = Rooting()
    rooting.place(np.zeros(50, np.int64), t_us[:50], q[:50], joints[:50], FULL, [body], 0, True)
    [tracker] = rooting.trackers.values()
    before = state(tracker)
    q_bad, joints_bad, t_bad = q[50:51].copy(), joints[50:51].copy(), t_us[50:51].copy()
    if bad == "nan":
        joints_bad[0, FULL.joint_index["r_ankle"]] = np.nan
    else:
        t_bad[0] = t_us[49] if bad == "same time" else t_us[10]
    root, contacts, _ = rooting.place(np.zeros(1, np.int64), t_bad, q_bad, joints_bad, FULL, [body], 0, True)
    assert np.array_equal(root, before[0]) and not contacts.any()
    assert all(np.array_equal(a, b) for a, b in zip(state(tracker), before))
    if bad == "nan":
        q_bad[0, FULL.segment_index["l_foot"]] = np.nan
        joints_bad = joints[50:51]
        root, _, _ = rooting.place(np.zeros(1, np.int64), t_bad, q_bad, joints_bad, FULL, [body], 0, True)
        assert np.array_equal(root, before[0]) and tracker.refused[0] == 2
