"""The emulator's per-tick computations as they were before they were batched (commit ded8972),
kept as the plain reference that tests/test_emulator_equality.py runs beside the package's on the
same input; never imported by the package.

- :func:`orientations`: the built-in generator's segment orientations, one elementary rotation and
  one chain of products at a time (``GeneratorSource.orientations``).
- :class:`ReferenceEmulator`: the emulator with its feeds sampled one by one each tick
  (``Feed.sample``) and its truth tap taken from the ring and encoded device by device.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream import quat, wire
from limbstream.device_emulator.emulator import Emulator
from limbstream.sources import SEGMENTS
from limbstream.sources.generator import GeneratorSource

_X, _Y, _Z = np.eye(3)


def _elementary(angle_deg: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(n, 4) rotations by (n,) angles (|angle| < 180) about one axis; continuous in the angle."""
    return quat.from_rotation(Rotation.from_rotvec(np.radians(angle_deg)[:, None] * axis))


def _chain(*factors: np.ndarray) -> np.ndarray:
    out = factors[0]
    for f in factors[1:]:
        out = quat.multiply(out, f)
    return out


def orientations(source: GeneratorSource, t: np.ndarray) -> np.ndarray:
    """(n, 10, 4) noise-free global segment orientations of ``source`` at times ``t`` (s)."""
    a = source.joint_angles(t)
    n = len(a["knee_flex_l"])
    heading = np.full(n, source._subject.heading)
    pelvis = _chain(_elementary(heading + a["pelvis_yaw"], _Y), _elementary(a["pelvis_tilt"], _X),
                    _elementary(a["pelvis_obliquity"], _Z))
    trunk = _chain(pelvis, _elementary(a["trunk_rot"], _Y), _elementary(a["trunk_flex"], _X),
                   _elementary(a["trunk_lat"], _Z))
    neck = _chain(trunk, _elementary(a["neck_rot"], _Y), _elementary(a["neck_flex"], _X),
                  _elementary(a["neck_lat"], _Z))
    seg = {"hip": pelvis, "neck": neck}
    for side, lat in (("l", 1.0), ("r", -1.0)):
        thigh = _chain(pelvis, _elementary(lat * a[f"hip_abd_{side}"], _Z), _elementary(-a[f"hip_flex_{side}"], _X),
                       _elementary(-lat * a[f"hip_rot_{side}"], _Y))
        seg[f"{side}_thigh"] = thigh
        seg[f"{side}_shank"] = _chain(thigh, _elementary(a[f"knee_flex_{side}"], _X))
        upper = _chain(trunk, _elementary(lat * a[f"shoulder_abd_{side}"], _Z),
                       _elementary(-a[f"shoulder_flex_{side}"], _X), _elementary(-lat * a[f"shoulder_rot_{side}"], _Y))
        seg[f"{side}_upperarm"] = upper
        seg[f"{side}_lowerarm"] = _chain(upper, _elementary(-a[f"elbow_flex_{side}"], _X))
    q = np.stack([seg[s] for s in SEGMENTS], axis=1)
    if source.mounting_offsets:
        q = quat.multiply(q, source._mount[None, :, :])
    return q


class ReferenceEmulator(Emulator):
    """The emulator whose truth tap takes each due device's samples from the ring and encodes them
    (``wire.encode_raw``) one device at a time, and whose feeds are sampled one by one."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._feed_rows = self

    def rows(self, k: int, count: int) -> np.ndarray:
        """Sample k of the first ``count`` feeds (finite feeds hold their last one), stacked."""
        return np.concatenate([f.sample(k if f.length is None else min(k, f.length - 1))
                               for f in self._by_length[:count]])

    def _flush_tap(self, slots: np.ndarray, k: int) -> None:
        for slot in slots.tolist():
            self._flush_one(slot, k)

    def _flush_one(self, slot: int, k: int) -> None:
        first = int(self.raw_next[slot])
        if k < first:
            return
        rows = np.arange(first, k + 1) % self._ring
        rows = rows[self._ring_n[rows, slot] >= 0]
        self.raw_next[slot] = k + 1
        if len(rows) == 0:
            return
        b = self.bank.kernel
        self.host.publish_raw(self.devices[slot], wire.RawBatch(
            int(b.stream[slot]), int(self._ring_n[rows[0], slot] - b.base[slot]), self._ring_t[rows, slot],
            self._ring_q[rows, slot], self._ring_ref[rows, slot], self._ring_own[rows, slot]))
