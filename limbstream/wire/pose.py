"""Pose frames: one full-body frame of a subject (356 bytes, little-endian)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .body import JOINTS, SEGMENTS
from .errors import WireError
from .keys import POSE
from .point import VERSION

KIND_EXACT, KIND_LIVE = 0, 1
FRAME_KINDS: dict[str, int] = {"exact": KIND_EXACT, "live": KIND_LIVE}
"""The pose frame kinds by name, the one table of them (the pose stream API's and ``limbstream
watch``'s ``kind``, the kinds' publisher options); ``auto`` (:data:`AUTO`) picks one by
:func:`auto_kind`."""
AUTO = "auto"
FRAME_GAP = 0x01
"""Pose frame flag: a device's sequence gap affects this frame (reconstruction may be wrong)."""
FRAME_MISSING = 0x02
"""Pose frame flag: some segment has no data (offline device); its orientation is held or identity."""
FRAME_TPOSE = 0x04
"""Pose frame flag: the orientations refer to the ``tpose`` rest pose (clear: ``standing``;
wire.REST_POSES)."""


AUTO_LIVE_WINDOW_S = 1.0
"""The one frame-kind rule (``kind=auto``: the dashboard's pose streams, Foxglove, VMC): a
subject's live frames while one of them came within this many seconds, else its exact frames.
Live frames are current (exact frames are final but about 0.4 s late); exact frames stand in for
a subject whose aggregator publishes no live frames (``--live-rate 0``) or stopped."""


def kind_name(kind: int) -> str:
    """The name of pose frame kind ``kind`` (:data:`FRAME_KINDS`)."""
    return "live" if kind == KIND_LIVE else "exact"


def pose_stream(kind: int) -> str:
    """``pose_exact`` / ``pose_live``: the pose stream of frames of ``kind`` (their publisher
    options, their sequence numbering)."""
    return f"{POSE}_{kind_name(kind)}"


def auto_kind(since_live_s: float) -> int:
    """The kind ``kind=auto`` shows, seconds after a subject's newest live frame (inf: none yet)."""
    return KIND_LIVE if since_live_s < AUTO_LIVE_WINDOW_S else KIND_EXACT


def frame_rest_pose(flags: int) -> str:
    """The rest pose a pose frame's orientations refer to, from its flags."""
    return "tpose" if flags & FRAME_TPOSE else "standing"


def rest_pose_flag(rest_pose: str) -> int:
    """The pose-frame flag bits of ``rest_pose``."""
    return FRAME_TPOSE if rest_pose == "tpose" else 0

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
        Segment orientations in :data:`~limbstream.wire.body.SEGMENTS` order.
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
            "kind": kind_name(self.kind),
            "gap": bool(self.flags & FRAME_GAP),
            "missing": bool(self.flags & FRAME_MISSING),
            "rest_pose": frame_rest_pose(self.flags),
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
