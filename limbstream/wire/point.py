"""Segment point: the one message a device sends per segment, little-endian.

Two versions (docs/protocol.md): v1, 36 bytes, the point alone; v2, 48 bytes, the point and its
body angular rate ``omega`` (fastSW's live rule: a receiver shows the newest point extrapolated
at that rate, ``limbstream.quat.predict``). :func:`encode_point` writes v2 when the point has a
rate; :func:`decode_point` reads both, a v1 point with ``omega`` None (no rate: held).
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from .errors import WireError

VERSION = 1
"""Format version of the binary payloads (first byte of each); a segment point with a rate is
:data:`VERSION_RATE`."""
VERSION_RATE = 2
"""Segment point version 2: the point and its body angular rate."""
UNIT_TOLERANCE = 1e-3
"""A segment point's quaternion norm must be within 1 +- this."""

FLAG_FINAL = 0x01
"""Segment point flag: the last point of the stream (end of stream flush)."""

_POINT = struct.Struct("<BBHIIq4f")
_POINT_RATE = struct.Struct("<BBHIIq4f3f")
POINT_SIZE = _POINT.size  # 36 bytes
POINT_SIZE_RATE = _POINT_RATE.size  # 48 bytes
_SIZES = {VERSION: POINT_SIZE, VERSION_RATE: POINT_SIZE_RATE}
_FIELDS = [("version", "u1"), ("flags", "u1"), ("stream", "<u2"), ("seq", "<u4"), ("index", "<u4"), ("t_us", "<i8"),
           ("q", "<f4", (4,))]
_DTYPES = {VERSION: np.dtype(_FIELDS), VERSION_RATE: np.dtype(_FIELDS + [("omega", "<f4", (3,))])}
"""The two layouts as NumPy record types (the same bytes as the structs above)."""


@dataclass(frozen=True)
class SegmentPoint:
    """One segment point (36 bytes on the wire, 48 with a rate).

    Attributes
    ----------
    stream : int
        uint16 id the device draws at start; a new id means a new stream (restart).
    seq : int
        uint32 per-stream sequence number of segment-point messages, from 0.
    index : int
        uint32 index of this sample in the device's stream (samples taken before it).
    t_us : int
        int64 device timestamp, microseconds since the Unix epoch.
    q : tuple of 4 float
        Orientation (w, x, y, z), unit norm, as float32.
    flags : int
        Bit field (:data:`FLAG_FINAL`).
    omega : tuple of 3 float or None
        Body angular rate (rad/s, float32) the receiver extrapolates the point with
        (``limbstream.quat.predict``); None: a v1 point, no rate (held).
    """

    stream: int
    seq: int
    index: int
    t_us: int
    q: tuple[float, float, float, float]
    flags: int = 0
    omega: tuple[float, float, float] | None = None


def encode_point(p: SegmentPoint) -> bytes:
    """SegmentPoint -> u8 version, u8 flags, u16 stream, u32 seq, u32 index, i64 t_us, 4 x f32 q
    (36 bytes, version 1), and 3 x f32 omega where the point has a rate (48 bytes, version 2)."""
    if p.omega is None:
        return _POINT.pack(VERSION, p.flags, p.stream, p.seq, p.index, p.t_us, *p.q)
    return _POINT_RATE.pack(VERSION_RATE, p.flags, p.stream, p.seq, p.index, p.t_us, *p.q, *p.omega)


def decode_point(payload: bytes) -> SegmentPoint:
    """36 (v1) or 48 (v2) bytes -> SegmentPoint; WireError with reason size (empty, or not the size
    of its version), version (neither 1 nor 2), non_finite (quaternion or rate), non_unit."""
    if not payload:
        raise WireError("size", "segment point is empty")
    version = payload[0]
    if version not in _SIZES:
        raise WireError("version", f"segment point version {version}, expected {VERSION} or {VERSION_RATE}")
    if len(payload) != _SIZES[version]:
        raise WireError("size", f"segment point v{version} has {len(payload)} bytes, expected {_SIZES[version]}")
    if version == VERSION:
        _, flags, stream, seq, index, t_us, w, x, y, z = _POINT.unpack(payload)
        omega = None
    else:
        _, flags, stream, seq, index, t_us, w, x, y, z, *rate = _POINT_RATE.unpack(payload)
        if not all(map(math.isfinite, rate)):
            raise WireError("non_finite", "segment point rate is not finite")
        omega = tuple(rate)
    if not all(map(math.isfinite, (w, x, y, z))):
        raise WireError("non_finite", "segment point quaternion is not finite")
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise WireError("non_unit", f"segment point quaternion norm {norm:.6g}")
    return SegmentPoint(stream, seq, index, t_us, (w, x, y, z), flags, omega)


