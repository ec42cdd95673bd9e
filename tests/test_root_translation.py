"""Root translation from foot contacts (limbstream.body.translation): a body that stands still does
not drift, a gait whose planted foot is still in the world moves the root by its steps, a jump
flies and lands on the floor, and frames ahead of the final ones leave the state alone."""
from __future__ import annotations

import numpy as np
import pytest

from limbstream.body.translation import CONTACT_M, GRAVITY, RootTracker
from limbstream.evaluation.translation import aligned
from limbstream.wire import CONTACTS

NAMES = ("l_heel", "l_toe", "r_heel", "r_toe")
FS = 50.0


def standing(n: int, rng: np.random.Generator, noise_m: float) -> np.ndarray:
    """(n, 4, 3) foot points of a body standing with its pelvis 0.95 m up, each point jittering."""
    base = np.array([[0.1, -0.95, -0.05], [0.1, -0.95, 0.15], [-0.1, -0.95, -0.05], [-0.1, -0.95, 0.15]])
    return base + rng.normal(0.0, noise_m, (n, 4, 3))


def test_a_body_standing_still_for_ten_minutes_stays_where_it_stood():
    rng = np.random.default_rng(1)
    n = int(600 * FS)
    tracker = RootTracker(1, NAMES)
    root, bits, _ = tracker.track(np.arange(n) / FS, standing(n, rng, 0.001))
    drift = np.linalg.norm(root[:, [0, 2]] - root[0, [0, 2]], axis=1)
    assert drift.max() < 0.05, drift.max()
    assert abs(root[:, 1].mean() - 0.95) < 0.01 and (bits != 0).all()


