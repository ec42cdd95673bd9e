"""Reconstruction of devices' streams from their segment points in C (``firmware_c/host/lsw_fuse.c``):
the aggregator's point store asks many rows at many times in one call.

Row ``r`` holds ``n[r]`` points in time order: times ``t[r, :n[r]]`` (int64 us), orientations
``q[r, :n[r]]`` (float32 w, x, y, z) and body rates ``w[r, :n[r]]`` (float32 rad/s, 0: held). The
results are those of :func:`limbstream.quat.slerp`, :func:`~limbstream.quat.predict` and
:func:`~limbstream.quat.angle_deg` on the same points, computed step for step in double.
"""
from __future__ import annotations

import ctypes

import numpy as np

from limbstream.kernel._lib import FuseRows, _lib

EXACT, LIVE, PREDICTED = 0, 1, 2
"""What a query asks (LswFuseMode): the SLERP between the points around its time (held outside
them; identity for an empty row); that, or where no point at or after the time is known, the
newest point extrapolated with its rate (a live frame's segment); the newest point at or before
the time extrapolated (identity if none)."""


_vp = ctypes.c_void_p
_lib.lsw_fuse_reconstruct.argtypes = [_vp, ctypes.c_size_t, _vp, _vp, _vp, _vp]
_lib.lsw_fuse_reconstruct.restype = None
_lib.lsw_fuse_errors.argtypes = [_vp, ctypes.c_size_t, _vp, _vp, _vp, _vp, _vp]
_lib.lsw_fuse_errors.restype = None
_lib.lsw_fuse_row_spans_size.argtypes = []
_lib.lsw_fuse_row_spans_size.restype = ctypes.c_size_t


def _int64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.int64)


