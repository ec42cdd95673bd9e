"""The SlimeVR tracker protocol over UDP (docs/protocol.md, "SlimeVR gateway"): decode what a
tracker sends, encode what a server answers. Pure: bytes in, values out, no I/O.

Every datagram is big-endian: ``i32 type, i64 packet number, payload``. A tracker numbers its
packets from 0 up (a handshake, and a pong, which echoes the server's ping, carry 0); a server
sends number 0. Bundles (100: ``u16 length, i32 type, payload`` repeated; 101, compact:
``u8 length, u8 type, payload`` repeated) carry several packets under one number.

Datagrams of rotations only, nearly all of the traffic, are read the same way in C
(``firmware_c/host/lsw_slimevr.c``; tests/test_grid.py checks that both agree).
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

PORT = 6969
"""The port trackers look for a server on."""
MAX_DATAGRAM = 1472
"""Largest datagram a tracker sends (1500-byte MTU less the IPv4 and UDP headers); longer: oversized."""
SERVER_TIMEOUT_S = 3.0
"""A tracker that hears nothing from its server for this long searches for one again (firmware)."""
TRACKER_TIMEOUT_S = 1.0
"""A server counts a tracker silent for this long as timed out (SlimeVR server)."""
KEEPALIVE_S = 0.5
"""A server sends each tracker a heartbeat and a ping this often (SlimeVR server)."""

# tracker -> server
HEARTBEAT, HANDSHAKE, ACCEL, PING_PONG, SERIAL, BATTERY, TAP, ERROR, SENSOR_INFO = 0, 3, 4, 10, 11, 12, 13, 14, 15
ROTATION_DATA, MAG_ACCURACY, SIGNAL, TEMPERATURE, USER_ACTION, FEATURE_FLAGS = 17, 18, 19, 20, 21, 22
ROTATION_ACCEL, ACK_CONFIG, FLEX_DATA, BUNDLE, BUNDLE_COMPACT, INSPECTION = 23, 24, 26, 100, 101, 105
IGNORED = frozenset({ACCEL, SERIAL, TAP, ERROR, MAG_ACCURACY, TEMPERATURE, USER_ACTION, ACK_CONFIG, FLEX_DATA,
                     INSPECTION})
"""Types a tracker may send that carry nothing limbstream uses: read and counted, not decoded."""
# server -> tracker
SERVER_HEARTBEAT = 1
ROTATION_NORMAL = 1
"""Rotation data type of the sensor's fused orientation (2: a magnetometer correction, ignored)."""

HANDSHAKE_GREETING = b"Hey OVR =D 5"
SERVER_FEATURES = bytes([0b11])
"""Server feature flags: bit 0 bundles (100), bit 1 compact bundles (101) and rotation +
acceleration (23)."""

_HEADER = struct.Struct(">iq")
_ROTATION = struct.Struct(">BB4fB")
_ROTATION_Q15 = struct.Struct(">B4h3h")
_Q15 = 1.0 / 32768.0


class ProtocolError(ValueError):
    """A datagram that is not a valid tracker packet; ``reason`` is the counter it goes to:
    truncated, oversized, unknown_type, bad_quaternion, bad_bundle."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Handshake:
    """A tracker looking for a server: board, IMU and MCU type ids, protocol version, firmware
    version, MAC address (``AA:BB:..``; None if it sent none or zeros)."""

    board: int = 0
    imu: int = 0
    mcu: int = 0
    protocol: int = 0
    firmware: str = ""
    mac: str | None = None


@dataclass(frozen=True, slots=True)
class SensorInfo:
    """Sensor ``sensor`` of the tracker: status (0 offline, 1 ok, 2 error), IMU type id and the
    body position it was set to (a SlimeVR TrackerPosition id; None: not sent, or 0)."""

    sensor: int
    status: int
    imu: int = 0
    position: int | None = None


@dataclass(slots=True)
class Rotation:
    """The fused orientation of sensor ``sensor``: ``q`` (w, x, y, z), unit norm, in the
    tracker's axes."""

    sensor: int
    q: tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class Battery:
    """Battery voltage (V) and level (fraction 0..1)."""

    voltage: float
    level: float


@dataclass(frozen=True, slots=True)
class Signal:
    """Wi-Fi signal strength, dBm."""

    dbm: int