@dataclass(frozen=True)
class PointColumns:
    """Segment point messages decoded together (a drain's worth), as columns; row ``i`` is
    message ``i``.

    Attributes
    ----------
    stream, seq, index, t_us, flags : (N,) int64
        As in :class:`SegmentPoint` (0 for an invalid message).
    q : (N, 4) float32
        Orientations (w, x, y, z).
    omega : (N, 3) float32
        Body angular rates, rad/s; 0 for a v1 point (no rate: held).
    nbytes : (N,) int64
        Payload sizes.
    reason : list of N (str or None)
        Why the message is not a valid point (the reasons of :func:`decode_point`); None where
        it is one.
    """

    stream: np.ndarray
    seq: np.ndarray
    index: np.ndarray
    t_us: np.ndarray
    flags: np.ndarray
    q: np.ndarray
    omega: np.ndarray
    nbytes: np.ndarray
    reason: list

    @classmethod
    def of(cls, points: list[SegmentPoint], nbytes: list[int]) -> PointColumns:
        """The columns of decoded points (all valid) of payload sizes ``nbytes``."""
        def column(name: str) -> np.ndarray:
            return np.array([getattr(p, name) for p in points], np.int64).reshape(len(points))
        return cls(column("stream"), column("seq"), column("index"), column("t_us"), column("flags"),
                   np.array([p.q for p in points], np.float32).reshape(-1, 4),
                   np.array([p.omega or (0.0, 0.0, 0.0) for p in points], np.float32).reshape(-1, 3),
                   np.array(nbytes, np.int64).reshape(len(points)), [None] * len(points))


def joined(payloads: list[bytes], first: int = 1) -> tuple[np.ndarray, ...]:
    """Payloads side by side: (their sizes (n,), all their bytes as one uint8 array, where each
    begins (n,), each one's first byte (its version; -1 where it has fewer than ``first`` bytes))."""
    n = len(payloads)
    nbytes = np.fromiter(map(len, payloads), np.int64, n)
    buf = np.frombuffer(b"".join(payloads), np.uint8)
    start = np.cumsum(nbytes) - nbytes
    version = np.full(n, -1, np.int64)
    version[nbytes >= first] = buf[start[nbytes >= first]]
    return nbytes, buf, start, version


def decode_points(payloads: list[bytes]) -> PointColumns:
    """Many segment point payloads at once -> :class:`PointColumns`: the same points and the same
    reasons as :func:`decode_point` of each, in a few NumPy calls for all."""
    n = len(payloads)
    nbytes, buf, start, version = joined(payloads)
    cols = {name: np.zeros(n, np.int64) for name in ("stream", "seq", "index", "t_us", "flags")}
    q, omega = np.zeros((n, 4), np.float32), np.zeros((n, 3), np.float32)
    valid = np.zeros(n, bool)
    for v, dtype in _DTYPES.items():
        mine = np.flatnonzero((version == v) & (nbytes == dtype.itemsize))
        if len(mine) == n:  # all of one version (a drain's usual): their bytes as they came
            rec = buf.view(dtype)
        elif len(mine):
            rec = buf[start[mine, None] + np.arange(dtype.itemsize)].view(dtype)[:, 0]
        if len(mine):
            for name in cols:
                cols[name][mine] = rec[name]
            q[mine] = rec["q"]
            if v == VERSION_RATE:
                omega[mine] = rec["omega"]
            valid[mine] = True
    finite = np.asarray(np.isfinite(q).all(axis=1) & np.isfinite(omega).all(axis=1))
    w, x, y, z = q.astype(np.float64).T
    unit = np.abs(np.sqrt(w * w + x * x + y * y + z * z) - 1.0) <= UNIT_TOLERANCE
    reason: list[str | None] = [None] * n
    for i in np.flatnonzero(~(valid & finite & unit)):
        if nbytes[i] == 0:
            reason[i] = "size"
        elif version[i] not in _SIZES:
            reason[i] = "version"
        elif not valid[i]:
            reason[i] = "size"
        else:
            reason[i] = "non_finite" if not finite[i] else "non_unit"
    return PointColumns(**cols, q=q, omega=omega, nbytes=nbytes, reason=reason)
