"""The serial link between a device and its gateway (docs/protocol.md, "Serial link"): the
host's codec; the firmware's is firmware_c/include/lsw_link.h (a test checks both agree).

A frame on the line is ``COBS(payload + crc16) + b"\\0"``; the payload is the link version
(:data:`LINK_VERSION`), the message type and its body, all little-endian; crc16 is
CRC-16/CCITT-FALSE of the payload. A bad frame is counted by reason (:data:`BAD_REASONS`) and
dropped; reading resumes at the next delimiter.

Host to device: :func:`encode_sample`, :func:`encode_raw`, :func:`encode_config`,
:func:`encode_fusion`, :func:`encode_start`, :func:`encode_request` (END, STATUS_REQ, IDENTIFY,
FUSION_REQ). Device to host: POINT (a segment point message, as published), :class:`Ack`,
:class:`LinkStatus`, :class:`Identity`, :class:`FusionStatus`.
"""
from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass
from collections.abc import Callable

import numpy as np

from .config import TUNABLES, DeviceConfig
from .errors import WireError
from .point import POINT_SIZE, POINT_SIZE_RATE

LINK_VERSION = 1
MAX_PAYLOAD = 96
"""Largest payload (version, type, body) either side sends."""
MAX_FRAME = MAX_PAYLOAD + 5
"""Largest frame on the line: COBS overhead, CRC and the delimiter included."""

SAMPLE, CONFIG, START, END, STATUS_REQ, IDENTIFY = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
RAW, FUSION, FUSION_REQ = 0x07, 0x08, 0x09
"""Host -> device message types."""
POINT, ACK, STATUS, IDENTITY, FUSION_STATUS = 0x81, 0x82, 0x83, 0x84, 0x85
"""Device -> host message types."""
NAMES = {SAMPLE: "sample", CONFIG: "config", START: "start", END: "end", STATUS_REQ: "status_req",
         IDENTIFY: "identify", RAW: "raw", FUSION: "fusion", FUSION_REQ: "fusion_req", POINT: "point", ACK: "ack",
         STATUS: "status", IDENTITY: "identity", FUSION_STATUS: "fusion_status"}
FUSION_FAULTS: tuple[str, ...] = ("invalid", "time_back", "gap", "saturated", "gyr_stuck")
"""Bad raw samples by kind, in the firmware's order (LswImuFault, lsw_imu.h)."""

BAD_REASONS: tuple[str, ...] = ("cobs", "length", "crc", "version", "type")
"""Why a frame is dropped, in the firmware's order (LswBadReason): not COBS; too long, too short
or a body of the wrong length for its type; checksum; another link version; unknown type."""

_SAMPLE = struct.Struct("<Iq4f")
_RAW = struct.Struct("<Iq9f")
_FUSION = struct.Struct("<HfIIfB4f")
_FUSION_STATUS = struct.Struct(f"<HBB3fII{len(FUSION_FAULTS)}I")
_CONFIG = struct.Struct("<H3d")
_START = struct.Struct("<HH")
_REQUEST = struct.Struct("<H")
_ACK = struct.Struct("<HBBBd")
_STATUS = struct.Struct(f"<HH6I{len(BAD_REASONS)}I{len(TUNABLES)}dI")
_IDENTITY = struct.Struct("<HBBB")

HOST_BODIES: dict[int, tuple[int, ...]] = {SAMPLE: (_SAMPLE.size,), CONFIG: (_CONFIG.size,), START: (_START.size,),
                                           END: (2,), STATUS_REQ: (2,), IDENTIFY: (2,), RAW: (_RAW.size,),
                                           FUSION: (_FUSION.size,), FUSION_REQ: (2,)}
"""Body lengths of the host's messages (what a device accepts)."""
DEVICE_BODIES: dict[int, tuple[int, ...]] = {POINT: (POINT_SIZE, POINT_SIZE_RATE), ACK: (_ACK.size,),
                                             STATUS: (_STATUS.size,), IDENTITY: tuple(range(5, MAX_PAYLOAD - 1)),
                                             FUSION_STATUS: (_FUSION_STATUS.size,)}
