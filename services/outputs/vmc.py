"""VMC output: pose frames as the VMC protocol (OSC over UDP) for avatar apps (VSeeFace,
Warudo, VNyan, VirtualMotionCapture ...).

One OSC bundle per pose frame sent, to each subject's own ``host:port``:

- ``/VMC/Ext/Root/Pos "root" px py pz qx qy qz qw``: the avatar root, unrotated, on the floor under
  the frame's root (Unity frame; its height the root's less the Hips bone's rest height, so the
  Hips stand at the root): the body walking through the room; at the origin for a frame without a
  root (zeros, no contacts);
- ``/VMC/Ext/Bone/Pos name px py pz qx qy qz qw`` for each bone of the frame's layout's rig
  (:func:`rig`; ``paper10``: :data:`VMC_BONES`; ``full`` drives Chest, Head, the hands and the feet
  too): the bone's local position (m) and rotation relative to its parent bone, Unity frame;
- ``/VMC/Ext/OK 1 3 0 tracking``: loaded, calibrated, normal mode, tracking 1 (0 when the frame
  lacks a segment's data);
- ``/VMC/Ext/T t``: seconds of frame time since the subject's first frame sent.

Frames (docs/outputs.md, "VMC"): limbstream's frame is right-handed, Y up, X to the subject's
left, the subject facing +Z; Unity's is left-handed, Y up, X to the right, the avatar facing
+Z. The map is the mirror x -> -x: a position (x, y, z) becomes (-x, y, z) and a quaternion
(w, x, y, z) becomes (w, x, -y, -z) (conjugation by i, which keeps products, so local rotations
may be taken before or after it). VMC rotations are relative to a T-pose at identity; a
``standing`` rest pose (arms hanging at identity) is the T-pose with the arms lowered by
90 degrees about the forward axis, so each arm segment's orientation is multiplied on the right
by that rotation first.

The encoding is a template bundle per subject built once with python-osc; each frame only
writes each bone's rotation, the tracking int and the time into it.
"""
from __future__ import annotations

import functools
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder

from limbstream import quat, wire
from limbstream.body import FULL, PAPER10, Body, Layout, lengths_of
from limbstream.skeleton import Skeleton, joint_lengths, rest_offsets
from limbstream.services.outputs.kinds import LiveFirst
from limbstream.services.outputs.subscription import Subscription

_S = Skeleton()


@dataclass(frozen=True)
class VmcBone:
    """One bone sent.

    Attributes
    ----------
    name : Unity HumanBodyBones name.
    parent : parent bone's name ("" for the root).
    segment : the limbstream segment that drives it, or "" for a bone held at rest (its local
        rotation is identity: it moves with its parent).
    offset : (3,) rest position relative to the parent, metres, limbstream frame (T-pose).
    """

    name: str
    parent: str
    segment: str
    offset: tuple[float, float, float]


def _bones(sk: Skeleton = _S) -> tuple[VmcBone, ...]:
    """The bones sent, their offsets those of skeleton ``sk``."""
    spine, leg = sk.spine, sk.thigh + sk.shank
    bones = [
        VmcBone("Hips", "", "hip", (0.0, leg, 0.0)),
        VmcBone("Spine", "Hips", "", (0.0, spine / 4, 0.0)),
        VmcBone("Chest", "Spine", "", (0.0, spine / 4, 0.0)),
        VmcBone("Neck", "Chest", "neck", (0.0, spine / 2, 0.0)),
        VmcBone("Head", "Neck", "", (0.0, sk.neck, 0.0)),
    ]
    for side, s, x in (("Left", "l", 1.0), ("Right", "r", -1.0)):
        bones += [
            VmcBone(f"{side}UpperLeg", "Hips", f"{s}_thigh", (x * sk.hip_width / 2, 0.0, 0.0)),
            VmcBone(f"{side}LowerLeg", f"{side}UpperLeg", f"{s}_shank", (0.0, -sk.thigh, 0.0)),
            VmcBone(f"{side}Foot", f"{side}LowerLeg", "", (0.0, -sk.shank, 0.0)),
            VmcBone(f"{side}Shoulder", "Chest", "", (0.0, spine / 2 - 0.05, 0.0)),
            VmcBone(f"{side}UpperArm", f"{side}Shoulder", f"{s}_upperarm", (x * sk.shoulder_width / 2, 0.0, 0.0)),
            VmcBone(f"{side}LowerArm", f"{side}UpperArm", f"{s}_lowerarm", (x * sk.upperarm, 0.0, 0.0)),
            VmcBone(f"{side}Hand", f"{side}LowerArm", "", (x * sk.lowerarm, 0.0, 0.0)),
        ]
    return tuple(bones)


