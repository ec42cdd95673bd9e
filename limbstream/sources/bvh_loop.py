"""A BVH clip looped on its own cycle, its root travelling on: long walks from short clips.

- **The loop** is the stretch between two frames ``i < j`` where the body is in the same pose
  (:func:`loop_frames`): its joints relative to the root in the root's heading frame, how fast
  they move there, the root's height and velocity. The frames are at least half the clip apart
  (and :data:`LOOP_MIN_S`): a loop of what the clip does, not of a still moment in it.
- **The looped clip** plays the file's frames up to ``j``, then ``i`` .. ``j - 1`` over and over.
  Each pass is turned about the vertical by the heading the passes before it gained, and moved to
  where they brought the root: a straight walk goes on straight, a circle goes round.
- **Its height** is ramped along each pass, so that a pass starts where the last one ended and
  ends where it began: the file's floor, which drifts by a few centimetres over a clip, comes back
  to one height every pass.
- Only the moving root joint's channels change, so the file's joint positions (its forward
  kinematics) follow. At each seam the pose steps by the two frames' mismatch
  (:attr:`LoopedClip.mismatch_m`), the size of a capture glitch on a walk.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from limbstream import quat
from limbstream.body import Layout
from limbstream.calibration import yaw, yaw_of
from limbstream.sources import Motion
from limbstream.sources.bvh import BvhClip, joint_positions, local_rotations, motion_of_clip

LOOP_MIN_S = 1.0
"""The shortest loop, s."""
MATCH_VELOCITY_S = 0.1
"""A joint's velocity counts in the pose match as its displacement over this time, s."""
SEARCH_FRAMES = 1500
"""The most frames the loop's search compares pairwise (a longer clip: every n-th, then refined)."""
_POSITION = ("Xposition", "Yposition", "Zposition")


@dataclass(frozen=True)
class LoopedClip:
    """A clip looped by :func:`looped_clip`: ``clip`` the looped frames, ``i`` and ``j`` the
    original's frames the loop goes from and back at, ``mismatch_m`` the mean distance between
    their joints (root-relative, heading frame), in the file's units times ``unit_m``."""

    clip: BvhClip
    i: int
    j: int
    mismatch_m: float


def moving_root(clip: BvhClip) -> int | None:
    """The joint that carries the clip's path: the first (the topmost) whose three position channels
    change over the clip, every joint above it still and unturned (channels constant, rotations
    0: an exporter's floor root); None if there is none."""
    for j, names in enumerate(clip.channels):
        start = clip.channel_start(j)
        if all(a in names for a in _POSITION) and np.ptp(clip.motion[:, [start + names.index(a) for a in _POSITION]]) > 0:
            k = int(clip.parents[j])
            while k >= 0:
                values = clip.motion[:, clip.channel_start(k):clip.channel_start(k) + len(clip.channels[k])]
                turned = [c for c, n in enumerate(clip.channels[k]) if n.endswith("rotation")]
                still = values.shape[1] == 0 or not np.ptp(values, axis=0).any()
                if not still or np.any(values[:, turned]):
                    return None
                k = int(clip.parents[k])
            return j
    return None


def _root(clip: BvhClip) -> tuple[int, list[int], list[int]]:
    """The moving root joint, its position and rotation channel columns; ValueError without one."""
    root = moving_root(clip)
    if root is None:
        raise ValueError(f"{clip.path.name}: no joint carries a path to loop on")
    names = clip.channels[root]
    start = clip.channel_start(root)
    rotation = [start + k for k, n in enumerate(names) if n.endswith("rotation")]
    return root, [start + names.index(a) for a in _POSITION], rotation


def _root_quat(clip: BvhClip, root: int) -> np.ndarray:
    """(F, 4) the root joint's orientations (BVH world, Y up)."""
    return quat.continuous(quat.from_rotation(local_rotations(clip, root)))


def _pose_features(clip: BvhClip, first: int) -> tuple[np.ndarray, np.ndarray]:
    """(F, D) what the loop matches of each frame from ``first`` on (file units): the joints
    relative to the root in its heading frame, their velocities, the root's height and velocity;
    and (F, J, 3) those joints."""
    root, _, _ = _root(clip)
    place = joint_positions(clip)[0][first:]
    turn = yaw(-yaw_of(_root_quat(clip, root)[first:]))[:, None]
    rel = quat.rotate(turn, place - place[:, root:root + 1])
    per_frame = MATCH_VELOCITY_S / clip.frame_time  # a velocity as its displacement over MATCH_VELOCITY_S
    own = np.concatenate([place[:, root:root + 1] * [0.0, 1.0, 0.0],
                          quat.rotate(turn, np.gradient(place[:, root:root + 1], axis=0)) * per_frame], axis=1)
    features = np.concatenate([rel, np.gradient(rel, axis=0) * per_frame, own], axis=1)
    return features.reshape(len(place), -1), rel


def _best_pair(features: np.ndarray, gap: int) -> tuple[int, int]:
    """(i, j), ``j >= i + gap``, the rows of ``features`` (F, D) closest to each other."""
    sq = (features * features).sum(axis=1)
    cost = sq[:, None] + sq[None, :] - 2.0 * features @ features.T
    cost[np.triu(np.ones(cost.shape, bool), gap) == 0] = np.inf
    i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
    return int(i), int(j)