"""Body lengths of the device's messages (what a gateway accepts)."""


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection)."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: ``data`` without zero bytes (one byte longer per 254)."""
    out = bytearray()
    for block in data.split(b"\0"):
        while len(block) >= 254:
            out += b"\xff" + block[:254]
            block = block[254:]
        out += bytes([len(block) + 1]) + block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; WireError('cobs') if ``data`` is not COBS."""
    out = bytearray()
    i = 0
    while i < len(data):
        code = data[i]
        if code == 0 or i + code > len(data):
            raise WireError("cobs", f"bad COBS block at byte {i}")
        out += data[i + 1:i + code]
        i += code
        if code != 0xFF and i < len(data):
            out.append(0)
    return bytes(out)


def frame(kind: int, body: bytes = b"") -> bytes:
    """One frame on the line: COBS of (version, type, body, crc16) and the 0x00 delimiter."""
    payload = bytes([LINK_VERSION, kind]) + body
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"link payload of {len(payload)} bytes, at most {MAX_PAYLOAD}")
    return cobs_encode(payload + struct.pack("<H", crc16(payload))) + b"\0"


class FrameReader:
    """Frames out of a byte stream, whatever its chunks; bad ones counted and dropped.

    Parameters
    ----------
    bodies : {type: accepted body lengths} of the messages this side reads
        (:data:`DEVICE_BODIES` on a gateway, :data:`HOST_BODIES` on a device).
    """

    def __init__(self, bodies: dict[int, tuple[int, ...]]):
        self.bodies = bodies
        self.bad: dict[str, int] = dict.fromkeys(BAD_REASONS, 0)
        self.frames = 0
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """The good frames ``data`` completes, as (type, body)."""
        out = []
        self._buffer += data
        *chunks, rest = bytes(self._buffer).split(b"\0")
        self._buffer = bytearray(rest[:MAX_FRAME + 1])  # an overlong frame stays too long
        for chunk in chunks:
            if chunk:  # back-to-back delimiters are not frames
                try:
                    out.append(self._check(chunk))
                    self.frames += 1
                except WireError as exc:
                    self.bad[exc.reason] += 1
        return out

    def _check(self, chunk: bytes) -> tuple[int, bytes]:
        if len(chunk) > MAX_FRAME - 1:
            raise WireError("length", f"frame of {len(chunk)} bytes")
        payload = cobs_decode(chunk)
        if len(payload) < 4:
            raise WireError("length", f"payload of {len(payload)} bytes")
        payload, crc = payload[:-2], int.from_bytes(payload[-2:], "little")
        if crc16(payload) != crc:
            raise WireError("crc", "checksum differs")
        if payload[0] != LINK_VERSION:
            raise WireError("version", f"link version {payload[0]}")
        kind, body = payload[1], payload[2:]
        if kind not in self.bodies:
            raise WireError("type", f"unknown message type 0x{kind:02x}")
        if len(body) not in self.bodies[kind]:
            raise WireError("length", f"{NAMES[kind]} body of {len(body)} bytes")
        return kind, body


# ---------------------------------------------------------------------- host -> device


def encode_sample(tick: int, t_us: int, q) -> bytes:
    """A SAMPLE frame: kernel tick (uint32, the device clock's microseconds), the sample's stamp
    (int64 us on the common time base: the time its point would carry), quaternion (4 float32)."""
    w, x, y, z = (float(v) for v in np.asarray(q, np.float32))
    return frame(SAMPLE, _SAMPLE.pack(tick & 0xFFFFFFFF, int(t_us), w, x, y, z))


def encode_raw(tick: int, t_us: int, gyr, acc, mag=None) -> bytes:
    """A RAW frame: one raw IMU sample, tick and stamp as :func:`encode_sample`'s, then gyr (rad/s),
    acc (m/s^2) and mag (uT; zeros without one), 3 float32 each, sensor frame."""
    values = np.concatenate([np.asarray(v if v is not None else np.zeros(3), np.float32).reshape(3)
                             for v in (gyr, acc, mag)])
    return frame(RAW, _RAW.pack(tick & 0xFFFFFFFF, int(t_us), *(float(v) for v in values)))


def encode_fusion(request: int, raw_period_s: float, out_period_us: int, max_gap_us: int, acc_limit: float,
                  nine_d: bool, rest_th_gyr_dps: float, rest_th_acc: float, heading: tuple[float, float]) -> bytes:
    """A FUSION frame: the raw-sample pipeline's settings (LswImuSettings, lsw_imu.h, as
    :func:`limbstream.kernel.fusion.imu_settings` computes them): sensor period (s, float32), device
    period (us), largest time step (us), accelerometer saturation (m/s^2, float32), 9D, VQF's rest
    thresholds (deg/s, m/s^2) and the filter's start heading (cos and sin of half its angle),
    float32. The device takes them
    as they are (so it computes what the host does) and starts a fresh filter."""
    return frame(FUSION, _FUSION.pack(request, raw_period_s, out_period_us, max_gap_us, acc_limit, int(bool(nine_d)),
                                      rest_th_gyr_dps, rest_th_acc, *heading))


def encode_config(request: int, config: DeviceConfig) -> bytes:
    """A CONFIG frame: every tunable, in :data:`TUNABLES` order, as float64 (the device checks
    them with the contract's bounds and answers with an :class:`Ack`)."""
    return frame(CONFIG, _CONFIG.pack(request, *(float(getattr(config, name)) for name in TUNABLES)))


def encode_start(request: int, stream: int) -> bytes:
    """A START frame: a new stream with this id (fresh kernel state, sequence 0, sample 0)."""
    return frame(START, _START.pack(request, stream))


def encode_request(kind: int, request: int) -> bytes:
    """An END, STATUS_REQ, IDENTIFY or FUSION_REQ frame."""
    if kind not in (END, STATUS_REQ, IDENTIFY, FUSION_REQ):
        raise ValueError(f"not a request type: {kind}")
    return frame(kind, _REQUEST.pack(request))


# ---------------------------------------------------------------------- device -> host


@dataclass(frozen=True)
class Ack:
    """The device's answer to a request: ``ok``, or ``error`` (the contract's refusal sentence)."""

    request: int
    kind: int
    ok: bool
    error: str | None = None


def refusal(index: int, value: float) -> str:
    """The contract's sentence refusing ``value`` for the tunable at ``index``
    (:meth:`limbstream.wire.Tunable.check`'s)."""
    names = list(TUNABLES)
    if not 0 <= index < len(names):
        return f"unknown tunable {index}"
    tunable = TUNABLES[names[index]]
    shown: float | int = int(value) if tunable.type is int and math.isfinite(value) and value.is_integer() else value
    try:
        tunable.check(shown)
    except ValueError as exc:
        return str(exc)
    return f"{tunable.name} refused, got {shown!r}"


@dataclass(frozen=True)
class LinkStatus:
    """The device's status (asked, or its heartbeat with request 0): the current stream's
    counters (samples, points, kernel-rejected samples), refused configs, good link frames
    read, bad ones by reason, its config and its stack's high-water mark (bytes)."""

    request: int
    stream: int
    seq: int
    samples: int
    points: int
    rejected: int
    refused: int
    frames: int
    bad: dict[str, int]
    config: DeviceConfig
    stack_bytes: int


@dataclass(frozen=True)
class Identity:
    """What the device says it is: link version, newest point version, sample dimension, text."""

    request: int
    link_version: int
    point_version: int
    dim: int
    text: str


@dataclass(frozen=True)
class FusionStatus:
    """The device's fusion (FUSION_REQ's answer): ``mode`` "6D" or "9D", ``rest`` (VQF's rest
    detection), ``bias`` (3 float, rad/s: the gyro bias estimate), this stream's ``raw`` samples
    and ``samples`` at the device rate, and its bad raw samples by kind (:data:`FUSION_FAULTS`)."""

    request: int
    mode: str
    rest: bool
    bias: tuple[float, float, float]
    raw: int
    samples: int
    faults: dict[str, int]


DeviceMessage = bytes | Ack | LinkStatus | Identity | FusionStatus


def _ack(body: bytes) -> Ack:
    request, kind, result, tunable, value = _ACK.unpack(body)
    if result == 0:
        return Ack(request, kind, True)
    return Ack(request, kind, False, "fusion settings refused" if kind == FUSION else refusal(tunable, value))


def _fusion_status(body: bytes) -> FusionStatus:
    request, mode, rest, bx, by, bz, raw, samples, *faults = _FUSION_STATUS.unpack(body)
    return FusionStatus(request, f"{mode}D", bool(rest), (bx, by, bz), raw, samples, dict(zip(FUSION_FAULTS, faults)))


def _status(body: bytes) -> LinkStatus:
    v = _STATUS.unpack(body)
    nb, nt = len(BAD_REASONS), len(TUNABLES)
    request, stream, seq, samples, points, rejected, refused, frames = v[:8]
    bad = dict(zip(BAD_REASONS, v[8:8 + nb]))
    values = v[8 + nb:8 + nb + nt]
    config = DeviceConfig(**{name: TUNABLES[name].type(x) for name, x in zip(TUNABLES, values)})
    return LinkStatus(request, stream, seq, samples, points, rejected, refused, frames, bad, config, v[-1])


def _identity(body: bytes) -> Identity:
    request, link, point, dim = _IDENTITY.unpack(body[:_IDENTITY.size])
    return Identity(request, link, point, dim, body[_IDENTITY.size:].decode("ascii", "replace"))


_DECODERS: dict[int, Callable[[bytes], DeviceMessage]] = {POINT: bytes, ACK: _ack, STATUS: _status,
                                                         IDENTITY: _identity, FUSION_STATUS: _fusion_status}


def decode_device(kind: int, body: bytes) -> DeviceMessage:
    """A device message read by a :class:`FrameReader` (DEVICE_BODIES): a POINT's body (the
    segment point message, bytes), an :class:`Ack`, :class:`LinkStatus`, :class:`Identity` or
    :class:`FusionStatus`."""
    return _DECODERS[kind](body)