VMC_BONES: tuple[VmcBone, ...] = _bones()
"""The bones sent, parents first: the 10 measured ones (Hips, Neck, Left/Right UpperLeg,
LowerLeg, UpperArm, LowerArm) and those held at rest (Spine, Chest, Head, Left/Right Foot,
Shoulder, Hand). Not sent (receivers keep them at rest): UpperChest, toes, fingers, eyes, jaw."""


_MIRROR_Q = np.array([1.0, 1.0, -1.0, -1.0])
_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
_MIRROR_P = np.array([-1.0, 1.0, 1.0])
_PRODUCT = quat.multiply(np.eye(4)[:, None, :], np.eye(4)[None, :, :])
"""(4, 4, 4) structure constants: the Hamilton product a * b is sum_ij a_i b_j _PRODUCT[i, j]."""
_LOCAL = (_PRODUCT * quat.conjugate(np.ones(4))[:, None, None] * _MIRROR_Q).reshape(16, 4)
"""mirror(conj(a) * b) as one (16, 4) matrix applied to the outer product of a and b."""


HEAD_AT = 0.25
"""``full``'s Head bone sits this fraction of the head segment above the neck base (the skull's
base; the Neck bone, held, sits at the neck base)."""


def _full_bones(body: Body) -> tuple[VmcBone, ...]:
    """``full``'s bones, their offsets those of ``body`` in the T-pose: the trunk's, head's,
    hands' and feet's segments drive Chest, Head, the hands and the feet; Spine (halfway up the
    pelvis segment), Neck and the shoulders (at the neck base) are held."""
    lay = body.layout
    at = {j: p for j, p in zip(lay.joints, body.positions(np.tile(_IDENTITY, (len(lay.segments), 1)), True,
                                                           np.float64))}
    standing = body.positions(np.tile(_IDENTITY, (len(lay.segments), 1)), False, np.float64)
    half = (at["spine"] - at["pelvis"]) / 2

    def off(joint: str, parent: str) -> tuple[float, float, float]:
        return tuple(float(v) for v in at[joint] - at[parent])  # type: ignore[return-value]

    bones = [
        VmcBone("Hips", "", "hip", (0.0, float(at["pelvis"][1] - standing[:, 1].min()), 0.0)),
        VmcBone("Spine", "Hips", "", tuple(float(v) for v in half)),  # type: ignore[arg-type]
        VmcBone("Chest", "Spine", "chest", tuple(float(v) for v in half)),  # type: ignore[arg-type]
        VmcBone("Neck", "Chest", "", off("neck_base", "spine")),
        VmcBone("Head", "Neck", "head", tuple(float(v) for v in HEAD_AT * (at["head_top"] - at["neck_base"]))),  # type: ignore[arg-type]
    ]
    for side, s in (("Left", "l"), ("Right", "r")):
        bones += [
            VmcBone(f"{side}UpperLeg", "Hips", f"{s}_thigh", off(f"{s}_hip", "pelvis")),
            VmcBone(f"{side}LowerLeg", f"{side}UpperLeg", f"{s}_shank", off(f"{s}_knee", f"{s}_hip")),
            VmcBone(f"{side}Foot", f"{side}LowerLeg", f"{s}_foot", off(f"{s}_ankle", f"{s}_knee")),
            VmcBone(f"{side}Shoulder", "Chest", "", off("neck_base", "spine")),
            VmcBone(f"{side}UpperArm", f"{side}Shoulder", f"{s}_upperarm", off(f"{s}_shoulder", "neck_base")),
            VmcBone(f"{side}LowerArm", f"{side}UpperArm", f"{s}_lowerarm", off(f"{s}_elbow", f"{s}_shoulder")),
            VmcBone(f"{side}Hand", f"{side}LowerArm", f"{s}_hand", off(f"{s}_wrist", f"{s}_elbow")),
        ]
    return tuple(bones)


@dataclass(frozen=True)
class Rig:
    """The VMC bones of one layout and the rows of its global table (the layout's segments, then
    the identity row ``root``) that give each bone's and its parent's global orientation."""

    layout: Layout
    bones: tuple[VmcBone, ...]
    child_row: np.ndarray
    parent_row: np.ndarray

    @property
    def root(self) -> int:
        return len(self.layout.segments)


