"""Joint-angle messages: one subject's joint angles at one pose frame, those of its body layout
(little-endian; docs/protocol.md, "Joint angles").

The aggregator publishes one per pose frame it takes them from (its live frames: at the live
frame rate), with that frame's kind, sequence number and time, so a client can pair them. Every
angle carries flag bits; the message says which calibration its angles rest on
(:data:`ANGLE_BASES`): where that makes no anatomical frame, every angle is flagged UNCALIBRATED
and no number is sent.

Version 2 (published): a 24-byte header naming the layout (its code, as a pose frame's:
``wire.LAYOUT_CODES``, or ``OTHER_LAYOUT`` for a layout file's) and the angle count, then the
layout's angles (``wire.joint_angles(layout)``) and their flags: 119 bytes for ``paper10``, 174
for ``full``. Version 1 (115 bytes, ``paper10``'s 20 angles, no layout byte) is still read.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .body import JOINT_ANGLES, joint_angles
from .errors import WireError
from .pose import LAYOUT_CODES, OTHER_LAYOUT, kind_name, layout_code

if TYPE_CHECKING:
    from limbstream.body import Layout

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

ANGLES_VERSION = 2
"""The joint-angle message version published: a layout's angles, the layout in the header."""
ANGLES_VERSION_V1 = 1
"""The first version (115 bytes, ``paper10`` only): read, no longer published."""
ANGLES_HEADER_SIZE = 24
"""Bytes before a version-2 message's angles."""
_HEADER = [("version", "u1"), ("kind", "u1"), ("basis", "u1"), ("n_angles", "u1"), ("seq", "<u4"), ("t_us", "<i8"),
           ("facing_deg", "<f4")]


def angles_dtype(n_angles: int) -> np.dtype:
    """Layout of a version-2 joint-angle payload of ``n_angles`` angles: u8 version, u8 kind, u8
    basis, u8 n_angles, u32 seq, i64 t_us, f32 facing_deg, u8 layout, 3 x u8 reserved (0), then
    A x f32 angles and A x u8 flags (24 + 5 A bytes, packed)."""
    return np.dtype(_HEADER + [("layout", "u1"), ("reserved", "u1", (3,)), ("angles", "<f4", (n_angles,)),
                               ("flags", "u1", (n_angles,))])


_COMMON_SIZE = np.dtype(_HEADER).itemsize
"""The bytes every version begins with (20: version to facing_deg)."""
_FIELDS = tuple(name for name, _ in _HEADER) + ("angles", "flags")
"""The fields both versions have."""
ANGLES_DTYPE_V1 = np.dtype(_HEADER + [("angles", "<f4", (len(JOINT_ANGLES),)), ("flags", "u1", (len(JOINT_ANGLES),))])
"""Layout of a version-1 joint-angle payload (115 bytes, ``paper10``'s angles)."""
ANGLES_DTYPE = angles_dtype(len(JOINT_ANGLES))
"""Layout of a ``paper10`` joint-angle payload (119 bytes, packed little-endian)."""
ANGLES_SIZE = ANGLES_DTYPE.itemsize


@functools.lru_cache(maxsize=16)
def angle_names(layout: Layout | None) -> tuple[str, ...]:
    """The angles of a message of ``layout`` (None: ``paper10``), in order."""
    return JOINT_ANGLES if layout is None or _is_paper10(layout) else joint_angles(layout)


