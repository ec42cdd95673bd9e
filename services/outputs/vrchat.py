"""VRChat output: pose frames as VRChat's OSC trackers (OSC over UDP, VRChat listens on port 9000).

Per pose frame sent, one OSC message (3 floats) per address, in this order:
``/tracking/trackers/N/position`` and ``/tracking/trackers/N/rotation`` for each tracker of the
frame's layout (:func:`trackers`: ``paper10``'s :data:`TRACKERS`, ``full``'s :data:`FULL_TRACKERS`;
N = 1..8), then ``/tracking/trackers/head/position`` and ``/rotation``.

Convention (docs.vrchat.com "OSC Trackers", docs/outputs.md "VRChat"): world positions in metres
and Euler angles in degrees, Unity's left-handed frame (Y up, X to the right, facing +Z), the
angles in Unity's order (z about Z, then x about X, then y about Y: :func:`quat.unity_euler_deg`).
limbstream's frame (right-handed, Y up, X to the subject's left, facing +Z) becomes Unity's by
the mirror x -> -x, as in :mod:`limbstream.services.outputs.vmc`: a position (x, y, z) becomes
(-x, y, z), a quaternion (w, x, y, z) becomes (w, x, -y, -z) (:func:`quat.mirror_x`).

Positions are world positions: the frame's joints (pelvis at the origin) plus its root (the body
walking through the room, the floor at y = 0). A frame without a root (zeros, no contacts: not
tracked, recorded before) has its joints lifted instead so that the lowest foot point (the lower
ankle; with feet, the lower of the ankles and toes) is on the floor, the pelvis at standing height.
"""
from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from pythonosc.osc_message_builder import OscMessageBuilder

from limbstream import quat, wire
from limbstream.body import FULL, PAPER10, Layout
from limbstream.services.outputs.kinds import LiveFirst
from limbstream.services.outputs.subscription import Subscription
from limbstream.services.outputs.vmc import parse_target

__all__ = ["FULL_TRACKERS", "TRACKERS", "VrchatSender", "parse_target", "serve", "tracker_values", "trackers"]


@dataclass(frozen=True)
class Tracker:
    """One OSC tracker: ``address`` is ``/tracking/trackers/<address>/...``; its position is the
    joint ``joint`` (or ``share`` of the way from ``joint`` to ``toward``); its rotation is the
    global orientation of ``segment``."""

    address: str
    name: str
    joint: str
    segment: str
    toward: str = ""
    share: float = 0.0


TRACKERS: tuple[Tracker, ...] = (
    Tracker("1", "hip", "pelvis", "hip"),
    Tracker("2", "chest", "pelvis", "hip", toward="neck_base", share=2 / 3),
    Tracker("3", "left foot", "l_ankle", "l_shank"),
    Tracker("4", "right foot", "r_ankle", "r_shank"),
    Tracker("5", "left knee", "l_knee", "l_thigh"),
    Tracker("6", "right knee", "r_knee", "r_thigh"),
    Tracker("7", "left elbow", "l_elbow", "l_upperarm"),
    Tracker("8", "right elbow", "r_elbow", "r_upperarm"),
    Tracker("head", "head", "head", "neck"),
)
"""The trackers sent, in order. The chest has no sensor of its own: the trunk follows the pelvis
segment (``hip``: pelvis -> neck base), so the chest tracker sits two thirds of the way up it
with its orientation."""

FULL_TRACKERS: tuple[Tracker, ...] = (
    Tracker("1", "hip", "pelvis", "hip"),
    Tracker("2", "chest", "spine", "chest", toward="neck_base", share=1 / 2),
    Tracker("3", "left foot", "l_ankle", "l_foot"),
    Tracker("4", "right foot", "r_ankle", "r_foot"),
    Tracker("5", "left knee", "l_knee", "l_thigh"),
    Tracker("6", "right knee", "r_knee", "r_thigh"),
    Tracker("7", "left elbow", "l_elbow", "l_upperarm"),
    Tracker("8", "right elbow", "r_elbow", "r_upperarm"),
    Tracker("head", "head", "head_top", "head"),
)
"""``full``'s trackers: the chest and the feet have segments of their own, so the chest tracker
has the chest's orientation, halfway up it (spine joint to neck base), and each foot tracker, at
the ankle (VRChat's foot target), the foot's orientation; the head tracker the head's."""
_MIRROR_P = np.array([-1.0, 1.0, 1.0])
_FOOT_POINTS = ("l_ankle", "r_ankle", "l_toe", "r_toe")
ADDRESSES: tuple[str, ...] = tuple(f"/tracking/trackers/{t.address}/{what}"
                                   for t in TRACKERS for what in ("position", "rotation"))
"""Every address sent, in the order sent per frame (the same for every layout)."""


