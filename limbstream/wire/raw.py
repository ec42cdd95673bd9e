"""Truth tap: batches of a device's raw samples (the reference a lab compares against).

Version 2 adds each sample's *reference time*: when the sample was really taken, on the
reference system's clock (the emulator's true time stands in for an external reference such as
an optical system). Receivers use it only to measure alignment, never to align. Version 3 adds
each sample's *own orientation*: the device's own estimate of its orientation at the sample (what
its kernel compressed: its fused sensor reading, which the truth differs from by the sensor's
fusion and mounting errors), against which the live bound is kept. Versions 1 and 2 are still
decoded (a recording may hold them).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from .errors import WireError
from .point import joined

RAW_VERSION = 3
"""Format version of truth-tap batches written with reference times and own orientations (2:
reference times only; 1: neither)."""
_HEADER_V1 = struct.Struct("<BBHHHIq")   # version, flags, stream, count, reserved, first_index, t0_us
_HEADER_V2 = struct.Struct("<BBHHHIqq")  # ... and ref0_us
RAW_SAMPLE_DTYPE = np.dtype([("dt_us", "<u4"), ("q", "<f4", (4,))])
RAW_SAMPLE_DTYPE_V2 = np.dtype([("dt_us", "<u4"), ("ref_dt_us", "<u4"), ("q", "<f4", (4,))])
RAW_SAMPLE_DTYPE_V3 = np.dtype([("dt_us", "<u4"), ("ref_dt_us", "<u4"), ("q", "<f4", (4,)), ("own", "<f4", (4,))])
MAX_RAW_BATCH = 4096
_LAYOUT = {1: (_HEADER_V1, RAW_SAMPLE_DTYPE), 2: (_HEADER_V2, RAW_SAMPLE_DTYPE_V2), 3: (_HEADER_V2, RAW_SAMPLE_DTYPE_V3)}


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
        Device timestamps (as its segment points carry them), microseconds since the Unix epoch.
    q : (n, 4) float32
        True orientations (w, x, y, z) of the segment.
    ref_us : (n,) int64 or None
        Reference times: when each sample was really taken, us since the epoch (versions 2 and
        3; None in a version 1 batch).
    own : (n, 4) float32 or None
        The device's own orientation at each sample, what its kernel compressed (version 3, which
        needs ``ref_us``; None in versions 1 and 2).
    """

    stream: int
    first_index: int
    t_us: np.ndarray
    q: np.ndarray
    ref_us: np.ndarray | None = None
    own: np.ndarray | None = None


def encode_raw(batch: RawBatch) -> bytes:
    """RawBatch -> bytes. Without reference times, version 1: header (20 B: u8 version, u8 flags,
    u16 stream, u16 count, u16 reserved, u32 first_index, i64 t0_us) + count x (u32 dt_us from
    t0, 4 x f32 q). With them, version 2: the same header + i64 ref0_us (28 B), then count x
    (u32 dt_us, u32 ref_dt_us from ref0, 4 x f32 q). With own orientations too, version 3: as
    version 2, each sample followed by 4 x f32 own."""
    n = len(batch.t_us)
    if not 0 < n <= MAX_RAW_BATCH:
        raise ValueError(f"raw batch must hold 1..{MAX_RAW_BATCH} samples, got {n}")
    t0 = int(batch.t_us[0])
    if batch.ref_us is None:
        body = np.empty(n, RAW_SAMPLE_DTYPE)
        header = _HEADER_V1.pack(1, 0, batch.stream, n, 0, batch.first_index, t0)
    else:
        ref0 = int(batch.ref_us[0])
        version = 2 if batch.own is None else 3
        body = np.empty(n, _LAYOUT[version][1])
        body["ref_dt_us"] = np.asarray(batch.ref_us, np.int64) - ref0
        header = _HEADER_V2.pack(version, 0, batch.stream, n, 0, batch.first_index, t0, ref0)
        if batch.own is not None:
            body["own"] = batch.own
    body["dt_us"] = np.asarray(batch.t_us, np.int64) - t0
    body["q"] = batch.q
    return header + body.tobytes()