def _is_paper10(layout: Layout) -> bool:
    return layout_code(layout) == 0


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
    angles : (A,) float32 degrees in the layout's angle order (:attr:`names`); NaN where flagged
        MISSING or UNCALIBRATED.
    flags : (A,) uint8 bits of :data:`ANGLE_FLAGS`.
    layout : the subject's body layout (``limbstream.body.Layout``; None: ``paper10``).
    """

    seq: int
    t_us: int
    kind: int
    basis: int
    facing_deg: float
    angles: np.ndarray
    flags: np.ndarray
    layout: Layout | None = None

    @property
    def calibration(self) -> AngleBasis:
        return ANGLE_BASES[self.basis]

    @property
    def names(self) -> tuple[str, ...]:
        """(A,) the angles' names (``wire.joint_angles(layout)``)."""
        return angle_names(self.layout)

    def to_json(self, subject: str) -> dict:
        """JSON-ready dict (the REST form): the layout by name, angles by name (null: no number),
        each flagged angle's flag names, the calibration by name and, where it gives no angles, why."""
        basis = self.calibration
        names = self.names
        return {"subject": subject, "seq": self.seq, "t": self.t_us / 1e6, "kind": kind_name(self.kind),
                "layout": "paper10" if self.layout is None else self.layout.name,
                "calibration": basis.name, "valid": basis.valid, "why": None if basis.valid else basis.meaning,
                "facing_deg": None if not math.isfinite(self.facing_deg) else round(float(self.facing_deg), 3),
                "angles": {name: None if not math.isfinite(v) else round(float(v), 3)
                           for name, v in zip(names, self.angles.tolist())},
                "flags": {name: [f for f, bit in ANGLE_FLAGS.items() if bits & bit]
                          for name, bits in zip(names, self.flags.tolist()) if bits}}


@dataclass(frozen=True)
class AngleFrames:
    """F joint-angle messages of one layout, columnar (what the aggregator makes per tick and
    layout, what a batch decodes to).

    Attributes: seq (F,), t_us (F,), kind (F,), basis (F,), facing_deg (F,), angles (F, A), flags
    (F, A), in the units of :class:`JointAngles`; layout (None: ``paper10``).
    """

    seq: np.ndarray
    t_us: np.ndarray
    kind: np.ndarray
    basis: np.ndarray
    facing_deg: np.ndarray
    angles: np.ndarray
    flags: np.ndarray
    layout: Layout | None = None

    def __len__(self) -> int:
        return len(self.t_us)

    def __getitem__(self, i: int) -> JointAngles:
        return JointAngles(int(self.seq[i]), int(self.t_us[i]), int(self.kind[i]), int(self.basis[i]),
                           float(self.facing_deg[i]), self.angles[i].astype(np.float32), self.flags[i].astype(np.uint8),
                           self.layout)

    def encode(self) -> list[bytes]:
        """One version-2 payload per message (built in one pass); ValueError if the angles are
        not the layout's count."""
        n = len(angle_names(self.layout))
        if np.shape(self.angles)[-1:] != (n,) and len(self):
            raise ValueError(f"{np.shape(self.angles)[-1]} angles for a layout of {n}")
        dtype = angles_dtype(n)
        rec = np.zeros(len(self), dtype)
        rec["version"], rec["n_angles"] = ANGLES_VERSION, n
        rec["layout"] = 0 if self.layout is None else layout_code(self.layout)
        rec["kind"], rec["basis"], rec["seq"], rec["t_us"] = self.kind, self.basis, self.seq, self.t_us
        rec["facing_deg"], rec["angles"], rec["flags"] = self.facing_deg, self.angles, self.flags
        buf = rec.tobytes()
        return [buf[i:i + dtype.itemsize] for i in range(0, len(buf), dtype.itemsize)]


def encode_angles(a: JointAngles) -> bytes:
    """JointAngles -> a version-2 payload (:func:`angles_dtype`: 119 bytes for ``paper10``)."""
    return AngleFrames(np.array([a.seq]), np.array([a.t_us]), np.array([a.kind]), np.array([a.basis]),
                       np.array([a.facing_deg]), np.asarray(a.angles)[None], np.asarray(a.flags)[None],
                       a.layout).encode()[0]


def _form(payload: bytes, layout: Layout | None) -> tuple[str, tuple]:
    """A payload's refusal reason ('' if none) and its form: (version, layout or None, dtype)."""
    if len(payload) < _COMMON_SIZE:  # shorter than the fields every version begins with: its first byte means nothing
        return "size", ()
    if payload[0] == ANGLES_VERSION_V1:
        if len(payload) != ANGLES_DTYPE_V1.itemsize:
            return "size", ()
        return ("" if payload[3] == len(JOINT_ANGLES) else "version"), (1, None, ANGLES_DTYPE_V1)
    if payload[0] != ANGLES_VERSION:
        return "version", ()
    if len(payload) < ANGLES_HEADER_SIZE or len(payload) != angles_dtype(payload[3]).itemsize:
        return "size", ()
    code = payload[20]
    if code == OTHER_LAYOUT:
        if layout is None:
            return "layout", ()
        found = layout
    elif code < len(LAYOUT_CODES):
        from limbstream.body import LAYOUTS  # (the body package is built on this one)
        found = LAYOUTS[LAYOUT_CODES[code]]
    else:
        return "layout", ()
    names = angle_names(None if code == 0 else found)
    if payload[3] != len(names):
        return "layout", ()
    return "", (2, None if code == 0 else found, angles_dtype(len(names)))


