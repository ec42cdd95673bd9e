"""Root translation from foot contacts in C (``firmware_c/host/lsw_root.c``): the per-frame state
machine of :meth:`limbstream.body.translation.RootTracker.step`, many frames of many rows in one
call, each frame against its row's state as the committed frames before it left it."""
from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np

from limbstream.kernel._lib import RootConst, RootState, _lib

MAX_POINTS = 128
"""LSW_ROOT_MAX_POINTS (lsw_root.h): points per body at most."""

_vp = ctypes.c_void_p
_lib.lsw_root_frames.argtypes = [_vp, _vp, _vp, _vp, ctypes.c_size_t, _vp, _vp, _vp, _vp, _vp, _vp, _vp, _vp]
_lib.lsw_root_frames.restype = None

STATE = (("root", np.float64, 2), ("velocity", np.float64, 2), ("pace", np.float64, 2), ("anchor", np.int64, 1),
         ("anchor_xyz", np.float64, 2), ("t", np.float64, 1), ("height", np.float64, 1), ("points", np.float64, 3),
         ("seen", np.bool_, 2), ("refused", np.int64, 1))
"""The state arrays (name, dtype, dimensions), RootTracker's attributes, in LswRootState's order."""


@dataclass(frozen=True)
class BoundState:
    """A tracker's state arrays (:data:`STATE`, N rows) and its points' constants, checked once and
    pointed to by the C struct (a tracker binds them again when it replaces an array: ``arrays``
    keeps them alive and tells which they are)."""

    arrays: tuple[np.ndarray, ...]
    rows: int
    feet: np.ndarray
    contact_bit: np.ndarray
    struct: RootState
    feet_ptr: int
    contact_bit_ptr: int


def _checked(name: str, a: np.ndarray, dtype: type, shape: tuple[int, ...]) -> np.ndarray:
    if a.dtype != dtype or not a.flags.c_contiguous or a.shape != shape:
        raise TypeError(f"root state {name} must be C-contiguous {np.dtype(dtype).name} {shape}, "
                        f"got {a.dtype} {a.shape}")
    return a


def bind_state(state: dict[str, np.ndarray], feet: np.ndarray, contact_bit: np.ndarray) -> BoundState:
    """The arrays of :data:`STATE` by name (N rows) for :func:`root_frames`, with ``feet`` (P,)
    bool the foot points and ``contact_bit`` (P,) each foot point's contact bit."""
    rows, n_points = len(state["t"]), len(feet)
    if n_points > MAX_POINTS:
        raise ValueError(f"root tracking takes at most {MAX_POINTS} points per body, got {n_points}")
    shapes = {1: (rows,), 2: (rows, 3), 3: (rows, n_points, 3)}
    arrays = tuple(_checked(name, state[name], dtype, (rows, n_points) if name == "seen" else shapes[dims])
                   for name, dtype, dims in STATE)
    feet = np.ascontiguousarray(feet, np.bool_)
    contact_bit = np.ascontiguousarray(contact_bit, np.int64)
    return BoundState(arrays, rows, feet, contact_bit, RootState(*[a.ctypes.data for a in arrays], n_points),
                      feet.ctypes.data, contact_bit.ctypes.data)


def root_frames(state: BoundState, const: RootConst, owner: np.ndarray, t: np.ndarray, points: np.ndarray,
                usable: np.ndarray, commit: bool | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames of rows ``owner`` (F,) in the order given: times ``t`` (F,) s, points ``points``
    (F, P, 3) m root-relative, ``usable`` (F, P) bool. ``state`` (:func:`bind_state`) is updated
    in place by the frames ``commit`` (F,) bool, or one bool for all (the others only read it).
    Returns the roots (F, 3) m, contact bits (F,) and flags (F,)."""
    rows, n_points = state.rows, len(state.feet)
    owner = np.ascontiguousarray(owner, np.int64)
    n = len(owner)
    if n and (owner.min() < 0 or owner.max() >= rows):
        raise ValueError(f"root frames: rows must be in 0..{rows - 1}")
    t = np.ascontiguousarray(t, np.float64)
    points = np.ascontiguousarray(points, np.float64)
    usable = np.ascontiguousarray(usable, np.bool_)
    commit = np.ascontiguousarray(np.broadcast_to(commit, (n,)), np.bool_)
    if t.shape != (n,) or points.shape != (n, n_points, 3) or usable.shape != (n, n_points):
        raise ValueError(f"root frames: shapes owner {owner.shape}, t {t.shape}, points {points.shape}, "
                         f"usable {usable.shape} do not match {n_points} points")
    root, bits, flags = np.zeros((n, 3)), np.zeros(n, np.int64), np.zeros(n, np.int64)
    _lib.lsw_root_frames(ctypes.byref(state.struct), ctypes.byref(const), state.feet_ptr, state.contact_bit_ptr, n,
                         owner.ctypes.data, t.ctypes.data, points.ctypes.data, usable.ctypes.data, commit.ctypes.data,
                         root.ctypes.data, bits.ctypes.data, flags.ctypes.data)
    return root, bits, flags