def encode_raws(stream: np.ndarray, first_index: np.ndarray, count: np.ndarray, t_us: np.ndarray, q: np.ndarray,
                ref_us: np.ndarray | None = None, own: np.ndarray | None = None) -> tuple[bytes, np.ndarray]:
    """Many truth-tap batches at once, laid end to end: the bytes of :func:`encode_raw` of each.

    Parameters
    ----------
    stream, first_index, count : (B,) per batch, as in :class:`RawBatch` (count >= 1).
    t_us : (S,) int64 device times of all samples, batch after batch (S = count.sum()).
    q : (S, 4) float32 their orientations.
    ref_us : (S,) int64 their reference times (version 2), or None (version 1).
    own : (S, 4) float32 the devices' own orientations (version 3, with ``ref_us``), or None.

    Returns
    -------
    payload : bytes, the B messages back to back.
    ends : (B,) int64 offset in payload just after each message.
    """
    count = np.asarray(count, np.int64)
    if len(count) and not (count.min() > 0 and count.max() <= MAX_RAW_BATCH):
        raise ValueError(f"raw batches must hold 1..{MAX_RAW_BATCH} samples, got {count.min()}..{count.max()}")
    if own is not None and ref_us is None:
        raise ValueError("own orientations go with reference times (version 3)")
    version = 1 if ref_us is None else 2 if own is None else 3
    header, dtype = _LAYOUT[version]
    first = np.cumsum(count) - count
    heads = np.zeros(len(count), _HEADS[version])
    heads["version"], heads["stream"], heads["count"], heads["first_index"] = version, stream, count, first_index
    t_us = np.asarray(t_us, np.int64)
    heads["t0"] = t_us[first]
    body = np.empty(len(t_us), dtype)
    body["dt_us"] = t_us - np.repeat(heads["t0"], count)
    body["q"] = q
    if ref_us is not None:
        ref_us = np.asarray(ref_us, np.int64)
        heads["ref0"] = ref_us[first]
        body["ref_dt_us"] = ref_us - np.repeat(heads["ref0"], count)
    if own is not None:
        body["own"] = own
    ends = np.cumsum(header.size + count * dtype.itemsize)
    out = np.empty(int(ends[-1]) if len(ends) else 0, np.uint8)
    if len(count) and count.min() == count.max():  # batches of one size: a (B, message) table
        table = out.reshape(len(count), -1)
        table[:, :header.size] = heads.view(np.uint8).reshape(len(count), -1)
        table[:, header.size:] = body.view(np.uint8).reshape(len(count), -1)
        return out.tobytes(), ends
    at_header = ((ends - count * dtype.itemsize - header.size)[:, None] + np.arange(header.size)).ravel()
    out[at_header] = heads.view(np.uint8)
    body_bytes = np.ones(len(out), bool)
    body_bytes[at_header] = False
    out[body_bytes] = body.view(np.uint8)  # each batch's samples follow its header, in order
    return out.tobytes(), ends


def decode_raw(payload: bytes) -> RawBatch:
    """Bytes (version 1, 2 or 3) -> RawBatch; WireError with reason size / version / non_finite /
    time_backwards (device or reference times)."""
    if len(payload) < _HEADER_V1.size:
        raise WireError("size", f"raw batch has {len(payload)} bytes, less than its header")
    version = payload[0]
    if version not in _LAYOUT:
        raise WireError("version", f"raw batch version {version}, expected 1 to {RAW_VERSION}")
    header, dtype = _LAYOUT[version]
    if len(payload) < header.size:
        raise WireError("size", f"raw batch has {len(payload)} bytes, less than its header")
    _, _, stream, n, _, first_index, t0, *ref0 = header.unpack_from(payload)
    expected = header.size + n * dtype.itemsize
    if n == 0 or len(payload) != expected:
        raise WireError("size", f"raw batch of {n} samples has {len(payload)} bytes, expected {expected}")
    body = np.frombuffer(payload, dtype, count=n, offset=header.size)
    q = body["q"].copy()
    own = body["own"].copy() if version == 3 else None
    if not (np.all(np.isfinite(q)) and (own is None or np.all(np.isfinite(own)))):
        raise WireError("non_finite", "raw batch has non-finite samples")
    dt = body["dt_us"].astype(np.int64)
    ref = body["ref_dt_us"].astype(np.int64) if ref0 else None
    if n > 1 and (np.any(np.diff(dt) < 0) or (ref is not None and np.any(np.diff(ref) < 0))):
        raise WireError("time_backwards", "raw batch timestamps go backwards")
    return RawBatch(stream, first_index, t0 + dt, q, None if ref is None else ref0[0] + ref, own)


@dataclass(frozen=True)
class RawColumns:
    """Truth-tap batches decoded together (a drain's worth), as columns: batch ``i`` is message
    ``i``, its samples rows ``start[i]:start[i] + count[i]`` of the sample columns.

    Attributes
    ----------
    stream, first_index, start, count : (B,) int64
        Per batch, as in :class:`RawBatch` (0 for an invalid message).
    has_ref : (B,) bool
        The batch carries reference times (versions 2 and 3).
    has_own : (B,) bool
        The batch carries own orientations (version 3).
    reason : list of B (str or None)
        Why the message is not a valid batch (the reasons of :func:`decode_raw`); None where it is.
    t_us, ref_us : (S,) int64
        Per sample: device time; reference time (0 in a batch without).
    q, own : (S, 4) float32
        Per sample: true orientation; the device's own (NaN in a batch without).
    """

    stream: np.ndarray
    first_index: np.ndarray
    start: np.ndarray
    count: np.ndarray
    has_ref: np.ndarray
    reason: list
    t_us: np.ndarray
    ref_us: np.ndarray
    q: np.ndarray
    has_own: np.ndarray
    own: np.ndarray

    def batch(self, i: int) -> RawBatch:
        """Batch ``i`` (valid) as a :class:`RawBatch` of its own arrays."""
        rows = slice(int(self.start[i]), int(self.start[i] + self.count[i]))
        return RawBatch(int(self.stream[i]), int(self.first_index[i]), self.t_us[rows].copy(), self.q[rows].copy(),
                        self.ref_us[rows].copy() if self.has_ref[i] else None,
                        self.own[rows].copy() if self.has_own[i] else None)


