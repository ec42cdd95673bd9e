"""A tree of elementary rotations in C (``firmware_c/host/lsw_gen.c``): the built-in generator's
segment orientations from its joint angles, every sample of a chunk in one call: each node its
parent times :func:`limbstream.quat.about_axes`' rotation, :func:`limbstream.quat.multiply`'s values
(an exact zero's sign aside)."""
from __future__ import annotations

import ctypes

import numpy as np

from limbstream.kernel._lib import _lib

MAX_NODES = 64
"""LSW_GEN_MAX_NODES (lsw_gen.h)."""

_vp = ctypes.c_void_p
_lib.lsw_gen_tree.argtypes = [ctypes.c_size_t, ctypes.c_uint32, _vp, _vp, _vp, ctypes.c_uint32, _vp, _vp]
_lib.lsw_gen_tree.restype = ctypes.c_int


class Tree:
    """Nodes, parents first: node j turns its parent's orientation (``parent[j]``, an earlier node;
    -1: the identity) by its angle about coordinate axis ``axis[j]`` (0 X, 1 Y, 2 Z), on the right.

    Parameters
    ----------
    axis, parent : (J,) ints, J at most :data:`MAX_NODES`.
    outputs : (S,) the nodes whose orientations :meth:`turn` gives, in its order.
    """

    def __init__(self, axis, parent, outputs):
        self.axis = np.ascontiguousarray(axis, np.int32)
        self.parent = np.ascontiguousarray(parent, np.int32)
        self.outputs = np.ascontiguousarray(outputs, np.int32)
        j = np.arange(len(self.axis))
        if not (len(self.axis) == len(self.parent) <= MAX_NODES and ((self.axis >= 0) & (self.axis <= 2)).all()
                and ((self.parent >= -1) & (self.parent < j)).all()
                and ((self.outputs >= 0) & (self.outputs < len(j))).all()):
            raise ValueError("a tree needs at most 64 nodes, axes 0..2, parents before their children "
                             "and outputs among its nodes")

    def turn(self, deg: np.ndarray) -> np.ndarray:
        """(n, S, 4) float64 the outputs' orientations (w, x, y, z) from ``deg`` (J, n) the nodes'
        angles, degrees."""
        deg = np.ascontiguousarray(deg, np.float64)
        if deg.ndim != 2 or len(deg) != len(self.axis):
            raise ValueError(f"deg must be ({len(self.axis)}, n), got {deg.shape}")
        n = deg.shape[1]
        q = np.empty((n, len(self.outputs), 4))
        if _lib.lsw_gen_tree(n, len(self.axis), deg.ctypes.data, self.axis.ctypes.data, self.parent.ctypes.data,
                             len(self.outputs), self.outputs.ctypes.data, q.ctypes.data):
            raise ValueError("lsw_gen_tree refused the tree")  # (checked above)
        return q