@functools.cache
def rig(layout: Layout) -> Rig:
    """The rig frames of ``layout`` drive: ``paper10``'s :data:`VMC_BONES`, ``full``'s
    (:func:`_full_bones`); ValueError for another layout."""
    if layout == PAPER10:
        bones = VMC_BONES
    elif layout == FULL:
        bones = _full_bones(Body.default(FULL))
    else:
        raise ValueError(f"VMC drives the layouts paper10 and full, not {layout.name}")
    seg, root = layout.segment_index, len(layout.segments)
    by_name = {b.name: b for b in bones}

    def driver(bone: VmcBone) -> int:  # its segment's row, or its nearest measured ancestor's
        while not bone.segment:
            if not bone.parent:
                return root
            bone = by_name[bone.parent]
        return seg[bone.segment]

    return Rig(layout, bones, np.array([driver(b) for b in bones]),
               np.array([driver(by_name[b.parent]) if b.parent else root for b in bones]))


def segment_rest_offsets(layout: Layout, rest_pose: str) -> np.ndarray:
    """(S, 4) rotation from the T-pose to ``rest_pose`` per segment of ``layout``: for a segment
    whose rest direction differs between them (the arms, the hands), the shortest turn from its
    ``tpose`` direction to its ``rest_pose`` one; ``paper10``: :func:`limbstream.skeleton.rest_offsets`."""
    if layout == PAPER10:
        return rest_offsets(rest_pose)
    wire.check_rest_pose(rest_pose)
    out = np.tile(_IDENTITY, (len(layout.segments), 1))
    for i, s in enumerate(layout.segments):
        a, b = np.array(s.directions["tpose"]), np.array(s.directions[rest_pose])
        if not np.allclose(a, b):
            half = (a + b) / np.linalg.norm(a + b)  # the turn a -> b: (a . h, a x h)
            out[i] = (float(a @ half), *np.cross(a, half))
    return out


@functools.cache
def _right_factor(rest_pose: str, layout: Layout = PAPER10) -> np.ndarray:
    """(S, 4, 4): q @ m[s] = q * segment_rest_offsets(layout, rest_pose)[s]."""
    return np.einsum("ijk,sj->sik", _PRODUCT, segment_rest_offsets(layout, rest_pose))


def local_rotations(q: np.ndarray, rest_pose: str = "standing", layout: Layout = PAPER10) -> np.ndarray:
    """Local bone rotations of ``layout``'s rig (:func:`rig`) in Unity's frame.

    Parameters
    ----------
    q : (..., S, 4) global segment orientations, scalar-first, limbstream frame (pose frames' q),
        ``layout``'s segments.
    rest_pose : the rest pose of ``q`` (:func:`segment_rest_offsets`).
    layout : the frames' layout (``paper10``: :data:`VMC_BONES`).

    Returns
    -------
    (..., B, 4) float64 scalar-first (w, x, y, z) in Unity's frame, B = len(rig(layout).bones):
    mirror(conj(g[parent]) * g[bone]) with g = normalize(q) * rest, held bones taking their nearest
    measured ancestor's g (identity for none). ValueError if a quaternion of ``q`` has zero norm
    or is not finite.
    """
    r = rig(layout)
    q = np.asarray(q, np.float64)
    norm = np.sqrt(np.einsum("...i,...i->...", q, q))
    if not np.all((norm > 0) & np.isfinite(norm)):
        raise ValueError("q contains zero-norm or non-finite quaternions")
    g = np.empty(q.shape[:-2] + (r.root + 1, 4))
    g[..., :r.root, :] = np.einsum("...si,sik->...sk", q / norm[..., None], _right_factor(rest_pose, layout))
    g[..., r.root, :] = (1.0, 0.0, 0.0, 0.0)
    a, b = g[..., r.parent_row, :], g[..., r.child_row, :]
    return (a[..., :, None] * b[..., None, :]).reshape(a.shape[:-1] + (16,)) @ _LOCAL


def rest_positions(skeleton: Skeleton | Body | None = None) -> np.ndarray:
    """(B, 3) local bone positions (m) in Unity's frame, in the order of its rig's bones, of
    ``skeleton`` (a ``paper10`` Skeleton, or a ``full`` Body; None: the default ``paper10`` one's)."""
    if isinstance(skeleton, Body):
        bones = _full_bones(skeleton)
    else:
        bones = VMC_BONES if skeleton is None else _bones(skeleton)
    return np.array([b.offset for b in bones]) * _MIRROR_P + 0.0  # + 0.0: no -0.0


SIZE_EVERY_US = 1_000_000
"""How often (frame time, us) an encoder reads the subject's bone lengths from its frames: a body
changes seldom (its devices' status, polled every 5 s), and reading it costs as much as a frame."""


