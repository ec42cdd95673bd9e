"""Clips played one after another, over and over, joined smoothly: long sessions from short clips.

At each seam the next clip is first turned about the vertical so that its hip faces where the
previous one's did (which way a body faces is arbitrary), then the last ``blend_s`` of the one and
the first ``blend_s`` of the other are cross-faded in joint space: the hip's orientation and every
joint's relative orientation (parent -> child, :data:`limbstream.joints.JOINT_TABLE`) are SLERPed
with the smoothstep weight ``3u^2 - 2u^3``. The weight and its rate are 0 at the start of the fade
and 1 and 0 at its end, so the orientation and its angular rate are continuous across the seam:
a filter sees no spike, and no still pose appears that the clips do not hold. A hinge stays a
hinge through the fade (two turns about one axis blend into a turn about it).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from limbstream import quat
from limbstream.calibration import yaw, yaw_of
from limbstream.joints.convention import JOINT_TABLE
from limbstream.sources import Motion

PARENT = {joint.child: joint.parent for joint in JOINT_TABLE}
"""Each segment's parent in the body's tree (the hip is the root)."""


def looped(motions: Sequence[Motion], seconds: float, blend_s: float = 1.0) -> Motion:
    """``motions`` (same segments, rate and rest pose) played in turn until ``seconds`` of motion.

    Parameters
    ----------
    motions : clips, each at least ``2 * blend_s`` long.
    seconds : length of the result, s (> 0).
    blend_s : length of each cross-fade, s (it overlaps the two clips: each seam shortens the
        total by this much).

    Returns
    -------
    Motion with ``t = k / fs`` and ``q`` (round(seconds * fs), S, 4), sign-continuous in time.
    """
    if not motions:
        raise ValueError("looped: no motions")
    first = motions[0]
    fs = first.fs
    for m in motions:
        if m.segments != first.segments or m.rest_pose != first.rest_pose or not np.isclose(m.fs, fs):
            raise ValueError(f"looped: clip {m.name!r} differs from {first.name!r} in segments, rest pose or rate")
    n_blend = max(2, round(blend_s * fs))
    short = [m.name for m in motions if len(m.t) < 2 * n_blend]
    if short:
        raise ValueError(f"looped: clips {short} are shorter than twice the {blend_s:g} s blend")
    if not seconds > 0:
        raise ValueError(f"looped: seconds must be > 0, got {seconds}")
    n_total = round(seconds * fs)
    order = _depth_order(first.segments)
    hip = first.segments.index("hip") if "hip" in first.segments else 0
    u = np.linspace(0.0, 1.0, n_blend)
    weight = u * u * (3.0 - 2.0 * u)
    pieces, length, k = [np.asarray(first.q, np.float64)], len(first.t), 1
    while length < n_total:
        clip = np.asarray(motions[k % len(motions)].q, np.float64)
        tail = pieces[-1][-n_blend:]
        turn = np.angle(np.mean(np.exp(1j * (yaw_of(tail[:, hip]) - yaw_of(clip[:n_blend, hip])))))
        clip = quat.multiply(yaw(turn)[None, None], clip)
        pieces[-1] = pieces[-1][:-n_blend]
        pieces += [_blend(tail, clip[:n_blend], weight, first.segments, order), clip[n_blend:]]
        length += len(clip) - n_blend
        k += 1
    q = quat.continuous(np.concatenate(pieces)[:n_total])
    names = "+".join(m.name for m in motions)
    return Motion(np.arange(n_total) / fs, q, first.segments, f"loop({names})", first.rest_pose)


def _depth_order(segments: tuple[str, ...]) -> list[int]:
    """Indices of ``segments``, parents (present ones) before their children."""
    def depth(name: str) -> int:
        parent = PARENT.get(name)
        return 0 if parent not in segments else 1 + depth(parent)
    return sorted(range(len(segments)), key=lambda i: depth(segments[i]))


def _blend(a: np.ndarray, b: np.ndarray, weight: np.ndarray, segments: tuple[str, ...],
           order: list[int]) -> np.ndarray:
    """(n, S, 4) the cross-fade from poses ``a`` to ``b`` (n, S, 4) in joint space, ``weight``
    (n,) going 0 -> 1."""
    out = np.empty_like(a)
    for i in order:
        parent = PARENT.get(segments[i])
        if parent in segments:
            p = segments.index(parent)
            local_a = quat.multiply(quat.conjugate(a[:, p]), a[:, i])
            local_b = quat.multiply(quat.conjugate(b[:, p]), b[:, i])
            out[:, i] = quat.multiply(out[:, p], quat.slerp(local_a, local_b, weight))
        else:
            out[:, i] = quat.slerp(a[:, i], b[:, i], weight)
    return out

