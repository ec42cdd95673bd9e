"""Pose frames: one full-body frame of a subject, in the subject's body layout (little-endian).

Version 2 (what the aggregator publishes): a 32-byte header, then the layout's segment orientations
and joint positions: 372 bytes for ``paper10``, 512 for ``full``. Version 1 (356 bytes, ``paper10``
only, no root or contacts) is still read: recordings made before hold it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .errors import WireError
from .keys import POSE

if TYPE_CHECKING:
    from limbstream.body import Layout

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
FRAME_NO_ROOT = 0x08
"""Pose frame flag: root translation off: the layout has no feet (the root stays at the origin)."""
FRAME_OFF_FEET = 0x10
"""Pose frame flag: no foot is the lowest point (a fall, a lie-down): the root follows the lowest joint."""

POSE_VERSION = 2
"""The pose frame version published: a body layout's frames, with the root position and foot contacts."""
POSE_VERSION_V1 = 1
"""The first pose frame version (356 bytes, ``paper10`` only): read, no longer published."""
LAYOUT_CODES: tuple[str, ...] = ("paper10", "full")
"""Byte 16 of a version-2 frame: the index of its built-in layout here; :data:`OTHER_LAYOUT` for
a layout file's (a reader passes that layout to :func:`decode_pose`: the subject's devices name
it in their status)."""
OTHER_LAYOUT = 255
CONTACTS: tuple[str, ...] = ("l_heel", "l_toe", "r_heel", "r_toe")
"""Byte 18 of a version-2 frame: bit i set when foot point ``CONTACTS[i]`` is planted on the floor
(all clear: not known, or no foot planted)."""
HEADER_SIZE = 32
"""Bytes before a version-2 frame's orientations."""
_V1_HEADER_SIZE = 16  # the fields every version begins with

_HEADER = [("version", "u1"), ("kind", "u1"), ("flags", "u1"), ("n_segments", "u1"), ("seq", "<u4"), ("t_us", "<i8")]


def pose_dtype(n_segments: int, n_joints: int) -> np.dtype:
    """Layout of a version-2 pose frame payload of ``n_segments`` segments and ``n_joints`` joints:
    the header (u8 version, u8 kind, u8 flags, u8 n_segments, u32 seq, i64 t_us, u8 layout, u8
    n_joints, u8 contacts, u8 reserved 0, 3 f32 root), then S x 4 f32 and J x 3 f32."""
    return np.dtype(_HEADER + [("layout", "u1"), ("n_joints", "u1"), ("contacts", "u1"), ("reserved", "u1"),
                               ("root", "<f4", (3,)), ("q", "<f4", (n_segments, 4)), ("joints", "<f4", (n_joints, 3))])


POSE_DTYPE_V1 = np.dtype(_HEADER + [("q", "<f4", (10, 4)), ("joints", "<f4", (15, 3))])
"""Layout of a version-1 pose frame payload (356 bytes, ``paper10``)."""
POSE_DTYPE = pose_dtype(10, 15)
"""Layout of a ``paper10`` pose frame payload (372 bytes); the kind byte sits at offset 1 in every version."""


def kind_name(kind: int) -> str:
    """The name of pose frame kind ``kind`` (:data:`FRAME_KINDS`)."""
    return "live" if kind == KIND_LIVE else "exact"


def pose_stream(kind: int) -> str:
    """``pose_exact`` / ``pose_live``: the pose stream of frames of ``kind`` (their publisher
    options, their sequence numbering)."""
    return f"{POSE}_{kind_name(kind)}"


AUTO_LIVE_WINDOW_S = 1.0
"""The one frame-kind rule (``kind=auto``: the dashboard's pose streams, Foxglove, VMC): a
subject's live frames while one of them came within this many seconds, else its exact frames.
Live frames are current (exact frames are final but about 0.4 s late); exact frames stand in for
a subject whose aggregator publishes no live frames (``--live-rate 0``) or stopped."""


def auto_kind(since_live_s: float) -> int:
    """The kind ``kind=auto`` shows, seconds after a subject's newest live frame (inf: none yet)."""
    return KIND_LIVE if since_live_s < AUTO_LIVE_WINDOW_S else KIND_EXACT


def frame_rest_pose(flags: int) -> str:
    """The rest pose a pose frame's orientations refer to, from its flags."""
    return "tpose" if flags & FRAME_TPOSE else "standing"


def rest_pose_flag(rest_pose: str) -> int:
    """The pose-frame flag bits of ``rest_pose``."""
    return FRAME_TPOSE if rest_pose == "tpose" else 0


def contact_names(contacts: int) -> list[str]:
    """The planted foot points of a frame's contact bits (:data:`CONTACTS`)."""
    return [name for i, name in enumerate(CONTACTS) if contacts >> i & 1]


def _paper10() -> Layout:
    from limbstream.body import PAPER10  # the body package is built on the wire package
    return PAPER10