def decode_angles_many(payloads: list[bytes], layout: Layout | None = None) -> tuple[AngleFrames, list[str]]:
    """Payloads (version 2 or 1) -> (the messages that keep the contract, in order; (n,) the
    reason each payload was refused, '' for a good one): ``size`` (shorter than the 20 bytes every
    version begins with, or not its version's and layout's size), ``version`` (neither version,
    or a version-1 payload whose angle count is not ``paper10``'s),
    ``layout`` (an unknown layout code; a layout file's without ``layout``, the subject's layout,
    given; an angle count other than its layout's; or another layout than the batch's first good
    payload's: a batch decodes to one layout), ``value`` (an unknown kind, basis or flag bit; an
    angle without MISSING/UNCALIBRATED that is not finite, or one with them that is not NaN; a
    basis that gives no angles with an angle not flagged UNCALIBRATED, or one that does with one
    flagged so; an infinite facing)."""
    forms = [_form(bytes(p), layout) for p in payloads]
    first = next((form for reason, form in forms if not reason), (1, None, ANGLES_DTYPE_V1))
    reasons = [reason or ("" if form[1:] == first[1:] or (form[1] is None and first[1] is None) else "layout")
               for reason, form in forms]
    shaped = [(p, form) for p, r, (_, form) in zip(payloads, reasons, forms) if not r]
    rows = [np.frombuffer(bytes(p), form[2], 1) for p, form in shaped]
    n = len(angle_names(first[1]))
    rec = np.zeros(len(rows), angles_dtype(n))
    for name in _FIELDS:
        rec[name] = np.concatenate([r[name] for r in rows]) if rows else rec[name]
    flags, angles = rec["flags"], rec["angles"]
    number = (flags & _NO_NUMBER) == 0
    uncalibrated = (flags & ANGLE_UNCALIBRATED) != 0
    valid = _VALID[np.minimum(rec["basis"], len(ANGLE_BASES) - 1)]
    value = ((rec["kind"] > 1) | (rec["basis"] >= len(ANGLE_BASES)) | (flags & ~np.uint8(7)).any(axis=1)
             | (number & ~np.isfinite(angles)).any(axis=1) | (~number & ~np.isnan(angles)).any(axis=1)
             | np.where(valid, uncalibrated.any(axis=1), ~uncalibrated.all(axis=1)) | np.isinf(rec["facing_deg"]))
    it = iter(np.where(value, "value", "").tolist())
    reasons = [r or next(it) for r in reasons]
    good = rec[~value]
    return AngleFrames(good["seq"].astype(np.int64), good["t_us"].astype(np.int64), good["kind"].astype(np.int64),
                       good["basis"].astype(np.int64), good["facing_deg"].astype(np.float64), good["angles"].copy(),
                       good["flags"].copy(), first[1]), reasons


def decode_angles(payload: bytes, layout: Layout | None = None) -> JointAngles:
    """Bytes (version 2 or 1) -> JointAngles; WireError with reason size / version / layout /
    value (:func:`decode_angles_many`; ``layout``: the subject's, for a layout file's messages)."""
    frames, (reason,) = decode_angles_many([bytes(payload)], layout)
    if reason:
        raise WireError(reason, f"joint-angle message refused ({len(payload)} bytes): {_WHY[reason]}")
    return frames[0]


_WHY = {"size": f"expected {ANGLES_DTYPE_V1.itemsize} bytes (version {ANGLES_VERSION_V1}) or its layout's (version "
                f"{ANGLES_VERSION}: {ANGLES_HEADER_SIZE} + 5 per angle)",
        "version": f"not version {ANGLES_VERSION} or {ANGLES_VERSION_V1}",
        "layout": "an unknown layout, a layout file's without the subject's layout, or an angle count not its layout's",
        "value": "a kind, basis or flag unknown, or angles that do not match their flags and basis"}
