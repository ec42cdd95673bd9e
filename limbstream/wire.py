"""The wire contract, one place: key expressions and payload codecs (docs/protocol.md).

All binary payloads are little-endian and start with a format version byte.

Key expressions (``<subject>`` and ``<segment>`` are single chunks):

==========================================  ===============================  ==============
key                                          payload                          publisher
==========================================  ===============================  ==============
``limbstream/<subject>/<segment>/seg``       :class:`SegmentPoint` (36 B)     device
``limbstream/<subject>/<segment>/raw``       :class:`RawBatch` (truth tap)    device
``limbstream/<subject>/<segment>/alive``     liveliness token                 device
``limbstream/<subject>/<segment>/config``    queryable, JSON :class:`DeviceConfig`  device
``limbstream/<subject>/pose``                :class:`PoseFrame`               aggregator
``limbstream/<subject>/stats``               JSON stats (:func:`encode_stats`) aggregator
==========================================  ===============================  ==============
"""
from __future__ import annotations

import json
import math
import re
import struct
from dataclasses import dataclass, field

import numpy as np

from limbstream.sources import SEGMENTS

PREFIX = "limbstream"
VERSION = 1
UNIT_TOLERANCE = 1e-3
"""A segment point's quaternion norm must be within 1 +- this."""

_CHUNK = re.compile(r"^[A-Za-z0-9_.\-]+$")


class WireError(ValueError):
    """A payload or key that breaks the contract. ``reason`` is a short counter label."""

    def __init__(self, reason: str, message: str):
        super().__init__(f"{reason}: {message}")
        self.reason = reason


# ----------------------------------------------------------------------------- keys


def check_chunk(name: str, what: str = "name") -> str:
    """Return ``name`` if it is a valid single key chunk, else raise ValueError naming it."""
    if not isinstance(name, str) or not _CHUNK.match(name):
        raise ValueError(f"{what} must be a non-empty chunk of letters, digits, '_', '-', '.'; got {name!r}")
    return name


def device_id(subject: str, segment: str) -> str:
    """The device id ``<subject>/<segment>`` used in keys, stats and the REST API."""
    return f"{check_chunk(subject, 'subject')}/{check_chunk(segment, 'segment')}"


def seg_key(subject: str, segment: str) -> str:
    return f"{PREFIX}/{device_id(subject, segment)}/seg"


def raw_key(subject: str, segment: str) -> str:
    return f"{PREFIX}/{device_id(subject, segment)}/raw"


def alive_key(subject: str, segment: str) -> str:
    return f"{PREFIX}/{device_id(subject, segment)}/alive"


def config_key(subject: str, segment: str) -> str:
    return f"{PREFIX}/{device_id(subject, segment)}/config"


def pose_key(subject: str) -> str:
    return f"{PREFIX}/{check_chunk(subject, 'subject')}/pose"


def stats_key(subject: str) -> str:
    return f"{PREFIX}/{check_chunk(subject, 'subject')}/stats"


def subject_pattern(text: str) -> str:
    """A user's subject pattern as a key chunk: ``*`` (all), a name, or a name with ``*``
    wildcards inside (``s0*`` becomes Zenoh's ``s0$*``). ValueError if it is neither."""
    text = text.strip()
    if text == "*":
        return text
    check_chunk(text.replace("*", "x"), "subject pattern")
    return text.replace("*", "$*")


def subject_selector(subjects: str = "*") -> str:
    """Key expression of every device key of the subjects matched by ``subjects`` (a chunk or ``*``)."""
    return f"{PREFIX}/{subjects}/*"


def parse_device_key(key: str) -> tuple[str, str, str]:
    """``limbstream/<subject>/<segment>/<kind>`` -> (subject, segment, kind); WireError('key') otherwise."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != PREFIX or not all(_CHUNK.match(p) for p in parts[1:]):
        raise WireError("key", f"not a device key: {key!r}")
    return parts[1], parts[2], parts[3]


def parse_subject_key(key: str) -> tuple[str, str]:
    """``limbstream/<subject>/<kind>`` -> (subject, kind); WireError('key') otherwise."""
    parts = str(key).split("/")
    if len(parts) != 3 or parts[0] != PREFIX or not all(_CHUNK.match(p) for p in parts[1:]):
        raise WireError("key", f"not a subject key: {key!r}")
    return parts[1], parts[2]


# ----------------------------------------------------------------------------- segment point

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


# ----------------------------------------------------------------------------- truth tap

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


# ----------------------------------------------------------------------------- pose frame

JOINTS: tuple[str, ...] = (
    "pelvis", "neck_base", "head",
    "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle",
    "l_shoulder", "l_elbow", "l_wrist", "r_shoulder", "r_elbow", "r_wrist",
)
"""Joint positions of a pose frame, in this order (see limbstream.skeleton)."""

BONES: tuple[tuple[str, str], ...] = (
    ("pelvis", "neck_base"), ("neck_base", "head"),
    ("pelvis", "l_hip"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"),
    ("pelvis", "r_hip"), ("r_hip", "r_knee"), ("r_knee", "r_ankle"),
    ("neck_base", "l_shoulder"), ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"),
    ("neck_base", "r_shoulder"), ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"),
)
"""Lines a client draws between joints."""

KIND_EXACT, KIND_LIVE = 0, 1
FRAME_GAP = 0x01
"""Pose frame flag: a device's sequence gap affects this frame (reconstruction may be wrong)."""
FRAME_MISSING = 0x02
"""Pose frame flag: some segment has no data (offline device); its orientation is held or identity."""