def gait(n: int, step_m: float = 0.6, step_s: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A walk straight ahead (+Z) at step_m per step_s: each foot planted in turn, the root moving
    at constant speed; foot points root-relative, and the true root path."""
    t = np.arange(n) / FS
    speed = step_m / step_s
    root = np.stack([np.zeros(n), np.full(n, 0.95), speed * t], axis=1)
    points = np.zeros((n, 4, 3))
    for side, (x, phase) in enumerate(((0.1, 0.0), (-0.1, 1.0))):
        # a foot is down for one step, then swings two step lengths forward in the next
        cycle = (t / step_s + phase) % 2.0
        k = np.floor((t / step_s + phase) / 2.0)
        down_z = (2 * k + 1 - phase) * step_m  # where it is put down this cycle
        swing = np.clip(cycle - 1.0, 0.0, 1.0)
        z = np.where(cycle < 1.0, down_z, down_z + 2 * step_m * swing)
        lift = np.where(cycle < 1.0, 0.0, 0.08 * np.sin(np.pi * swing))
        for c, dz in ((0, -0.05), (1, 0.15)):
            points[:, 2 * side + c] = np.stack([np.full(n, x), lift, z + dz], axis=1) - root
    return points, root


def test_a_walk_moves_the_root_by_its_steps():
    points, truth = gait(int(20 * FS))
    root, bits, _ = RootTracker(1, NAMES).track(np.arange(len(points)) / FS, points)
    err = np.linalg.norm((root - root[0])[:, [0, 2]] - (truth - truth[0])[:, [0, 2]], axis=1)
    path = np.linalg.norm(truth[-1] - truth[0])
    assert err[-1] < 0.01 * path, (err[-1], path)
    assert np.abs(root[:, 1] - 0.95).max() < 1e-6
    left = bits & (1 << CONTACTS.index("l_heel")) != 0
    assert 0.3 < left.mean() < 0.7  # each foot down about half the time


def test_a_jump_flies_under_gravity_and_lands_on_the_floor():
    n = int(3 * FS)
    t = np.arange(n) / FS
    points = standing(n, np.random.default_rng(2), 0.0)
    # a crouch and push-off: the legs extend (the pelvis rises relative to the feet) at 1.5 m/s,
    # then tuck during the flight, then stand
    up = (t >= 1.0) & (t < 1.1)
    extend = np.where(up, 1.5 * (t - 1.0), np.where(t >= 1.1, 0.15, 0.0))
    tuck = np.where((t >= 1.1) & (t < 1.4), 0.1, 0.0)
    points[:, :, 1] = -0.8 - extend[:, None] + tuck[:, None]
    tracker = RootTracker(1, NAMES)
    root, bits, _ = tracker.track(t, points)
    flying = bits == 0
    assert flying[(t > 1.15) & (t < 1.3)].all() and not flying[t < 1.0].any() and not flying[t > 2.0].any()
    assert root[:, 1].max() > 0.95 + 0.03  # it rose above the extended legs' height
    air = np.flatnonzero(flying)
    fall = np.diff(root[air, 1], 2) * FS ** 2
    assert np.allclose(fall, -GRAVITY, atol=1e-6)  # under gravity alone
    feet = root[:, 1:2] + points[:, :, 1]
    assert feet.min() > -0.02  # never through the floor by more than 2 cm
    assert abs(root[-1, 1] - 0.95) < 1e-6  # landed and standing again


def test_a_frame_ahead_of_the_final_ones_does_not_move_the_state():
    rng = np.random.default_rng(3)
    points = standing(10, rng, 0.0)
    tracker = RootTracker(1, NAMES)
    tracker.track(np.arange(5) / FS, points[:5])
    before = tracker.root.copy(), tracker.anchor.copy(), tracker.t.copy()
    ahead = points[5:6].copy()
    ahead[:, :, 2] -= 0.02  # the planted feet slid back: the root moved forward
    root, _, _ = tracker.step(np.array([0]), np.array([5 / FS]), ahead, commit=False)
    assert root[0, 2] > before[0][0, 2] + 0.015
    assert np.array_equal(tracker.root, before[0]) and np.array_equal(tracker.anchor, before[1])
    assert np.array_equal(tracker.t, before[2])


def test_translation_figures_align_the_start_once_and_measure_the_rest():
    """A true walk and an estimate of it in a world turned by 30 degrees and shifted: aligned on
    the first 0.5 s, a perfect estimate scores 0; one whose root falls 10 cm behind by the end and
    floats 2 cm high scores exactly that; feet through the floor and skating show."""
    from limbstream.evaluation.translation import translation_figures

    points, truth = gait(int(10 * FS))
    t = np.arange(len(truth)) / FS
    feet = truth[:, None] + points
    heading = np.radians(30.0)
    c, s = np.cos(heading), np.sin(heading)
    to_estimate = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # the inverse of the alignment's turn
    shift = np.array([2.0, 0.0, -1.0])
    est_root, est_feet = truth @ to_estimate.T + shift, feet @ to_estimate.T + shift
    f = translation_figures(t, est_root, est_feet, truth, feet, heading)
    assert f.end_cm < 1e-9 and f.height_cm < 1e-9 and f.below_cm == 0.0
    assert abs(f.path_m - (truth[-1, 2] - truth[0, 2])) < 1e-9
    assert f.skate_cmps < 1e-9 and f.true_skate_cmps < 1e-9

    lag = np.clip(t - 0.5, 0.0, None)[:, None] * [0.0, 0.0, -0.1 / (t[-1] - 0.5)]
    lagged = est_root + lag @ to_estimate.T + [0.0, 0.02, 0.0]
    sunk = est_feet + (lag @ to_estimate.T)[:, None] - [0.0, 0.03, 0.0]
    f = translation_figures(t, lagged, sunk, truth, feet, heading)
    assert abs(f.end_cm - 10.0) < 1e-6 and abs(f.end_pct - 10.0 / f.path_m) < 1e-6
    assert abs(f.height_cm - 2.0) < 1e-6 and abs(f.below_cm - 3.0) < 1e-6
    sliding = 100 * 0.1 / (t[-1] - 0.5)  # cm/s: the lag slides the planted feet too, after the first 0.5 s
    assert 0.9 * sliding < f.skate_cmps <= sliding + 1e-9 and f.true_skate_cmps < 1e-9


def test_the_height_over_the_feet_is_scored_beside_the_height_over_the_lowest_point():
    """A file whose floor is not level (its walk steps 5 cm up halfway, its world raised there) and
    an estimate on a flat floor, its root always at the truth's height over its feet: the height
    error over the file's lowest point counts the step (5 cm on half the frames), the height over
    the feet does not."""
    from limbstream.evaluation.translation import translation_figures

    points, truth = gait(int(10 * FS))
    t = np.arange(len(truth)) / FS
    raised = truth + np.where(t >= 5.0, 0.05, 0.0)[:, None] * [0.0, 1.0, 0.0]
    f = translation_figures(t, truth, truth[:, None] + points, raised, raised[:, None] + points)
    assert abs(f.height_cm - 2.5) < 0.05 and f.height_feet_cm < 1e-9
    sunk = truth - [0.0, 0.02, 0.0]
    f = translation_figures(t, sunk, sunk[:, None] + points, raised, raised[:, None] + points)
    assert abs(f.height_feet_cm - 2.0) < 1e-9


def test_the_aggregator_stage_gives_each_subject_its_own_path():
    """services.aggregator.rooting: frames of two full subjects walking interleaved in ticks of
    several frames each give every subject the path its frames alone give it, and a live frame
    between ticks reads the state without moving it."""
    from limbstream.body import FULL, Body
    from limbstream.body.translation import BodyPoints, heel_drops
    from limbstream.services.aggregator.rooting import Rooting
    from limbstream.sources.generator import GeneratorSource

    n = 400
    t_us = (np.arange(n) * 20_000).astype(np.int64)
    bodies = [Body.from_height(FULL, 1.8), Body.default(FULL)]
    frames = []
    for body, seed in zip(bodies, (3, 4)):
        q = GeneratorSource(seed, activities=["walking"], layout="full").orientations(t_us / 1e6)
        frames.append((q, body.positions(q, False, dtype=np.float64)))
    rooting = Rooting()
    got: list[list[np.ndarray]] = [[], []]
    for start in range(0, n, 7):  # ticks of 7 frames per subject
        for row, (q, joints) in enumerate(frames):
            at = slice(start, min(start + 7, n))
            owner = np.full(len(q[at]), row)
            root, _, flags = rooting.place(owner, t_us[at], q[at], joints[at], FULL, bodies, owner, commit=True)
            got[row].append(root)
            assert not flags.any()
        live_at = slice(min(start + 7, n - 1), min(start + 8, n))
        before = {k: v.root.copy() for k, v in rooting.trackers.items()}
        rooting.place(np.array([0]), t_us[live_at] + 5_000, frames[0][0][live_at], frames[0][1][live_at], FULL,
                      bodies, 0, commit=False)
        assert all(np.array_equal(before[k], v.root) for k, v in rooting.trackers.items())
    points = BodyPoints(FULL)
    for row, (q, joints) in enumerate(frames):
        alone, _, _ = RootTracker(1, points.names).track(t_us / 1e6, points.positions(heel_drops(FULL, bodies[row]), q, joints))
        assert np.allclose(np.concatenate(got[row]), alone, atol=1e-12)
        walked = np.concatenate(got[row])
        assert np.linalg.norm(walked[-1, [0, 2]] - walked[0, [0, 2]]) > 0.5  # the walk goes somewhere


def test_eval_scores_the_root_path_of_a_walk_read_onto_full(cmu_bvh_dir, tmp_path, capsys):
    """``eval --layout full`` on a CMU walk prints the root translation table: the root tracked
    from the reconstruction's feet ends within 3 % of the path walked (0.8 % measured on 131_01),
    its height within 6 cm of the file's (4.0), no foot below the floor."""
    import json

    from limbstream import cli

    out = tmp_path / "rows.json"
    code = cli.main(["eval", str(cmu_bvh_dir / "131_01.bvh"), "--algorithms", "fastsw", "--thresholds", "9e-4",
                     "--max-len", "25", "--layout", "full", "--json", str(out), "--dump", str(tmp_path)])
    text = capsys.readouterr().out
    assert code == 0, text
    [row] = json.loads(out.read_text())
    [walk] = row["translation"]
    dumped = np.load(tmp_path / "131_01.npz")
    root, true_root = dumped["root"], dumped["true_root"]
    assert root.shape == true_root.shape == (len(dumped["t"]), 3) and np.isfinite(root).all()
    travelled = np.linalg.norm(root[-1, [0, 2]] - root[0, [0, 2]])
    assert abs(travelled - np.linalg.norm(true_root[-1, [0, 2]] - true_root[0, [0, 2]])) < 0.2
    assert walk["motion"] == "131_01" and walk["path_m"] > 4.0
    assert walk["end_pct"] < 3.0 and walk["height_cm"] < 6.0 and walk["below_cm"] == 0.0
    assert walk["height_feet_cm"] < 3.0  # the root over the file's feet frame by frame (0.2 measured)
    assert "root translation from the reconstruction's feet" in text and "true skate" in text
    # the dump holds what the figures are computed from: aligned as eval aligns it, its end error is eval's
    feet, names, contacts = dumped["feet"], [str(n) for n in dumped["foot_points"]], dumped["contacts"]
    assert names == list(CONTACTS) and feet.shape == (len(root), 4, 3) and contacts.shape == (len(root),)
    moved, _ = aligned(dumped["t"], root, feet, true_root, float(dumped["root_heading_rad"]))
    assert abs(100 * np.linalg.norm(moved[-1, [0, 2]] - true_root[-1, [0, 2]]) - walk["end_cm"]) < 1e-6
    touching = np.stack([(contacts >> i) & 1 for i in range(4)], axis=1).astype(bool)
    assert 0.2 < touching.any(axis=1).mean() and (feet[:, :, 1][touching] <= CONTACT_M + 1e-9).all()


def test_exports_carry_the_root_path_of_a_recording(tmp_path):
    """A recording whose frames carry a root walking forward (+Z) and sideways: its BVH root
    channels are that path (read back by an independent reader), its .mot has OpenSim's
    pelvis_tx (forward), pelvis_ty (up), pelvis_tz (right) in metres."""
    from support.bvh import read_bvh_positions
    from support.export import T0_US, storage_columns

    from limbstream import wire
    from limbstream.body import FULL, Body
    from limbstream.services.outputs.export import export, read_take
    from limbstream.services.outputs.recording import RecordingWriter
    from limbstream.sources.generator import GeneratorSource

    q = GeneratorSource(seed=3, layout="full").motion(3.0).q.astype(np.float32)
    joints = Body.default(FULL).positions(q).astype(np.float32)
    k = np.arange(len(q))
    root = np.stack([0.2 * k / len(k), 0.95 + 0.01 * np.sin(k / 5.0), 1.4 * k / 50.0], axis=1).astype(np.float32)
    path = tmp_path / "session.mcap"
    writer = RecordingWriter(path)
    for i in k:
        t = T0_US + 20_000 * int(i)
        frame = wire.PoseFrame(int(i), t, wire.KIND_EXACT, 0, q[i], joints[i], FULL, root[i], 0b0001)
        writer.add("pose", wire.pose_key("s01"), wire.encode_pose(frame), t * 1000)
    writer.close()
    take = read_take(path, None)
    assert take.root is not None and np.allclose(take.root, root, atol=1e-6)
    export(take, "bvh", tmp_path / "walk.bvh")
    positions = read_bvh_positions(tmp_path / "walk.bvh")
    assert np.allclose(positions["Hips"], root, atol=1e-4)
    export(take, "mot", tmp_path / "walk.mot")
    _, columns = storage_columns(tmp_path / "walk.mot")
    assert np.allclose(columns["pelvis_tx"], root[:, 2], atol=1e-4)   # forward: limbstream's +Z
    assert np.allclose(columns["pelvis_ty"], root[:, 1], atol=1e-4)   # up
    assert np.allclose(columns["pelvis_tz"], -root[:, 0], atol=1e-4)  # right: limbstream's -X


@pytest.mark.parametrize("fs", [50.0, 100.0, 200.0])
def test_a_jump_flies_at_every_frame_rate(fs):
    """The push-off of the jump above, framed at ``fs``: the take-off is a rate (the ballistic root
    rising away from the legs), not a height gained in one frame, which a faster frame rate never
    reaches (at 200 Hz the same jump stood on its tucked feet throughout)."""
    t = np.arange(int(3 * fs)) / fs
    points = standing(len(t), np.random.default_rng(2), 0.0)
    extend = np.where((t >= 1.0) & (t < 1.1), 1.5 * (t - 1.0), np.where(t >= 1.1, 0.15, 0.0))
    tuck = np.where(t < 1.4, 0.1 * np.clip((t - 1.1) / 0.05, 0.0, 1.0), 0.0)  # the legs tuck over 0.05 s
    points[:, :, 1] = -0.8 - extend[:, None] + tuck[:, None]
    root, bits, _ = RootTracker(1, NAMES).track(t, points)
    flying = bits == 0
    assert flying[(t > 1.15) & (t < 1.3)].all() and not flying[t < 1.0].any() and not flying[t > 2.0].any()
    assert root[:, 1].max() > 0.95 + 0.03
