"""Truth tap: batches of a device's raw samples (the reference a lab compares against)."""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from .errors import WireError
from .point import VERSION

_RAW_HEADER = struct.Struct("<BBHHHIq")  # version, flags, stream, count, dt_us, first_index, t0_us
RAW_SAMPLE_DTYPE = np.dtype([("dt_us", "<u4"), ("q", "<f4", (4,))])
MAX_RAW_BATCH = 4096


@dataclass(frozen=True)
class RawBatch:
    """Consecutive raw samples of one device (truth tap), ``index`` ``first_index + k``.

    Attributes
    ----------
    stream : int
        The device's stream id (as in SegmentPoint).
    first_index : int
        Sample index of the first sample.
    t_us : (n,) int64
        Device timestamps, microseconds since the Unix epoch.
    q : (n, 4) float32
        Orientations (w, x, y, z).
    """

    stream: int
    first_index: int
    t_us: np.ndarray
    q: np.ndarray


def encode_raw(batch: RawBatch) -> bytes:
    """RawBatch -> header (20 B: u8 version, u8 flags, u16 stream, u16 count, u16 reserved,
    u32 first_index, i64 t0_us) + count x (u32 dt_us from t0, 4 x f32 q)."""
    n = len(batch.t_us)
    if not 0 < n <= MAX_RAW_BATCH:
        raise ValueError(f"raw batch must hold 1..{MAX_RAW_BATCH} samples, got {n}")
    t0 = int(batch.t_us[0])
    body = np.empty(n, RAW_SAMPLE_DTYPE)
    body["dt_us"] = np.asarray(batch.t_us, np.int64) - t0
    body["q"] = batch.q
    return _RAW_HEADER.pack(VERSION, 0, batch.stream, n, 0, batch.first_index, t0) + body.tobytes()


def decode_raw(payload: bytes) -> RawBatch:
    """Bytes -> RawBatch; WireError with reason size / version / non_finite / time_backwards."""
    if len(payload) < _RAW_HEADER.size:
        raise WireError("size", f"raw batch has {len(payload)} bytes, less than its header")
    version, _, stream, n, _, first_index, t0 = _RAW_HEADER.unpack_from(payload)
    if version != VERSION:
        raise WireError("version", f"raw batch version {version}, expected {VERSION}")
    expected = _RAW_HEADER.size + n * RAW_SAMPLE_DTYPE.itemsize
    if n == 0 or len(payload) != expected:
        raise WireError("size", f"raw batch of {n} samples has {len(payload)} bytes, expected {expected}")
    body = np.frombuffer(payload, RAW_SAMPLE_DTYPE, count=n, offset=_RAW_HEADER.size)
    q = body["q"].copy()
    if not np.all(np.isfinite(q)):
        raise WireError("non_finite", "raw batch has non-finite samples")
    if n > 1 and np.any(np.diff(body["dt_us"].astype(np.int64)) < 0):
        raise WireError("time_backwards", "raw batch timestamps go backwards")
    return RawBatch(stream, first_index, t0 + body["dt_us"].astype(np.int64), q)