POSE_DTYPE = np.dtype([("version", "u1"), ("kind", "u1"), ("flags", "u1"), ("n_segments", "u1"),
                       ("seq", "<u4"), ("t_us", "<i8"), ("q", "<f4", (len(SEGMENTS), 4)),
                       ("joints", "<f4", (len(JOINTS), 3))])
"""Layout of a pose frame payload (356 bytes, packed little-endian)."""
_POSE_SIZE = POSE_DTYPE.itemsize


@dataclass(frozen=True)
class PoseFrame:
    """A full-body frame of one subject.

    Attributes
    ----------
    seq : int
        Frame counter per subject and kind.
    t_us : int
        Frame time, microseconds since the Unix epoch (device time base).
    kind : int
        :data:`KIND_EXACT` (final, below the watermark) or :data:`KIND_LIVE` (at "now").
    flags : int
        :data:`FRAME_GAP`, :data:`FRAME_MISSING`.
    q : (10, 4) float32
        Segment orientations in :data:`limbstream.sources.SEGMENTS` order.
    joints : (15, 3) float32
        Joint positions, metres, in :data:`JOINTS` order (Y up, pelvis at the origin).
    """

    seq: int
    t_us: int
    kind: int
    flags: int
    q: np.ndarray
    joints: np.ndarray = field(default_factory=lambda: np.zeros((len(JOINTS), 3), np.float32))

    def to_json(self, subject: str) -> dict:
        """JSON-ready dict (the WebSocket / SSE / REST form)."""
        return {
            "subject": subject,
            "seq": self.seq,
            "t": self.t_us / 1e6,
            "kind": "live" if self.kind == KIND_LIVE else "exact",
            "gap": bool(self.flags & FRAME_GAP),
            "missing": bool(self.flags & FRAME_MISSING),
            "segments": {s: [round(float(v), 6) for v in self.q[i]] for i, s in enumerate(SEGMENTS)},
            "joints": {j: [round(float(v), 4) for v in self.joints[i]] for i, j in enumerate(JOINTS)},
        }


@dataclass(frozen=True)
class PoseFrames:
    """F pose frames of one kind, columnar (what the aggregator builds per tick).

    Attributes: seq (F,) int, t_us (F,) int, kind, flags (F,) int, q (F, 10, 4), joints (F, 15, 3)
    in the units of :class:`PoseFrame`.
    """

    seq: np.ndarray
    t_us: np.ndarray
    kind: int
    flags: np.ndarray
    q: np.ndarray
    joints: np.ndarray

    @classmethod
    def empty(cls, kind: int) -> PoseFrames:
        return cls(np.zeros(0, np.int64), np.zeros(0, np.int64), kind, np.zeros(0, np.int64),
                   np.zeros((0, len(SEGMENTS), 4)), np.zeros((0, len(JOINTS), 3)))

    def __len__(self) -> int:
        return len(self.t_us)

    def __getitem__(self, i: int) -> PoseFrame:
        return PoseFrame(int(self.seq[i]), int(self.t_us[i]), self.kind, int(self.flags[i]),
                         self.q[i].astype(np.float32), self.joints[i].astype(np.float32))

    def encode(self) -> list[bytes]:
        """One payload per frame, as :func:`encode_pose` (built in one pass)."""
        rec = np.zeros(len(self), POSE_DTYPE)
        rec["version"], rec["kind"], rec["n_segments"] = VERSION, self.kind, len(SEGMENTS)
        rec["flags"], rec["seq"], rec["t_us"] = self.flags, self.seq, self.t_us
        rec["q"], rec["joints"] = self.q, self.joints
        buf = rec.tobytes()
        return [buf[i:i + _POSE_SIZE] for i in range(0, len(buf), _POSE_SIZE)]


def encode_pose(frame: PoseFrame) -> bytes:
    """PoseFrame -> 356 bytes (:data:`POSE_DTYPE`): u8 version, u8 kind, u8 flags, u8 n_segments,
    u32 seq, i64 t_us, 10 x 4 f32 quaternions, 15 x 3 f32 joint positions."""
    return PoseFrames(np.array([frame.seq]), np.array([frame.t_us]), frame.kind, np.array([frame.flags]),
                      np.asarray(frame.q)[None], np.asarray(frame.joints)[None]).encode()[0]


