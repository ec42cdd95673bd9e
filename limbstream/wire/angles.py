"""Joint-angle messages: one subject's joint angles at one pose frame (115 bytes, little-endian;
docs/protocol.md, "Joint angles").

The aggregator publishes one per pose frame it takes them from (its live frames: at the live
frame rate), with that frame's kind, sequence number and time, so a client can pair them. Every
angle carries flag bits; the message says which calibration its angles rest on
(:data:`ANGLE_BASES`): where that makes no anatomical frame, every angle is flagged UNCALIBRATED
and no number is sent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .body import JOINT_ANGLES
from .errors import WireError
from .pose import kind_name

ANGLE_MISSING, ANGLE_GIMBAL, ANGLE_UNCALIBRATED = 1, 2, 4
"""Flag bits of one angle (0: a valid angle): a segment of its joint has no data (no number);
the joint is within ``joints.GIMBAL_DEG`` of gimbal lock (a number, ill-conditioned); the
subject's frames are not anatomical (no number)."""
ANGLE_FLAGS: dict[str, int] = {"missing": ANGLE_MISSING, "gimbal": ANGLE_GIMBAL, "uncalibrated": ANGLE_UNCALIBRATED}
"""The flag bits by name (the JSON form's)."""
_NO_NUMBER = ANGLE_MISSING | ANGLE_UNCALIBRATED


@dataclass(frozen=True)
class AngleBasis:
    """A calibration the angles of a message can rest on: its name, whether it gives anatomical
    frames (angles), and what it means (for a client to tell its user)."""

    name: str
    valid: bool
    meaning: str


ANGLE_BASES: tuple[AngleBasis, ...] = (
    AngleBasis("unknown", False, "a device of the subject has not said yet what its orientations are"),
    AngleBasis("uncalibrated", False, "a device reports its sensor's orientation, not its segment's, and is not "
                                      "calibrated (calibrate the subject: rest and mounting poses)"),
    AngleBasis("no_facing", False, "rest calibration only: which way the subject faces is found once a knee or an "
                                   "elbow has moved (about 10 deg RMS about a horizontal axis)"),
    AngleBasis("segments", True, "the devices send their segments' own orientations"),
    AngleBasis("mounting", True, "calibrated from the rest and mounting poses"),
    AngleBasis("functional", True, "rest calibration, and the facing found from the knees' and elbows' motion "
                                   "(facing_deg)"),
)
"""The calibrations a message's angles can rest on, by code (the message's ``basis`` byte)."""
BASIS: dict[str, int] = {b.name: code for code, b in enumerate(ANGLE_BASES)}
"""The code of each basis by name."""

ANGLES_VERSION = 1
ANGLES_DTYPE = np.dtype([("version", "u1"), ("kind", "u1"), ("basis", "u1"), ("n_angles", "u1"), ("seq", "<u4"),
                         ("t_us", "<i8"), ("facing_deg", "<f4"), ("angles", "<f4", (len(JOINT_ANGLES),)),
                         ("flags", "u1", (len(JOINT_ANGLES),))])
"""Layout of a joint-angle payload (115 bytes, packed little-endian)."""
ANGLES_SIZE = ANGLES_DTYPE.itemsize
_VALID = np.array([b.valid for b in ANGLE_BASES])


@dataclass(frozen=True)
class JointAngles:
    """One subject's joint angles at one pose frame.

    Attributes
    ----------
    seq, t_us, kind : the pose frame's sequence number, time (us since the epoch, device time)
        and kind (``wire.KIND_LIVE`` / ``KIND_EXACT``).
    basis : the calibration the angles rest on, a code of :data:`ANGLE_BASES`.
    facing_deg : the subject's facing the hinges told (basis ``functional``), degrees; NaN: none.
    angles : (A,) float32 degrees in :data:`JOINT_ANGLES` order; NaN where flagged MISSING or
        UNCALIBRATED.
    flags : (A,) uint8 bits of :data:`ANGLE_FLAGS`.
    """

    seq: int
    t_us: int
    kind: int
    basis: int
    facing_deg: float
    angles: np.ndarray
    flags: np.ndarray

    @property
    def calibration(self) -> AngleBasis:
        return ANGLE_BASES[self.basis]

    def to_json(self, subject: str) -> dict:
        """JSON-ready dict (the REST form): angles by name (null: no number), each flagged angle's
        flag names, the calibration by name and, where it gives no angles, why."""
        basis = self.calibration
        return {"subject": subject, "seq": self.seq, "t": self.t_us / 1e6, "kind": kind_name(self.kind),
                "calibration": basis.name, "valid": basis.valid, "why": None if basis.valid else basis.meaning,
                "facing_deg": None if not math.isfinite(self.facing_deg) else round(float(self.facing_deg), 3),
                "angles": {name: None if not math.isfinite(v) else round(float(v), 3)
                           for name, v in zip(JOINT_ANGLES, self.angles.tolist())},
                "flags": {name: [f for f, bit in ANGLE_FLAGS.items() if bits & bit]
                          for name, bits in zip(JOINT_ANGLES, self.flags.tolist()) if bits}}