class VmcEncoder:
    """One subject's VMC bundle, rebuilt per frame by writing numbers into a template.

    Parameters
    ----------
    rest_pose : override of the rest pose the frames carry in their flags (None: theirs).
    """

    def __init__(self, rest_pose: str | None = None):
        if rest_pose is not None:
            rest_offsets(rest_pose)  # ValueError on a bad name
        self.rest_pose = rest_pose
        self.t0_us: int | None = None
        self._build(PAPER10)

    def _build(self, layout: Layout) -> None:
        """The template of ``layout``'s rig, its bones at the default body's rest offsets."""
        self.rig = rig(layout)
        default = None if layout == PAPER10 else Body.default(layout)
        bundle = OscBundleBuilder(IMMEDIATELY)
        messages = [self._message("/VMC/Ext/Root/Pos", "root", [0.0] * 6 + [1.0])]
        for bone, p in zip(self.rig.bones, rest_positions(default)):
            messages.append(self._message("/VMC/Ext/Bone/Pos", bone.name, [*p, 0.0, 0.0, 0.0, 1.0]))
        ok = OscMessageBuilder("/VMC/Ext/OK")
        for v in (1, 3, 0, 1):
            ok.add_arg(v, "i")
        messages += [ok.build(), self._message("/VMC/Ext/T", None, [0.0])]
        ends, at = [], 16  # "#bundle\0" + time tag, then per element: int32 size + message
        for m in messages:
            bundle.add_content(m)
            at += 4 + len(m.dgram)
            ends.append(at)
        self.buffer = bytearray(bundle.build().dgram)
        if len(self.buffer) != ends[-1]:
            raise RuntimeError("OSC bundle layout differs from the one assumed")
        words = np.frombuffer(self.buffer, ">f4")  # OSC aligns everything to 4 bytes
        self._floats, self._ints = words, np.frombuffer(self.buffer, ">i4")
        bone_ends = np.array(ends[1:1 + len(self.rig.bones)]) // 4
        self._rot = bone_ends[:, None] - 4 + np.arange(4)  # qx qy qz qw: the last 4 words
        self._pos = bone_ends[:, None] - 7 + np.arange(3)  # x y z: the 3 words before them
        self._root = ends[0] // 4 - 7 + np.arange(3)  # the root message's px py pz
        self._lengths = self._lengths_of(layout, (_S if default is None else default).positions(
            np.tile(_IDENTITY, (len(layout.segments), 1))))  # the template's
        self._sized_us = -SIZE_EVERY_US  # frame time the bones were last sized at (:meth:`_size`)
        self._tracking = ends[-2] // 4 - 1
        self._time = ends[-1] // 4 - 1

    @staticmethod
    def _lengths_of(layout: Layout, joints: np.ndarray) -> np.ndarray:
        return joint_lengths(joints) if layout == PAPER10 else np.array(list(lengths_of(layout, joints).values()))

    def _size(self, joints: np.ndarray) -> None:
        """The bones' positions of the subject's body, as its frames draw it (``joints``: a
        frame's positions), written when its lengths change (by more than 0.1 mm); once per
        :data:`SIZE_EVERY_US` of frame time (and when frame time goes back)."""
        layout = self.rig.layout
        lengths = self._lengths_of(layout, joints)
        if np.all(np.abs(lengths - self._lengths) <= 1e-4) or not np.all((lengths > 0) & np.isfinite(lengths)):
            return
        self._lengths = lengths
        body = Skeleton.of_joints(joints) if layout == PAPER10 else Body(layout, lengths_of(layout, joints))
        self._floats[self._pos] = rest_positions(body)

    def _root_position(self, frame: wire.PoseFrame) -> np.ndarray:
        """(3,) m, Unity frame: where the avatar root goes for ``frame``'s root (x mirrored; the
        Hips bone's rest height below it, so the Hips land at the root); zeros without a root."""
        if not frame.has_root:
            return np.zeros(3)
        x, y, z = frame.root.astype(np.float64)
        return np.array([-x, y - self._floats[self._pos[0, 1]], z])

    @staticmethod
    def _message(address: str, name: str | None, floats: list[float]):
        m = OscMessageBuilder(address)
        if name is not None:
            m.add_arg(name, "s")
        for v in floats:
            m.add_arg(float(v), "f")
        return m.build()

    def encode(self, frame: wire.PoseFrame, local: np.ndarray | None = None) -> bytes:
        """The bundle of ``frame`` (about 1.6 kB for ``paper10``, its layout's rig's bones);
        ``local``: its :func:`local_rotations` if already computed. ValueError on a zero-norm
        quaternion or a layout without a rig."""
        layout = frame.layout or PAPER10
        if layout != self.rig.layout:
            self._build(layout)  # (ValueError: a layout without a rig)
        if local is None:
            local = local_rotations(frame.q, self.rest_pose or wire.frame_rest_pose(frame.flags), layout)
        if not 0 <= frame.t_us - self._sized_us < SIZE_EVERY_US:
            self._size(frame.joints)
            self._sized_us = frame.t_us
        self._floats[self._rot] = local[:, [1, 2, 3, 0]]
        self._floats[self._root] = self._root_position(frame)
        self._ints[self._tracking] = 0 if frame.flags & wire.FRAME_MISSING else 1
        if self.t0_us is None:
            self.t0_us = frame.t_us
        self._floats[self._time] = (frame.t_us - self.t0_us) / 1e6
        return bytes(self.buffer)