_HEADS = {v: np.dtype([("version", "u1"), ("flags", "u1"), ("stream", "<u2"), ("count", "<u2"), ("reserved", "<u2"),
                       ("first_index", "<u4"), ("t0", "<i8")] + ([("ref0", "<i8")] if v >= 2 else []))
          for v in _LAYOUT}
"""The headers of every version as NumPy record types (the bytes of the structs above)."""


def _all_finite(x: np.ndarray) -> np.ndarray:
    """(n,) whether every value of each row of ``x`` (n, 4) float32 is finite: the row's four
    bools read as one 32-bit word (a reduction along 4 values costs ten times more)."""
    return np.isfinite(x).view(np.uint32)[:, 0] == 0x01010101


def decode_raws(payloads: list[bytes]) -> RawColumns:
    """Many truth-tap payloads at once -> :class:`RawColumns`: the same batches and the same
    reasons as :func:`decode_raw` of each, in a few NumPy calls for all."""
    b = len(payloads)
    nbytes, buf, offset, version = joined(payloads, _HEADER_V1.size)
    long = nbytes >= _HEADER_V1.size
    stream, count, first_index, t0, ref0 = (np.zeros(b, np.int64) for _ in range(5))
    present = set(version.tolist())
    for v, (header, dtype) in _LAYOUT.items():
        if v not in present:  # (a drain's batches are mostly of one version)
            continue
        mine = np.flatnonzero((version == v) & (nbytes >= header.size))
        head = buf[offset[mine, None] + np.arange(header.size)].view(_HEADS[v])[:, 0]
        ok = (head["count"] > 0) & (nbytes[mine] == header.size + head["count"].astype(np.int64) * dtype.itemsize)
        mine, head = mine[ok], head[ok]
        stream[mine], count[mine], first_index[mine], t0[mine] = head["stream"], head["count"], head["first_index"], head["t0"]
        if v >= 2:
            ref0[mine] = head["ref0"]
    start = np.cumsum(count) - count
    total = int(count.sum())
    sample_batch = np.repeat(np.arange(b), count)
    rank = np.arange(total) - start[sample_batch]
    t_us, ref_us, q = np.zeros(total, np.int64), np.zeros(total, np.int64), np.zeros((total, 4), np.float32)
    own = np.full((total, 4), np.nan, np.float32)
    for v, (header, dtype) in _LAYOUT.items():
        if v not in present:
            continue
        batches = np.flatnonzero((version == v) & (count > 0))
        if len(batches) == 0:
            continue
        rows = slice(None) if int(count[batches].sum()) == total else np.flatnonzero(version[sample_batch] == v)
        body = np.frombuffer(b"".join([payloads[i][header.size:] for i in batches.tolist()]), dtype)
        t_us[rows] = t0[sample_batch[rows]] + body["dt_us"]
        q[rows] = body["q"]
        if v >= 2:
            ref_us[rows] = ref0[sample_batch[rows]] + body["ref_dt_us"]
        if v == 3:
            own[rows] = body["own"]
    bad = ~_all_finite(q)
    v3 = np.flatnonzero(version[sample_batch] == 3)
    if len(v3):
        bad[v3] |= ~_all_finite(own[v3])
    finite = np.bincount(sample_batch[bad], minlength=b) == 0
    later = rank[1:] > 0  # a sample after the first of its batch: its times may not go back
    back = later & ((np.diff(t_us) < 0) | (np.diff(ref_us) < 0))
    backwards = np.bincount(sample_batch[1:][back], minlength=b) > 0
    reason: list[str | None] = [None] * b
    for i in np.flatnonzero((count == 0) | ~finite | backwards):
        if not long[i] or (version[i] in _LAYOUT and count[i] == 0):
            reason[i] = "size"
        elif version[i] not in _LAYOUT:
            reason[i] = "version"
        else:
            reason[i] = "non_finite" if not finite[i] else "time_backwards"
    return RawColumns(stream, first_index, start, count, version >= 2, reason, t_us, ref_us, q, version == 3, own)
