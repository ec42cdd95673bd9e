"""Segment point: the one message a device sends per segment (36 bytes, little-endian)."""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from .errors import WireError

VERSION = 1
"""Format version of the binary payloads (first byte of each)."""
UNIT_TOLERANCE = 1e-3
"""A segment point's quaternion norm must be within 1 +- this."""

FLAG_FINAL = 0x01
"""Segment point flag: the last point of the stream (end of stream flush)."""

_POINT = struct.Struct("<BBHIIq4f")
POINT_SIZE = _POINT.size  # 36 bytes


@dataclass(frozen=True)
class SegmentPoint:
    """One segment point (36 bytes on the wire).

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
    """

    stream: int
    seq: int
    index: int
    t_us: int
    q: tuple[float, float, float, float]
    flags: int = 0


def encode_point(p: SegmentPoint) -> bytes:
    """SegmentPoint -> 36 bytes: u8 version, u8 flags, u16 stream, u32 seq, u32 index, i64 t_us, 4 x f32 q."""
    return _POINT.pack(VERSION, p.flags, p.stream, p.seq, p.index, p.t_us, *p.q)


def decode_point(payload: bytes) -> SegmentPoint:
    """36 bytes -> SegmentPoint; WireError with reason size / version / non_finite / non_unit."""
    if len(payload) != POINT_SIZE:
        raise WireError("size", f"segment point has {len(payload)} bytes, expected {POINT_SIZE}")
    version, flags, stream, seq, index, t_us, w, x, y, z = _POINT.unpack(payload)
    if version != VERSION:
        raise WireError("version", f"segment point version {version}, expected {VERSION}")
    if not all(map(math.isfinite, (w, x, y, z))):
        raise WireError("non_finite", "segment point quaternion is not finite")
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise WireError("non_unit", f"segment point quaternion norm {norm:.6g}")
    return SegmentPoint(stream, seq, index, t_us, (w, x, y, z), flags)