def decode_pose(payload: bytes) -> PoseFrame:
    """Bytes -> PoseFrame; WireError with reason size / version."""
    if len(payload) != _POSE_SIZE:
        raise WireError("size", f"pose frame has {len(payload)} bytes, expected {_POSE_SIZE}")
    rec = np.frombuffer(payload, POSE_DTYPE, 1)[0]
    if rec["version"] != VERSION or rec["n_segments"] != len(SEGMENTS):
        raise WireError("version", f"pose frame version {rec['version']} with {rec['n_segments']} segments")
    return PoseFrame(int(rec["seq"]), int(rec["t_us"]), int(rec["kind"]), int(rec["flags"]),
                     rec["q"].copy(), rec["joints"].copy())


# ----------------------------------------------------------------------------- stats and config

STATS_FIELDS: tuple[str, ...] = (
    "device", "segment", "online", "samples", "points", "icr", "msgs_per_s", "bytes_per_s",
    "aad_deg", "p99_deg", "max_deg", "live_err_deg", "watermark_lag_s", "gaps", "dropped",
    "threshold",
)
"""Fields of every device entry of a stats message."""


def encode_stats(subject: str, t: float, devices: list[dict], extra: dict | None = None) -> bytes:
    """Stats JSON: ``{"subject", "t" (s, epoch), "devices": [{STATS_FIELDS...}, ...], **extra}``.
    Non-finite numbers become null."""

    def clean(v):
        return None if isinstance(v, float) and not math.isfinite(v) else v

    entries = [{k: clean(d.get(k)) for k in STATS_FIELDS} | {
        k: clean(v) for k, v in d.items() if k not in STATS_FIELDS} for d in devices]
    message = {k: clean(v) for k, v in (extra or {}).items()} | {"subject": subject, "t": t, "devices": entries}
    return json.dumps(message, separators=(",", ":")).encode()


def decode_stats(payload: bytes) -> dict:
    """Stats JSON -> dict; WireError('json') if malformed or missing fields."""
    try:
        data = json.loads(bytes(payload))  # RecursionError: nesting deeper than the parser allows
        devices = data["devices"]
        if not isinstance(data["subject"], str) or not isinstance(devices, list):
            raise TypeError("subject must be a string and devices a list")
        for d in devices:
            missing = [k for k in STATS_FIELDS if k not in d]
            if missing:
                raise KeyError(f"device entry lacks {missing}")
    except (ValueError, KeyError, TypeError, RecursionError) as exc:
        raise WireError("json", f"bad stats message: {exc}") from None
    return data


@dataclass(frozen=True)
class DeviceConfig:
    """Settings a device applies: SSR threshold and max segment length (samples)."""

    threshold: float
    max_len: int

    def validate(self) -> DeviceConfig:
        if not (isinstance(self.threshold, (int, float)) and math.isfinite(self.threshold) and self.threshold >= 0):
            raise ValueError(f"threshold must be a finite number >= 0, got {self.threshold!r}")
        if not (isinstance(self.max_len, int) and 1 <= self.max_len <= 100_000):
            raise ValueError(f"max_len must be an integer in 1..100000, got {self.max_len!r}")
        return self


def encode_config(config: DeviceConfig) -> bytes:
    return json.dumps({"threshold": config.threshold, "max_len": config.max_len}).encode()


def decode_config(payload: bytes, current: DeviceConfig | None = None) -> DeviceConfig:
    """JSON ``{"threshold": float, "max_len": int}`` -> validated DeviceConfig; WireError('config').

    With ``current``, either field may be left out (it keeps its current value)."""
    try:
        data = json.loads(bytes(payload))
    except (ValueError, RecursionError) as exc:  # RecursionError: absurdly deep nesting
        raise WireError("config", f"device config is not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise WireError("config", "device config must be a JSON object {threshold, max_len}")
    unknown = set(data) - {"threshold", "max_len"}
    if unknown:
        raise WireError("config", f"unknown device config fields {sorted(unknown)}")
    base = current or DeviceConfig(math.nan, 0)
    if current is None and len(data) < 2 or not data:
        raise WireError("config", "device config needs threshold and max_len")
    threshold = data.get("threshold", base.threshold)
    max_len = data.get("max_len", base.max_len)
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)):
        raise WireError("config", f"threshold must be a number, got {threshold!r}")
    if isinstance(max_len, bool):
        raise WireError("config", f"max_len must be an integer, got {max_len!r}")
    try:
        return DeviceConfig(float(threshold), max_len).validate()
    except (ValueError, OverflowError) as exc:  # OverflowError: an integer beyond float range
        raise WireError("config", str(exc)) from None