def _builtin(code: int) -> Layout:
    from limbstream.body import LAYOUTS
    return LAYOUTS[LAYOUT_CODES[code]]


def layout_code(layout: Layout) -> int:
    """Byte 16 of a frame of ``layout``: its index in :data:`LAYOUT_CODES` if it is that built-in
    layout, else :data:`OTHER_LAYOUT`."""
    if layout.name in LAYOUT_CODES and _builtin(LAYOUT_CODES.index(layout.name)) == layout:
        return LAYOUT_CODES.index(layout.name)
    return OTHER_LAYOUT


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
        :data:`FRAME_GAP`, :data:`FRAME_MISSING`, :data:`FRAME_TPOSE`, :data:`FRAME_NO_ROOT`,
        :data:`FRAME_OFF_FEET`.
    q : (S, 4) float32
        Segment orientations in ``layout.segment_names`` order.
    joints : (J, 3) float32
        Joint positions, metres, in ``layout.joints`` order (world frame, Y up).
    layout : limbstream.body.Layout
        The subject's body layout (None: ``paper10``).
    root : (3,) float32
        The root (pelvis) position, metres, world frame, Y up (zeros: not tracked; :data:`FRAME_NO_ROOT`:
        the layout has no feet to track it by).
    contacts : int
        Planted foot points, bits of :data:`CONTACTS`.
    """

    seq: int
    t_us: int
    kind: int
    flags: int
    q: np.ndarray
    joints: np.ndarray = None  # type: ignore[assignment]  # None: zeros of the layout's joints
    layout: Layout | None = None
    root: np.ndarray = field(default_factory=lambda: np.zeros(3, np.float32))
    contacts: int = 0

    def __post_init__(self):
        if self.layout is None:
            object.__setattr__(self, "layout", _paper10())
        if self.joints is None:
            object.__setattr__(self, "joints", np.zeros((len(self.layout.joints), 3), np.float32))

    @property
    def has_root(self) -> bool:
        """Whether the frame carries a root position (non-zero, or contacts set): else the body was
        not tracked through the room (a layout without feet: :data:`FRAME_NO_ROOT`, a frame before
        root tracking, a version-1 frame)."""
        return not self.flags & FRAME_NO_ROOT and (bool(self.contacts) or bool(np.any(self.root)))

    def to_json(self, subject: str) -> dict:
        """JSON-ready dict (the WebSocket / SSE / REST form)."""
        layout = self.layout
        assert layout is not None
        return {
            "subject": subject,
            "seq": self.seq,
            "t": self.t_us / 1e6,
            "kind": kind_name(self.kind),
            "gap": bool(self.flags & FRAME_GAP),
            "missing": bool(self.flags & FRAME_MISSING),
            "rest_pose": frame_rest_pose(self.flags),
            "no_root": bool(self.flags & FRAME_NO_ROOT),
            "off_feet": bool(self.flags & FRAME_OFF_FEET),
            "layout": layout.name,
            "segments": {s: [round(float(v), 6) for v in self.q[i]] for i, s in enumerate(layout.segment_names)},
            "joints": {j: [round(float(v), 4) for v in self.joints[i]] for i, j in enumerate(layout.joints)},
            "root": [round(float(v), 4) for v in self.root],
            "contacts": contact_names(self.contacts),
        }


@dataclass(frozen=True)
class PoseFrames:
    """F pose frames of one kind and one layout, columnar (what the aggregator builds per tick).

    Attributes: seq (F,) int, t_us (F,) int, kind, flags (F,) int, q (F, S, 4), joints (F, J, 3),
    layout (None: ``paper10``), root (F, 3) (None: zeros), contacts (F,) int (None: zeros), in the
    units of :class:`PoseFrame`.
    """

    seq: np.ndarray
    t_us: np.ndarray
    kind: int
    flags: np.ndarray
    q: np.ndarray
    joints: np.ndarray
    layout: Layout | None = None
    root: np.ndarray | None = None
    contacts: np.ndarray | None = None

    def __post_init__(self):
        if self.layout is None:
            object.__setattr__(self, "layout", _paper10())
        if self.root is None:
            object.__setattr__(self, "root", np.zeros((len(self.t_us), 3)))
        if self.contacts is None:
            object.__setattr__(self, "contacts", np.zeros(len(self.t_us), np.int64))

    @classmethod
    def empty(cls, kind: int, layout: Layout | None = None) -> PoseFrames:
        layout = layout or _paper10()
        return cls(np.zeros(0, np.int64), np.zeros(0, np.int64), kind, np.zeros(0, np.int64),
                   np.zeros((0, len(layout.segments), 4)), np.zeros((0, len(layout.joints), 3)), layout)

    def __len__(self) -> int:
        return len(self.t_us)

    def __getitem__(self, i: int) -> PoseFrame:
        assert self.root is not None and self.contacts is not None
        return PoseFrame(int(self.seq[i]), int(self.t_us[i]), self.kind, int(self.flags[i]),
                         self.q[i].astype(np.float32), self.joints[i].astype(np.float32), self.layout,
                         self.root[i].astype(np.float32), int(self.contacts[i]))

    def rows(self, index: np.ndarray) -> PoseFrames:
        """The frames ``index`` (K,) of these, in that order."""
        assert self.root is not None and self.contacts is not None
        return PoseFrames(self.seq[index], self.t_us[index], self.kind, self.flags[index], self.q[index],
                          self.joints[index], self.layout, self.root[index], self.contacts[index])

    def encode(self) -> list[bytes]:
        """One payload per frame, as :func:`encode_pose` (built in one pass)."""
        layout = self.layout
        assert layout is not None
        dtype = pose_dtype(len(layout.segments), len(layout.joints))
        rec = np.zeros(len(self), dtype)
        rec["version"], rec["kind"], rec["n_segments"] = POSE_VERSION, self.kind, len(layout.segments)
        rec["layout"], rec["n_joints"] = layout_code(layout), len(layout.joints)
        rec["flags"], rec["seq"], rec["t_us"] = self.flags, self.seq, self.t_us
        rec["contacts"], rec["root"] = self.contacts, self.root
        rec["q"], rec["joints"] = self.q, self.joints
        buf, size = rec.tobytes(), dtype.itemsize
        return [buf[i:i + size] for i in range(0, len(buf), size)]


def encode_pose(frame: PoseFrame) -> bytes:
    """PoseFrame -> bytes (:func:`pose_dtype`, version 2): the 32-byte header, S x 4 f32
    quaternions, J x 3 f32 joint positions (372 bytes for ``paper10``, 512 for ``full``)."""
    return PoseFrames(np.array([frame.seq]), np.array([frame.t_us]), frame.kind, np.array([frame.flags]),
                      np.asarray(frame.q)[None], np.asarray(frame.joints)[None], frame.layout,
                      np.asarray(frame.root)[None], np.array([frame.contacts])).encode()[0]


def _frame_layout(code: int, n_segments: int, n_joints: int, layout: Layout | None) -> Layout:
    if code == OTHER_LAYOUT:
        if layout is None:
            raise WireError("layout", "pose frame of a layout file's layout: pass the subject's layout to read it")
        found = layout
    elif code < len(LAYOUT_CODES):
        found = _builtin(code)
    else:
        raise WireError("layout", f"pose frame layout code {code}, expected 0-{len(LAYOUT_CODES) - 1} or {OTHER_LAYOUT}")
    if (len(found.segments), len(found.joints)) != (n_segments, n_joints):
        raise WireError("layout", f"pose frame has {n_segments} segments and {n_joints} joints; layout {found.name} "
                                  f"has {len(found.segments)} and {len(found.joints)}")
    return found


def decode_pose(payload: bytes, layout: Layout | None = None) -> PoseFrame:
    """Bytes -> PoseFrame, version 2 or 1; WireError with reason size, version or layout.
    ``layout``: the layout of frames whose layout byte is :data:`OTHER_LAYOUT` (a layout file's)."""
    if len(payload) < _V1_HEADER_SIZE:
        raise WireError("size", f"pose frame has {len(payload)} bytes, shorter than any header")
    version = payload[0]
    if version == POSE_VERSION_V1:
        if len(payload) != POSE_DTYPE_V1.itemsize:
            raise WireError("size", f"pose frame v1 has {len(payload)} bytes, expected {POSE_DTYPE_V1.itemsize}")
        rec = np.frombuffer(payload, POSE_DTYPE_V1, 1)[0]
        if rec["n_segments"] != 10:
            raise WireError("version", f"pose frame version 1 with {rec['n_segments']} segments")
        return PoseFrame(int(rec["seq"]), int(rec["t_us"]), int(rec["kind"]), int(rec["flags"]),
                         rec["q"].copy(), rec["joints"].copy())
    if version != POSE_VERSION:
        raise WireError("version", f"pose frame version {version}, expected {POSE_VERSION} (or {POSE_VERSION_V1})")
    if len(payload) < HEADER_SIZE:
        raise WireError("size", f"pose frame has {len(payload)} bytes, shorter than its {HEADER_SIZE}-byte header")
    n_segments, n_joints = payload[3], payload[17]
    dtype = pose_dtype(n_segments, n_joints)
    if len(payload) != dtype.itemsize:
        raise WireError("size", f"pose frame has {len(payload)} bytes, expected {dtype.itemsize} for "
                                f"{n_segments} segments and {n_joints} joints")
    rec = np.frombuffer(payload, dtype, 1)[0]
    found = _frame_layout(int(rec["layout"]), n_segments, n_joints, layout)
    return PoseFrame(int(rec["seq"]), int(rec["t_us"]), int(rec["kind"]), int(rec["flags"]), rec["q"].copy(),
                     rec["joints"].copy(), found, rec["root"].copy(), int(rec["contacts"]))
