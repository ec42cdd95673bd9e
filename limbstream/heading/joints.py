"""The joints between a subject's segments, their relative orientations and the joint angle error.

A joint joins a parent segment to a child (``wire.joints_among``: in the 10-segment body,
:data:`limbstream.joints.JOINT_TABLE`, the hip is the root, and the shoulders and the neck hang
from it as the spine has no sensor; with a chest, the ``full`` layout's joints).
Its relative orientation is ``R = q_parent^-1 * q_child`` (child frame -> parent frame): it is
what a joint angle is made of, and it does not depend on which way the whole body faces. A
heading error ``e`` of the child relative to its parent (a turn about the world's vertical)
turns it into ``rot(g, e) * R``, where ``g`` is the vertical in the parent's frame; the twist of
``R`` about ``g`` (:func:`twist`) takes ``e`` up exactly, the rest of ``R`` does not.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from limbstream import quat, wire
from limbstream.body import LAYOUTS
from limbstream.joints.convention import JOINT_TABLE, Joint, from_tpose  # noqa: F401  (JOINT_TABLE: the docs')

UP = np.array([0.0, 1.0, 0.0])
"""The world's vertical (the skeleton's Y)."""

HINGE, BALL = "hinge", "3-DoF"
"""Joint classes: a hinge (knee, elbow: one axis fixed in both segments) and a ball joint (hip,
shoulder, neck: bounded by its range of motion only)."""


_BUILTIN = {s.name: (s, q) for layout in LAYOUTS.values() for s, q in zip(layout.segments, from_tpose(layout))}
"""Every built-in layout's segments by name, with their T-pose -> standing turns (a name means
the same segment in each)."""


def is_hinge(joint: Joint) -> bool:
    """A joint is a hinge if it reports one angle (knees, elbows)."""
    return joint.angles[1] is None and joint.angles[2] is None


def kind(name: str) -> str:
    """A joint's kind, its name without the side: ``hip``, ``knee``, ``ankle``, ``shoulder``,
    ``elbow``, ``wrist``, ``lumbar``, ``neck``."""
    return name.split("_")[0]


@dataclass(frozen=True)
class Layout:
    """The joints among ``segments`` (``wire.joints_among``: those whose parent and child are both
    there; the 10-segment body's in :data:`limbstream.joints.JOINT_TABLE` order), and the arrays
    that index them.

    Attributes
    ----------
    segments : tuple of S str
    joints : tuple of J str
    parent, child : (J,) int, indices into ``segments``
    hinge : (J,) bool, the joint is a hinge
    rest_pose : str, what identity orientations mean (``wire.REST_POSES``)
    """

    segments: tuple[str, ...]
    joints: tuple[str, ...]
    parent: np.ndarray
    child: np.ndarray
    hinge: np.ndarray
    rest_pose: str

    @staticmethod
    def of(segments, rest_pose: str = wire.DEFAULT_REST_POSE) -> Layout:
        """The layout of ``segments`` (names of the built-in layouts' segments; unknown ones take
        part in no joint)."""
        segments = tuple(segments)
        index = {name: i for i, name in enumerate(segments)}
        joints = wire.joints_among(segments)
        return Layout(segments, tuple(j.name for j in joints),
                      np.array([index[j.parent] for j in joints], int),
                      np.array([index[j.child] for j in joints], int),
                      np.array([is_hinge(j) for j in joints], bool),
                      wire.check_rest_pose(rest_pose))

    def to_standing(self) -> tuple[np.ndarray, np.ndarray]:
        """(J, 4) twice: ``a``, ``b`` such that ``a * R * b`` is a relative orientation ``R``
        referred to the standing rest pose (T-pose arms and hands lowered; identities for
        standing data)."""
        identity = np.array([1.0, 0.0, 0.0, 0.0])
        tpose = self.rest_pose == "tpose"
        per_segment = np.array([_BUILTIN[s][1] if tpose and s in _BUILTIN else identity
                                for s in self.segments]).reshape(-1, 4)
        return quat.conjugate(per_segment[self.parent]), per_segment[self.child]

    def bone_axes(self) -> np.ndarray:
        """(J, 3) each joint's child bone direction in the child's frame (its rest direction)."""
        return np.array([_BUILTIN[self.segments[c]][0].directions[self.rest_pose] for c in self.child],
                        np.float64).reshape(-1, 3)

    def classes(self) -> dict[str, np.ndarray]:
        """Joint class name -> (J,) bool mask (only the classes present)."""
        out = {HINGE: self.hinge, BALL: ~self.hinge}
        return {name: mask for name, mask in out.items() if mask.any()}


def relative(q: np.ndarray, layout: Layout) -> np.ndarray:
    """(..., J, 4) the joints' relative orientations ``q_parent^-1 q_child`` of segment
    orientations ``q`` (..., S, 4)."""
    q = np.asarray(q, np.float64)
    return quat.multiply(quat.conjugate(q[..., layout.parent, :]), q[..., layout.child, :])


def vertical_in(q: np.ndarray) -> np.ndarray:
    """(..., 3) the world's vertical in the frames of orientations ``q`` (..., 4)."""
    return quat.rotate(quat.conjugate(q), UP)


def twist(r: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(...) the angle (rad, in (-pi, pi]) of the twist about unit ``axis`` (..., 3) of rotations
    ``r`` (..., 4): ``r`` is that turn about ``axis`` and a swing about an axis perpendicular to
    it (in either order: the angle is the same). ``twist(rot(axis, e) r) = twist(r) + e``."""
    r = np.asarray(r, np.float64)
    return 2.0 * np.arctan2(np.sum(r[..., 1:] * axis, axis=-1), r[..., 0])


def joint_errors_deg(q_est: np.ndarray, q_true: np.ndarray, layout: Layout) -> np.ndarray:
    """(..., J) the joint angle error, degrees: the angle between the estimated and the true
    relative orientation of each joint, for segment orientations ``q_est``, ``q_true``
    (..., S, 4). It does not depend on which way either body faces."""
    return quat.angle_deg(relative(q_est, layout), relative(q_true, layout))