@dataclass(frozen=True, slots=True)
class Pong:
    """The tracker's echo of a server ping."""

    ping_id: int


@dataclass(frozen=True, slots=True)
class Other:
    """A packet of a type limbstream reads but does not use (heartbeat, feature flags,
    correction data, :data:`IGNORED`), or does not know (``known`` False)."""

    type: int
    known: bool = True


Message = Handshake | SensorInfo | Rotation | Battery | Signal | Pong | Other


@dataclass(slots=True)
class Datagram:
    """One decoded datagram: its (outer) type, packet number and messages."""

    type: int
    number: int
    messages: tuple[Message, ...]


def _quaternion(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if not math.isfinite(norm) or norm < 1e-3:
        raise ProtocolError("bad_quaternion", f"rotation ({w}, {x}, {y}, {z}) is not finite or is zero")
    return (w / norm, x / norm, y / norm, z / norm)


def _need(payload: bytes, size: int, what: str) -> None:
    if len(payload) < size:
        raise ProtocolError("truncated", f"{what} needs {size} bytes, got {len(payload)}")


def _mac(raw: bytes) -> str | None:
    return None if raw == bytes(6) else ":".join(f"{b:02X}" for b in raw)


def _handshake(p: bytes) -> Handshake:
    """Board, IMU, MCU (i32 each), three unused i32, protocol (i32), firmware (u8 length +
    ASCII), MAC (6 bytes); later fields (vendor strings) are not read. Old firmware sends fewer."""
    ints = [struct.unpack_from(">i", p, 4 * k)[0] if len(p) >= 4 * k + 4 else 0 for k in range(7)]
    at, firmware, mac = 28, "", None
    if len(p) > at:
        n = p[at]
        firmware = p[at + 1:at + 1 + n].split(b"\0")[0].decode("ascii", "replace")
        at += 1 + n
    if len(p) >= at + 6:
        mac = _mac(p[at:at + 6])
    return Handshake(ints[0], ints[1], ints[2], ints[6], firmware, mac)


def decode_message(kind: int, p: bytes) -> Message:
    """One packet's payload (after the header, or a bundle item's after its type)."""
    if kind == ROTATION_DATA:
        _need(p, _ROTATION.size - 1, "rotation data")  # (accuracy byte optional)
        sensor, data_type, x, y, z, w = struct.unpack_from(">BB4f", p)
        if data_type != ROTATION_NORMAL:
            return Other(kind)
        return Rotation(sensor, _quaternion(w, x, y, z))
    if kind == ROTATION_ACCEL:
        _need(p, 9, "rotation and acceleration")
        sensor, x, y, z, w = struct.unpack_from(">B4h", p)
        return Rotation(sensor, _quaternion(w * _Q15, x * _Q15, y * _Q15, z * _Q15))
    if kind == SENSOR_INFO:
        _need(p, 2, "sensor info")
        position = p[6] if len(p) > 6 and p[6] else None
        return SensorInfo(p[0], p[1], p[2] if len(p) > 2 else 0, position)
    if kind == BATTERY:
        _need(p, 4, "battery level")
        if len(p) >= 8:
            voltage, level = struct.unpack_from(">ff", p)
        else:
            voltage, level = 0.0, struct.unpack_from(">f", p)[0]
        return Battery(voltage if math.isfinite(voltage) else 0.0, level if math.isfinite(level) else math.nan)
    if kind == SIGNAL:
        _need(p, 2, "signal strength")
        return Signal(struct.unpack_from(">b", p, 1)[0])
    if kind == PING_PONG:
        _need(p, 4, "ping")
        return Pong(struct.unpack_from(">i", p)[0])
    if kind == HANDSHAKE:
        return _handshake(p)
    if kind in (HEARTBEAT, FEATURE_FLAGS) or kind in IGNORED:
        return Other(kind)
    return Other(kind, known=False)


def _bundle(p: bytes, compact: bool) -> tuple[Message, ...]:
    out, at = [], 0
    size = 1 if compact else 2
    while at < len(p):
        if len(p) < at + size:
            raise ProtocolError("bad_bundle", "bundle item length cut off")
        n = p[at] if compact else struct.unpack_from(">H", p, at)[0]
        at += size
        item = p[at:at + n]
        if len(item) < n:
            raise ProtocolError("truncated", f"bundle item of {n} bytes has {len(item)}")
        at += n
        if n == 0:
            continue
        head = 1 if compact else 4
        if n < head:
            raise ProtocolError("bad_bundle", f"bundle item of {n} bytes has no type")
        kind = item[0] if compact else struct.unpack_from(">i", item)[0]
        if kind in (BUNDLE, BUNDLE_COMPACT, HANDSHAKE):
            raise ProtocolError("bad_bundle", f"packet type {kind} inside a bundle")
        out.append(decode_message(kind, item[head:]))
    return tuple(out)


def decode(datagram: bytes) -> Datagram:
    """A datagram from a tracker -> Datagram; ProtocolError (with its reason) if it is not one."""
    if len(datagram) > MAX_DATAGRAM:
        raise ProtocolError("oversized", f"datagram of {len(datagram)} bytes (at most {MAX_DATAGRAM})")
    _need(datagram, _HEADER.size, "packet header")
    kind, number = _HEADER.unpack_from(datagram)
    payload = datagram[_HEADER.size:]
    if kind in (BUNDLE, BUNDLE_COMPACT):
        return Datagram(kind, number, _bundle(payload, kind == BUNDLE_COMPACT))
    message = decode_message(kind, payload)
    if isinstance(message, Other) and not message.known:
        raise ProtocolError("unknown_type", f"unknown packet type {kind}")
    return Datagram(kind, number, (message,))


# ---------------------------------------------------------------- server -> tracker

def handshake_answer() -> bytes:
    """The answer to a handshake: 64 bytes, type 3 in the first byte (not the fourth), then the
    greeting the firmware checks."""
    return (bytes([HANDSHAKE]) + HANDSHAKE_GREETING).ljust(64, b"\0")


def heartbeat() -> bytes:
    """A heartbeat (the tracker answers with its own, type 0)."""
    return _HEADER.pack(SERVER_HEARTBEAT, 0)


def ping(ping_id: int) -> bytes:
    """A ping (the tracker echoes it as is: its pong)."""
    return _HEADER.pack(PING_PONG, 0) + struct.pack(">i", ping_id)


def sensor_info_answer(sensor: int, status: int) -> bytes:
    """The acknowledgement of a sensor info: type, sensor id, status (no packet number); until
    it comes, the tracker sends its sensor info again every second."""
    return struct.pack(">iBB", SENSOR_INFO, sensor & 0xFF, status & 0xFF)


def feature_flags() -> bytes:
    """The server's feature flags (:data:`SERVER_FEATURES`), the answer to the tracker's."""
    return _HEADER.pack(FEATURE_FLAGS, 0) + SERVER_FEATURES


# ---------------------------------------------------------------- body positions

POSITION_SEGMENTS: dict[int, tuple[str, ...]] = {
    1: ("head",), 2: ("neck", "head"), 3: ("chest",), 4: ("chest",), 5: ("hip",), 6: ("hip",),
    7: ("l_thigh",), 8: ("r_thigh",), 9: ("l_shank",), 10: ("r_shank",), 11: ("l_foot",), 12: ("r_foot",),
    13: ("l_lowerarm",), 14: ("r_lowerarm",), 15: ("l_upperarm",), 16: ("r_upperarm",),
    17: ("l_hand",), 18: ("r_hand",), 19: ("l_shoulder",), 20: ("r_shoulder",),
}
"""SlimeVR body position ids (TrackerPosition: 1 head, 2 neck, 3 upper chest, 4 chest, 5 waist,
6 hip, 7-10 upper and lower legs, 11-12 feet, 13-14 lower arms, 15-16 upper arms, 17-18 hands,
19-20 shoulders) -> the segments that may carry it, first choice first: a sensor feeds the first
one its subject's layout has (:func:`position_segment`). The neck is ``paper10``'s head-and-neck
segment and the ``full`` layout's head; chest and upper chest both feed the chest, as the waist
and the hip feed the pelvis (the first such sensor placed takes it: a second is listed as taken);
the shoulders have a segment only in a layout file that names one. Finger positions have none."""


def position_segment(position: int | None, segments: tuple[str, ...]) -> str | None:
    """The segment a sensor at SlimeVR body position ``position`` feeds among ``segments`` (its
    subject's layout's), or None."""
    return next((s for s in POSITION_SEGMENTS.get(position or 0, ()) if s in segments), None)