def loop_frames(clip: BvhClip, first: int = 0, min_s: float = LOOP_MIN_S) -> tuple[int, int, float]:
    """(i, j, mismatch) the loop's frames, ``first <= i < j``, ``j - i`` at least ``min_s``
    (ValueError for a clip too short), where the pose and its motion match best; ``mismatch``
    the mean distance between their joints, file units. A long clip is searched every
    ``stride``-th frame (at most :data:`SEARCH_FRAMES`), then frame by frame around the best pair."""
    frames = clip.n_frames - first
    gap = max(1, round(min_s / clip.frame_time))
    if frames <= gap:
        raise ValueError(f"{clip.path.name}: {frames * clip.frame_time:.2f} s, too short for a loop of {min_s:g} s")
    features, rel = _pose_features(clip, first)
    stride = -(-frames // SEARCH_FRAMES)
    i, j = _best_pair(features[::stride], -(-gap // stride))
    i, j = i * stride, j * stride
    if stride > 1:  # frame by frame within a stride of the coarse pair
        near_i = np.arange(max(0, i - stride), min(frames, i + stride + 1))
        near_j = np.arange(max(0, j - stride), min(frames, j + stride + 1))
        cost = ((features[near_i][:, None] - features[near_j][None]) ** 2).sum(axis=2)
        cost[near_j[None] - near_i[:, None] < gap] = np.inf
        a, b = np.unravel_index(int(np.argmin(cost)), cost.shape)
        i, j = int(near_i[a]), int(near_j[b])
    mismatch = float(np.linalg.norm(rel[i] - rel[j], axis=1).mean())
    return first + i, first + j, mismatch


def looped_clip(clip: BvhClip, seconds: float, first: int = 0, unit_m: float = 1.0) -> LoopedClip:
    """``clip`` played from frame ``first`` for ``seconds`` (the frames before ``first`` kept as
    they are), looped on :func:`loop_frames`' stretch with its root travelling on (the module)."""
    if not seconds > 0:
        raise ValueError(f"a loop of {seconds} s")
    root, pos, rot = _root(clip)
    i, j, mismatch = loop_frames(clip, first, max(LOOP_MIN_S, 0.5 * (clip.n_frames - first) * clip.frame_time))
    total = first + round(seconds / clip.frame_time)
    passes = max(0, -(-(total - j) // (j - i)))
    index = np.concatenate([np.arange(j)] + [np.arange(i, j)] * passes)[:total]
    motion = clip.motion[index].copy()
    q = _root_quat(clip, root)
    p = clip.motion[:, pos]
    turn_per_pass = float(yaw_of(q[j]) - yaw_of(q[i]))
    origin, turn = p[j].copy(), turn_per_pass  # where pass 1 puts frame i, and how far it is turned
    for k in range(passes):
        rows = slice(j + k * (j - i), min(total, j + (k + 1) * (j - i)))
        src = index[rows]
        spin = yaw(turn)
        moved = quat.rotate(spin, p[src] - p[i])
        motion[rows, pos[0]], motion[rows, pos[2]] = origin[0] + moved[:, 0], origin[2] + moved[:, 2]
        # the height: each pass starts where the last one ended and ends where it started, the file's
        # own drift over the loop (its floor's) taken out along the pass
        motion[rows, pos[1]] = p[src, 1] + (p[j, 1] - p[i, 1]) * (1.0 - (src - i) / (j - i))
        if rot:
            seq = "".join(clip.channels[root][c - clip.channel_start(root)][0] for c in rot)
            motion[rows, rot] = quat.to_rotation(quat.multiply(spin, q[src])).as_euler(seq, degrees=True)
        end = quat.rotate(spin, p[j] - p[i])
        origin = origin + [end[0], 0.0, end[2]]
        turn += turn_per_pass
    return LoopedClip(dataclasses.replace(clip, motion=motion), i, j, mismatch * unit_m)


def walks_on(motion: Motion) -> bool:
    """Whether ``motion`` can be looped with its root walking on: a BVH clip read with its file's
    positions, a joint that carries its path and more than :data:`LOOP_MIN_S` of frames (a shorter
    one is looped as any other clip is)."""
    source = motion.positions
    if source is None or motion.root is None or moving_root(source.clip) is None:
        return False
    first = round(source.start_s / source.clip.frame_time)
    return source.clip.n_frames - first > round(LOOP_MIN_S / source.clip.frame_time)


def looped_motion(motion: Motion, seconds: float, layout: str | Layout) -> tuple[Motion, LoopedClip]:
    """A BVH motion (read with its file's positions: ``motion.positions``) looped for ``seconds``
    of motion with its root travelling on, read again as the file was onto ``layout``; named
    ``loop(<name>)``. ValueError for a motion without its file or its root path."""
    source = motion.positions
    if source is None or motion.root is None:
        raise ValueError(f"{motion.name}: no BVH file with a root path to loop on")
    first = round(source.start_s / source.clip.frame_time)
    loop = looped_clip(source.clip, seconds, first, source.unit_m)
    fs = None if np.isclose(motion.fs, 1.0 / source.clip.frame_time) else motion.fs
    out = motion_of_clip(loop.clip, fs, source.segment_map, first > 0, layout=layout, name=f"loop({motion.name})")
    return out, loop