@dataclass(frozen=True)
class AngleFrames:
    """F joint-angle messages, columnar (what the aggregator makes per tick, what a batch decodes to).

    Attributes: seq (F,), t_us (F,), kind (F,), basis (F,), facing_deg (F,), angles (F, A), flags
    (F, A), in the units of :class:`JointAngles`.
    """

    seq: np.ndarray
    t_us: np.ndarray
    kind: np.ndarray
    basis: np.ndarray
    facing_deg: np.ndarray
    angles: np.ndarray
    flags: np.ndarray

    def __len__(self) -> int:
        return len(self.t_us)

    def __getitem__(self, i: int) -> JointAngles:
        return JointAngles(int(self.seq[i]), int(self.t_us[i]), int(self.kind[i]), int(self.basis[i]),
                           float(self.facing_deg[i]), self.angles[i].astype(np.float32), self.flags[i].astype(np.uint8))

    def encode(self) -> list[bytes]:
        """One payload per message (built in one pass)."""
        rec = np.zeros(len(self), ANGLES_DTYPE)
        rec["version"], rec["n_angles"] = ANGLES_VERSION, len(JOINT_ANGLES)
        rec["kind"], rec["basis"], rec["seq"], rec["t_us"] = self.kind, self.basis, self.seq, self.t_us
        rec["facing_deg"], rec["angles"], rec["flags"] = self.facing_deg, self.angles, self.flags
        buf = rec.tobytes()
        return [buf[i:i + ANGLES_SIZE] for i in range(0, len(buf), ANGLES_SIZE)]


def encode_angles(a: JointAngles) -> bytes:
    """JointAngles -> 115 bytes (:data:`ANGLES_DTYPE`): u8 version, u8 kind, u8 basis, u8 n_angles,
    u32 seq, i64 t_us, f32 facing_deg, A x f32 angles, A x u8 flags."""
    return AngleFrames(np.array([a.seq]), np.array([a.t_us]), np.array([a.kind]), np.array([a.basis]),
                       np.array([a.facing_deg]), np.asarray(a.angles)[None], np.asarray(a.flags)[None]).encode()[0]


def decode_angles_many(payloads: list[bytes]) -> tuple[AngleFrames, list[str]]:
    """Payloads -> (the messages that keep the contract, in order; (n,) the reason each payload
    was refused, '' for a good one): ``size``, ``version`` (or an angle count other than
    len(JOINT_ANGLES)), ``value`` (an unknown kind, basis or flag bit; an angle without
    MISSING/UNCALIBRATED that is not finite, or one with them that is not NaN; a basis that gives
    no angles with an angle not flagged UNCALIBRATED, or one that does with one flagged so; an
    infinite facing)."""
    reasons = ["" if len(p) == ANGLES_SIZE else "size" for p in payloads]
    sized = [p for p, r in zip(payloads, reasons) if not r]
    rec = np.frombuffer(b"".join(sized), ANGLES_DTYPE)
    version = (rec["version"] != ANGLES_VERSION) | (rec["n_angles"] != len(JOINT_ANGLES))
    flags, angles = rec["flags"], rec["angles"]
    number = (flags & _NO_NUMBER) == 0
    uncalibrated = (flags & ANGLE_UNCALIBRATED) != 0
    valid = _VALID[np.minimum(rec["basis"], len(ANGLE_BASES) - 1)]
    value = ((rec["kind"] > 1) | (rec["basis"] >= len(ANGLE_BASES)) | (flags & ~np.uint8(7)).any(axis=1)
             | (number & ~np.isfinite(angles)).any(axis=1) | (~number & ~np.isnan(angles)).any(axis=1)
             | np.where(valid, uncalibrated.any(axis=1), ~uncalibrated.all(axis=1)) | np.isinf(rec["facing_deg"]))
    sized_reasons = np.where(version, "version", np.where(value, "value", "")).tolist()
    it = iter(sized_reasons)
    reasons = [r or next(it) for r in reasons]
    good = rec[np.array([not r for r in sized_reasons], bool)]
    return AngleFrames(good["seq"].astype(np.int64), good["t_us"].astype(np.int64), good["kind"].astype(np.int64),
                       good["basis"].astype(np.int64), good["facing_deg"].astype(np.float64), good["angles"].copy(),
                       good["flags"].copy()), reasons


def decode_angles(payload: bytes) -> JointAngles:
    """Bytes -> JointAngles; WireError with reason size / version / value
    (:func:`decode_angles_many`)."""
    frames, (reason,) = decode_angles_many([bytes(payload)])
    if reason:
        raise WireError(reason, f"joint-angle message refused ({len(payload)} bytes): {_WHY[reason]}")
    return frames[0]


_WHY = {"size": f"expected {ANGLES_SIZE} bytes", "version": f"not version {ANGLES_VERSION} with {len(JOINT_ANGLES)} angles",
        "value": "a kind, basis or flag unknown, or angles that do not match their flags and basis"}
