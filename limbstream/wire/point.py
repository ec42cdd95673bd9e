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
    """36 (v1) or 48 (v2) bytes -> SegmentPoint; WireError with reason version (neither 1 nor 2),
    size (not the size of its version), non_finite (quaternion or rate), non_unit."""
    version = payload[0] if len(payload) else None
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