class PointRows:
    """The C library's view of a point store's arrays; make a new one when they are replaced.

    Parameters
    ----------
    t : (rows, cap) int64 times, us.
    q : (rows, cap, 4) float32 orientations.
    w : (rows, cap, 3) float32 body rates, rad/s.
    n : (rows,) int64 points held per row.

    It remembers the last SLERP spans each row's queries used (their arcs), reused only where the
    span's two points are the same times and stored values, so the arrays may change between calls.
    """

    def __init__(self, t: np.ndarray, q: np.ndarray, w: np.ndarray, n: np.ndarray):
        for name, a, dtype in (("t", t, np.int64), ("q", q, np.float32), ("w", w, np.float32), ("n", n, np.int64)):
            if a.dtype != dtype or not a.flags.c_contiguous:
                raise TypeError(f"{name} must be C-contiguous {np.dtype(dtype).name}")
        if q.shape != (*t.shape, 4) or w.shape != (*t.shape, 3) or n.shape != t.shape[:1]:
            raise ValueError(f"shapes t {t.shape}, q {q.shape}, w {w.shape}, n {n.shape} do not match")
        self._spans = np.zeros(len(t) * _lib.lsw_fuse_row_spans_size(), np.uint8)
        self._arrays = (t, q, w, n)  # kept alive while C points into them
        self._rows = FuseRows(t.ctypes.data, q.ctypes.data, w.ctypes.data, n.ctypes.data, t.shape[1],
                              self._spans.ctypes.data)
        self._ref = ctypes.addressof(self._rows)

    def reconstruct(self, slots: np.ndarray, t_us: np.ndarray, mode: np.ndarray | int) -> np.ndarray:
        """(Q, 4) float64 unit quaternions: row ``slots[i]`` at ``t_us[i]`` (us) as ``mode[i]``
        (:data:`EXACT`, :data:`LIVE` or :data:`PREDICTED`; one for all, or (Q,)) asks. Slots must
        be rows of the store."""
        slots, t_us = _int64(slots), _int64(t_us)
        modes = np.ascontiguousarray(np.broadcast_to(np.asarray(mode, np.uint8), slots.shape))
        out = np.empty((len(slots), 4))
        _lib.lsw_fuse_reconstruct(self._ref, len(slots), slots.ctypes.data, t_us.ctypes.data, modes.ctypes.data,
                                  out.ctypes.data)
        return out

    def errors(self, slots: np.ndarray, t_us: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Angular errors (Q,) degrees of the :data:`EXACT` and of the :data:`PREDICTED`
        reconstruction of row ``slots[i]`` at ``t_us[i]`` against ``truth[i]`` ((Q, 4))."""
        slots, t_us = _int64(slots), _int64(t_us)
        truth = np.ascontiguousarray(truth, np.float32)
        exact, predicted = np.empty(len(slots)), np.empty(len(slots))
        _lib.lsw_fuse_errors(self._ref, len(slots), slots.ctypes.data, t_us.ctypes.data, truth.ctypes.data,
                             exact.ctypes.data, predicted.ctypes.data)
        return exact, predicted


_lib.lsw_fuse_ring_append.argtypes = [_vp, _vp, _vp, ctypes.c_int64, ctypes.c_size_t, _vp, _vp]
_lib.lsw_fuse_ring_append.restype = None


def ring_append(ring: np.ndarray, seen: np.ndarray, total: np.ndarray, rows: np.ndarray, values: np.ndarray) -> None:
    """Append ``values`` (k,) to ring windows ``ring`` (R, window) float32 of rows ``rows`` (k,),
    in order: row r's value at ``seen[r] % window``, then ``seen[r]`` (R,) int64 += 1 and
    ``total[r]`` (R,) float64 += value. Rows must be rows of the arrays."""
    for name, a, dtype in (("ring", ring, np.float32), ("seen", seen, np.int64), ("total", total, np.float64)):
        if a.dtype != dtype or not a.flags.c_contiguous:
            raise TypeError(f"{name} must be C-contiguous {np.dtype(dtype).name}")
    rows, values = _int64(rows), np.ascontiguousarray(values, np.float64)
    _lib.lsw_fuse_ring_append(ring.ctypes.data, seen.ctypes.data, total.ctypes.data, ring.shape[1], len(rows),
                              rows.ctypes.data, values.ctypes.data)


_lib.lsw_fuse_ring_ranks.argtypes = [_vp, ctypes.c_int64, ctypes.c_size_t, _vp, _vp, ctypes.c_size_t, _vp, _vp]
_lib.lsw_fuse_ring_ranks.restype = ctypes.c_int


MAX_RANKS = 8
"""LSW_FUSE_MAX_RANKS (lsw_fuse.h)."""

RING_TOP = 64
"""LSW_FUSE_RING_TOP (lsw_fuse.h)."""


def takes_top(n: np.ndarray, least: np.ndarray) -> np.ndarray:
    """(k,) bool: rows of ``n`` (k,) values asked for ranks ``least`` (k,) and above are answered
    from a heap of their largest values, cheaper than their radix select or a sort
    (LSW_FUSE_RING_TOP_OF: at most RING_TOP of them, an eighth of the row at most)."""
    top = n - least
    return (top <= RING_TOP) & (8 * top <= n)


def ring_ranks(ring: np.ndarray, rows: np.ndarray, n: np.ndarray, ranks: np.ndarray) -> np.ndarray:
    """(k, R) float32: of each row ``rows[i]`` (k,) of ring windows ``ring`` (rows, window) float32,
    the values of ranks ``ranks[i]`` (k, R) int64 (0: the smallest) among its first ``n[i]`` (k,)
    values, as sorting them gives; each n within 1 .. window, each rank within 0 .. n - 1."""
    if ring.dtype != np.float32 or not ring.flags.c_contiguous:
        raise TypeError("ring must be C-contiguous float32")
    rows, n, ranks = _int64(rows), _int64(n), _int64(ranks)
    if ranks.ndim != 2 or len(ranks) != len(rows) or len(n) != len(rows) or ranks.shape[1] > MAX_RANKS:
        raise ValueError(f"ranks must be (k, R), R <= {MAX_RANKS}, and n (k,) for k = {len(rows)} rows")
    if not (((1 <= n) & (n <= ring.shape[1])).all() and ((0 <= ranks) & (ranks < n[:, None])).all()):
        raise ValueError("each n must be within 1 .. window and each rank within 0 .. n - 1")
    out = np.empty(ranks.shape, np.float32)
    if _lib.lsw_fuse_ring_ranks(ring.ctypes.data, ring.shape[1], len(rows), rows.ctypes.data, n.ctypes.data,
                                ranks.shape[1], ranks.ctypes.data, out.ctypes.data):
        raise MemoryError("ring_ranks: no scratch memory")
    return out


_lib.lsw_fuse_chain.argtypes = [ctypes.c_size_t, _vp, ctypes.c_uint32, _vp, ctypes.c_uint32, _vp, _vp, _vp, _vp, _vp,
                                _vp, _vp, ctypes.c_uint32, _vp, _vp]
_lib.lsw_fuse_chain.restype = None
MAX_JOINTS = 64
"""LSW_FUSE_MAX_JOINTS (lsw_fuse.h)."""


class Chain:
    """A kinematic chain: bone ``b`` places joint ``joint[b]`` at its parent joint ``parent[b]``
    (-1: the origin) plus its bone vector turned by segment ``segment[b]``'s orientation, or by
    the SLERP from it toward segment ``toward[b]``'s by ``share[b]`` where ``toward[b] >= 0`` (a
    bent bone); bones come parents first.

    Parameters
    ----------
    segment, joint, parent : (B,) ints.
    vec, alt_vec : (B, 3) bone vectors in their segments' frames, and the alternative ones.
    joints : joints of a body (those no bone places stay at the origin).
    toward, share : (B,) int and float, or None: no bone bends.
    """

    def __init__(self, segment, joint, parent, vec: np.ndarray, alt_vec: np.ndarray, joints: int,
                 toward=None, share=None):
        if not 0 < joints <= MAX_JOINTS:
            raise ValueError(f"joints must be 1..{MAX_JOINTS}, got {joints}")
        self.segment, self.joint, self.parent = (np.ascontiguousarray(a, np.int32) for a in (segment, joint, parent))
        self.vec, self.alt_vec = (np.ascontiguousarray(a, np.float64).reshape(-1, 3) for a in (vec, alt_vec))
        self.joints = joints
        bends = toward is not None and bool(np.any(np.asarray(toward) >= 0))
        self.toward = np.ascontiguousarray(toward, np.int32) if bends else None
        self.share = np.ascontiguousarray(share, np.float64) if bends else None

    def positions(self, q: np.ndarray, alt: np.ndarray | bool, dtype: type = np.float32) -> np.ndarray:
        """(..., joints, 3) joint positions (``dtype``: float32 or float64; summed in float64
        either way) of bodies whose segment orientations are ``q`` (..., segments, 4) (unit norm),
        with the alternative bone vectors where ``alt`` (...)."""
        q = np.ascontiguousarray(q, np.float64)
        bodies = q.shape[:-2]
        alt = np.ascontiguousarray(np.broadcast_to(np.asarray(alt, np.uint8), bodies))
        wide = np.dtype(dtype) == np.float64
        if not wide and np.dtype(dtype) != np.float32:
            raise ValueError(f"dtype must be float32 or float64, got {dtype}")
        out = np.empty((*bodies, self.joints, 3), np.float64 if wide else np.float32)
        _lib.lsw_fuse_chain(alt.size, q.ctypes.data, q.shape[-2], alt.ctypes.data, len(self.segment),
                            self.segment.ctypes.data, self.joint.ctypes.data, self.parent.ctypes.data,
                            None if self.toward is None else self.toward.ctypes.data,
                            None if self.share is None else self.share.ctypes.data, self.vec.ctypes.data, self.alt_vec.ctypes.data, self.joints,
                            None if wide else out.ctypes.data, out.ctypes.data if wide else None)
        return out