def parse_target(text: str) -> tuple[str, int]:
    """``host:port`` -> (IPv4 address, port); ValueError naming what is wrong."""
    host, sep, port = str(text).rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"expected HOST:PORT with a port in 1..65535, got {text!r}")
    try:
        address = socket.getaddrinfo(host, int(port), socket.AF_INET, socket.SOCK_DGRAM)[0][4]
    except (socket.gaierror, UnicodeError) as exc:
        raise ValueError(f"cannot resolve host {host!r}: {exc}") from None
    return address[0], address[1]


@dataclass
class VmcCounters:
    """What a :class:`VmcSender` did: bundles sent, frames refused (a quaternion of zero norm or
    not finite), send errors (e.g. ICMP port unreachable reported on a later send)."""

    sent: int = 0
    bad: int = 0
    send_errors: int = 0


class VmcSender:
    """Sends the pose frames of some subjects, each to its own UDP target, one bundle per frame
    of the kind :class:`~limbstream.services.outputs.kinds.LiveFirst` picks.

    Parameters
    ----------
    targets : subject -> (host, port).
    rest_pose : override of the rest pose the frames carry in their flags (None: theirs).
    """

    def __init__(self, targets: dict[str, tuple[str, int]], rest_pose: str | None = None):
        self.targets = dict(targets)
        self.rest_pose = rest_pose
        self.encoders = {s: VmcEncoder(rest_pose) for s in targets}
        self.kinds = LiveFirst()
        self.counters = VmcCounters()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def send(self, items: list[tuple[str, wire.PoseFrame]], now: float | None = None) -> int:
        """Send the frames of ``items`` (subject, frame) that are of the sender's subjects and of
        the kind shown; their rotations are computed in one vectorised call. Returns bundles sent."""
        todo = [(s, f) for s, f in items if s in self.encoders and self.kinds.wanted(s, f, now)]
        if not todo:
            return 0
        rest = [(self.rest_pose or wire.frame_rest_pose(f.flags), f.layout or PAPER10) for _, f in todo]
        local: list = [None] * len(todo)
        for pose, layout in set(rest):  # one vectorised call per rest pose and layout
            rows = [i for i, r in enumerate(rest) if r == (pose, layout)]
            try:
                for i, value in zip(rows, local_rotations(np.stack([todo[i][1].q for i in rows]), pose, layout)):
                    local[i] = value
            except ValueError:  # a bad frame among them: one by one, so only it is refused
                pass
        sent = 0
        for (subject, frame), rows in zip(todo, local):
            try:
                payload = self.encoders[subject].encode(frame, rows)
            except ValueError:
                self.counters.bad += 1
                continue
            try:
                self.sock.sendto(payload, self.targets[subject])
            except OSError:
                self.counters.send_errors += 1
                continue
            sent += 1
        self.counters.sent += sent
        return sent

    def close(self) -> None:
        self.sock.close()


def serve(sender: VmcSender, subscriptions: list[Subscription], stop: threading.Event,
          wait_s: float = 0.0, period_s: float = 0.01) -> str | None:
    """Send every pose frame the subscriptions bring until ``stop`` is set.

    Parameters
    ----------
    sender : the subjects and their targets.
    subscriptions : one pose subscription per subject of ``sender``.
    stop : set to end.
    wait_s : a subject without any pose frame after this many seconds is an error (0: wait forever).
    period_s : how often the channels are drained, seconds.

    Returns
    -------
    None when stopped, or the first subject that sent no frame within ``wait_s``.
    """
    start = time.monotonic()
    seen: set[str] = set()
    while not stop.wait(period_s):
        items = [(item.subject, item.value) for sub in subscriptions for item in sub.drain()]
        seen.update(s for s, _ in items)
        sender.send(items)
        if wait_s and len(seen) < len(sender.targets) and time.monotonic() - start > wait_s:
            return next(s for s in sender.targets if s not in seen)
    return None
