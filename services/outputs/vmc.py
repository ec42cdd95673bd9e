"""VMC output: pose frames as the VMC protocol (OSC over UDP) for avatar apps (VSeeFace,
Warudo, VNyan, VirtualMotionCapture ...).

One OSC bundle per pose frame sent, to each subject's own ``host:port``:

- ``/VMC/Ext/Root/Pos "root" px py pz qx qy qz qw``: the avatar root, at the origin, unrotated;
- ``/VMC/Ext/Bone/Pos name px py pz qx qy qz qw`` for each bone of :data:`VMC_BONES`: the
  bone's local position (m) and rotation relative to its parent bone, Unity frame;
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
from limbstream.skeleton import Skeleton, joint_lengths, rest_offsets
from limbstream.services.outputs.kinds import LiveFirst
from limbstream.services.outputs.subscription import Subscription

_SEG = {name: i for i, name in enumerate(wire.SEGMENTS)}
_ROOT = len(wire.SEGMENTS)  # index of the identity row (the avatar root) in the global table
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


def _driver(bone: VmcBone) -> int:
    """Row of the global table that gives ``bone``'s global orientation: its segment's, or for a
    bone held at rest its nearest measured ancestor's (the root row for none)."""
    by_name = {b.name: b for b in VMC_BONES}
    while not bone.segment:
        if not bone.parent:
            return _ROOT
        bone = by_name[bone.parent]
    return _SEG[bone.segment]


_BY_NAME = {b.name: b for b in VMC_BONES}
_CHILD_ROW = np.array([_driver(b) for b in VMC_BONES])
_PARENT_ROW = np.array([_driver(_BY_NAME[b.parent]) if b.parent else _ROOT for b in VMC_BONES])
_MIRROR_Q = np.array([1.0, 1.0, -1.0, -1.0])
_MIRROR_P = np.array([-1.0, 1.0, 1.0])
_PRODUCT = quat.multiply(np.eye(4)[:, None, :], np.eye(4)[None, :, :])
"""(4, 4, 4) structure constants: the Hamilton product a * b is sum_ij a_i b_j _PRODUCT[i, j]."""
_LOCAL = (_PRODUCT * quat.conjugate(np.ones(4))[:, None, None] * _MIRROR_Q).reshape(16, 4)
"""mirror(conj(a) * b) as one (16, 4) matrix applied to the outer product of a and b."""


@functools.cache
def _right_factor(rest_pose: str) -> np.ndarray:
    """(10, 4, 4): q @ m[s] = q * rest_offsets(rest_pose)[s]."""
    return np.einsum("ijk,sj->sik", _PRODUCT, rest_offsets(rest_pose))


def local_rotations(q: np.ndarray, rest_pose: str = "standing") -> np.ndarray:
    """Local bone rotations of :data:`VMC_BONES` in Unity's frame.

    Parameters
    ----------
    q : (..., 10, 4) global segment orientations, scalar-first, limbstream frame (pose frames' q).
    rest_pose : the rest pose of ``q`` (:func:`rest_offsets`).

    Returns
    -------
    (..., B, 4) float64 scalar-first (w, x, y, z) in Unity's frame, B = len(VMC_BONES):
    mirror(conj(g[parent]) * g[bone]) with g = normalize(q) * rest, held bones taking their nearest
    measured ancestor's g (identity for none). ValueError if a quaternion of ``q`` has zero norm
    or is not finite.
    """
    q = np.asarray(q, np.float64)
    norm = np.sqrt(np.einsum("...i,...i->...", q, q))
    if not np.all((norm > 0) & np.isfinite(norm)):
        raise ValueError("q contains zero-norm or non-finite quaternions")
    g = np.empty(q.shape[:-2] + (_ROOT + 1, 4))
    g[..., :_ROOT, :] = np.einsum("...si,sik->...sk", q / norm[..., None], _right_factor(rest_pose))
    g[..., _ROOT, :] = (1.0, 0.0, 0.0, 0.0)
    a, b = g[..., _PARENT_ROW, :], g[..., _CHILD_ROW, :]
    return (a[..., :, None] * b[..., None, :]).reshape(a.shape[:-1] + (16,)) @ _LOCAL


def rest_positions(skeleton: Skeleton | None = None) -> np.ndarray:
    """(B, 3) local bone positions (m) in Unity's frame, :data:`VMC_BONES` order, of ``skeleton``
    (None: the default one's)."""
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
        bundle = OscBundleBuilder(IMMEDIATELY)
        messages = [self._message("/VMC/Ext/Root/Pos", "root", [0.0] * 6 + [1.0])]
        for bone, p in zip(VMC_BONES, rest_positions()):
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
        bone_ends = np.array(ends[1:1 + len(VMC_BONES)]) // 4
        self._rot = bone_ends[:, None] - 4 + np.arange(4)  # qx qy qz qw: the last 4 words
        self._pos = bone_ends[:, None] - 7 + np.arange(3)  # x y z: the 3 words before them
        self._lengths = joint_lengths(_S.positions(np.tile([1.0, 0.0, 0.0, 0.0], (_ROOT, 1))))  # the template's
        self._sized_us = -SIZE_EVERY_US  # frame time the bones were last sized at (:meth:`_size`)
        self._tracking = ends[-2] // 4 - 1
        self._time = ends[-1] // 4 - 1
        self.t0_us: int | None = None

    def _size(self, joints: np.ndarray) -> None:
        """The bones' positions of the subject's body, as its frames draw it (``joints``: a
        frame's positions), written when its lengths change (by more than 0.1 mm); once per
        :data:`SIZE_EVERY_US` of frame time (and when frame time goes back)."""
        lengths = joint_lengths(joints)
        if np.all(np.abs(lengths - self._lengths) <= 1e-4) or not np.all((lengths > 0) & np.isfinite(lengths)):
            return
        self._lengths = lengths
        self._floats[self._pos] = rest_positions(Skeleton.of_joints(joints))

    @staticmethod
    def _message(address: str, name: str | None, floats: list[float]):
        m = OscMessageBuilder(address)
        if name is not None:
            m.add_arg(name, "s")
        for v in floats:
            m.add_arg(float(v), "f")
        return m.build()

    def encode(self, frame: wire.PoseFrame, local: np.ndarray | None = None) -> bytes:
        """The bundle of ``frame`` (about 1.6 kB); ``local``: its :func:`local_rotations` if
        already computed. ValueError on a zero-norm quaternion."""
        if local is None:
            local = local_rotations(frame.q, self.rest_pose or wire.frame_rest_pose(frame.flags))
        if not 0 <= frame.t_us - self._sized_us < SIZE_EVERY_US:
            self._size(frame.joints)
            self._sized_us = frame.t_us
        self._floats[self._rot] = local[:, [1, 2, 3, 0]]
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
        rest = [self.rest_pose or wire.frame_rest_pose(f.flags) for _, f in todo]
        local: list = [None] * len(todo)
        for pose in set(rest):  # one vectorised call per rest pose
            rows = [i for i, r in enumerate(rest) if r == pose]
            try:
                for i, value in zip(rows, local_rotations(np.stack([todo[i][1].q for i in rows]), pose)):
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