def trackers(layout: Layout) -> tuple[Tracker, ...]:
    """The trackers of frames of ``layout``: ``full``'s :data:`FULL_TRACKERS`, ``paper10``'s
    :data:`TRACKERS`; ValueError for another layout."""
    if layout == FULL:
        return FULL_TRACKERS
    if layout == PAPER10:
        return TRACKERS
    raise ValueError(f"VRChat's trackers are placed on the layouts paper10 and full, not {layout.name}")


@lru_cache(maxsize=8)
def _table(layout: Layout) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """(T,) segment rows of the trackers' rotations, (T, J) weights of the joints placing them,
    the rows of the foot points (the lowest goes on the floor)."""
    chosen, j, s = trackers(layout), layout.joint_index, layout.segment_index
    mix = np.zeros((len(chosen), len(layout.joints)))
    for k, t in enumerate(chosen):
        mix[k, j[t.joint]] += 1.0 - t.share
        if t.toward:
            mix[k, j[t.toward]] += t.share
    return np.array([s[t.segment] for t in chosen]), mix, [j[p] for p in _FOOT_POINTS if p in j]


def tracker_values(frame: wire.PoseFrame) -> tuple[np.ndarray, np.ndarray]:
    """The trackers of ``frame`` in VRChat's convention.

    Parameters
    ----------
    frame : a pose frame (q (S, 4) scalar-first, joints (J, 3) m, pelvis at the origin, root (3,)
        m) of ``paper10`` or ``full``.

    Returns
    -------
    positions (T, 3) metres and rotations (T, 3) Unity Euler angles in degrees (x, y, z), Unity's
    frame, in the order of the layout's :func:`trackers`: world positions (joints + root) or, for a
    frame without a root, the joints lifted so the lowest foot point is at y = 0. ValueError on a zero-norm or non-finite quaternion, non-finite joints or a
    layout without trackers.
    """
    rows, mix, feet = _table(frame.layout or PAPER10)
    joints = np.asarray(frame.joints, np.float64)
    if not np.all(np.isfinite(joints)):
        raise ValueError("joints are not finite")
    root = np.asarray(frame.root, np.float64) if frame.has_root else np.array([0.0, -joints[feet, 1].min(), 0.0])
    if not np.all(np.isfinite(root)):
        raise ValueError("root is not finite")
    positions = mix @ (joints + root) * _MIRROR_P + 0.0  # + 0.0: no -0.0
    rotations = quat.unity_euler_deg(quat.mirror_x(quat.normalize(frame.q)[rows])) + 0.0
    return positions, rotations


def _message(address: str, values) -> bytes:
    m = OscMessageBuilder(address)
    for v in values:
        m.add_arg(float(v), "f")
    return m.build().dgram


@dataclass
class VrchatCounters:
    """What a :class:`VrchatSender` did: frames sent, frames refused (a quaternion of zero norm
    or not finite), send errors (e.g. ICMP port unreachable reported on a later send)."""

    sent: int = 0
    bad: int = 0
    send_errors: int = 0


class VrchatSender:
    """Sends one subject's pose frames (of the kind
    :class:`~limbstream.services.outputs.kinds.LiveFirst` picks) as OSC tracker messages to
    ``target`` (host, port)."""

    def __init__(self, subject: str, target: tuple[str, int]):
        self.subject = subject
        self.target = target
        self.kinds = LiveFirst()
        self.counters = VrchatCounters()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def send(self, frame: wire.PoseFrame, now: float | None = None) -> bool:
        """Send ``frame`` if it is of the kind shown; True if sent. A frame lacking a segment's
        data (``FRAME_MISSING``) is sent as it is (its segments hold their last orientation)."""
        if not self.kinds.wanted(self.subject, frame, now):
            return False
        try:
            positions, rotations = tracker_values(frame)
        except ValueError:
            self.counters.bad += 1
            return False
        for k, t in enumerate(TRACKERS):
            for what, values in (("position", positions[k]), ("rotation", rotations[k])):
                try:
                    self.sock.sendto(_message(f"/tracking/trackers/{t.address}/{what}", values), self.target)
                except OSError:
                    self.counters.send_errors += 1
        self.counters.sent += 1
        return True

    def close(self) -> None:
        self.sock.close()


def serve(sender: VrchatSender, subscription: Subscription, stop: threading.Event,
          wait_s: float = 0.0, period_s: float = 0.01) -> bool:
    """Send every pose frame ``subscription`` brings until ``stop`` is set.

    Parameters
    ----------
    wait_s : no pose frame after this many seconds is an error (0: wait forever).
    period_s : how often the channel is drained, seconds.

    Returns
    -------
    True when stopped, False when no frame came within ``wait_s``.
    """
    start = time.monotonic()
    seen = False
    while not stop.wait(period_s):
        for item in subscription.drain():
            seen = True
            sender.send(item.value)
        if wait_s and not seen and time.monotonic() - start > wait_s:
            return False
    return True
