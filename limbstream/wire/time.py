"""Time exchange: a device's request to the time service and the service's answer (binary,
little-endian), and the arithmetic of one four-timestamp exchange (docs/protocol.md,
"Time exchange").

A device sends a request at ``t1`` (its own clock) as a ``get`` on :func:`.keys.time_key`; the
service stamps its receive time ``t2`` and its send time ``t3`` (the common time base) and
answers; the device stamps the answer's arrival ``t4`` (its own clock). All four are
microseconds since the Unix epoch, ``int64``.

=======  ====================================================================  ======
message  layout                                                                bytes
=======  ====================================================================  ======
request  u8 version, u8 flags (0), u16 reserved, u32 id, i64 t1                16
answer   u8 version, u8 flags (0), u16 reserved, u32 id, i64 t1, i64 t2, i64 t3  32
=======  ====================================================================  ======

The answer echoes the request's ``id`` and ``t1``: a device matches an answer to the request
it sent, never to its own idea of when it sent one.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

from .errors import WireError

TIME_VERSION = 1
"""Format version of time requests and answers."""
MAX_TIME_US = 2**53
"""Times must lie in [0, 2**53) us (float64 exact), as device timestamps do."""

_REQUEST = struct.Struct("<BBHIq")
_ANSWER = struct.Struct("<BBHIqqq")
TIME_REQUEST_SIZE = _REQUEST.size  # 16
TIME_ANSWER_SIZE = _ANSWER.size    # 32


@dataclass(frozen=True)
class TimeRequest:
    """A device's time request.

    Attributes
    ----------
    id : uint32 request number (the device's own counter).
    t1_us : int64 device clock when the request left, us since the epoch.
    """

    id: int
    t1_us: int


@dataclass(frozen=True)
class TimeAnswer:
    """The time service's answer.

    Attributes
    ----------
    id, t1_us : the request's, echoed.
    t2_us : service clock when the request arrived, us since the epoch.
    t3_us : service clock when the answer left (>= t2_us).
    """

    id: int
    t1_us: int
    t2_us: int
    t3_us: int


def _in_range(*times: int) -> bool:
    return all(0 <= t < MAX_TIME_US for t in times)


def encode_time_request(r: TimeRequest) -> bytes:
    """TimeRequest -> 16 bytes."""
    return _REQUEST.pack(TIME_VERSION, 0, 0, r.id, r.t1_us)


def decode_time_request(payload: bytes) -> TimeRequest:
    """16 bytes -> TimeRequest; WireError with reason size / version / time_range."""
    if len(payload) != TIME_REQUEST_SIZE:
        raise WireError("size", f"time request has {len(payload)} bytes, expected {TIME_REQUEST_SIZE}")
    version, _, _, rid, t1 = _REQUEST.unpack(payload)
    if version != TIME_VERSION:
        raise WireError("version", f"time request version {version}, expected {TIME_VERSION}")
    if not _in_range(t1):
        raise WireError("time_range", f"time request t1 {t1} outside [0, 2**53) us")
    return TimeRequest(rid, t1)


def encode_time_answer(a: TimeAnswer) -> bytes:
    """TimeAnswer -> 32 bytes."""
    return _ANSWER.pack(TIME_VERSION, 0, 0, a.id, a.t1_us, a.t2_us, a.t3_us)


def decode_time_answer(payload: bytes) -> TimeAnswer:
    """32 bytes -> TimeAnswer; WireError with reason size / version / time_range /
    time_backwards (sent before it was received)."""
    if len(payload) != TIME_ANSWER_SIZE:
        raise WireError("size", f"time answer has {len(payload)} bytes, expected {TIME_ANSWER_SIZE}")
    version, _, _, rid, t1, t2, t3 = _ANSWER.unpack(payload)
    if version != TIME_VERSION:
        raise WireError("version", f"time answer version {version}, expected {TIME_VERSION}")
    if not _in_range(t1, t2, t3):
        raise WireError("time_range", "time answer has a time outside [0, 2**53) us")
    if t3 < t2:
        raise WireError("time_backwards", f"time answer sent ({t3}) before it was received ({t2})")
    return TimeAnswer(rid, t1, t2, t3)


def offset_delay(t1: float, t2: float, t3: float, t4: float) -> tuple[float, float]:
    """One exchange -> (offset, delay), us: ``offset`` = service clock minus device clock at the
    exchange's midpoint, ((t2 - t1) + (t3 - t4)) / 2, exact when both directions take equally
    long (else off by half the difference); ``delay`` = round trip without the service's own
    time, (t4 - t1) - (t3 - t2), negative only for a bogus answer."""
    return ((t2 - t1) + (t3 - t4)) / 2.0, (t4 - t1) - (t3 - t2)
