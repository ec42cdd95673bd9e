"""Range of motion: a ball joint's relative orientation stays within its anatomical range
(Lehmann, Laidig, Deimel, Seel, arXiv 2002.00639: the relative headings that put a joint out of
its range are not the true one).

A joint's range is a box of three angles, the relative orientation taken as intrinsic turns about
the parent's X (flexion-extension), then Z (abduction-adduction), then Y (axial rotation), in the
standing rest pose's frames (X left, Y up, Z forward; T-pose arms are turned down first). The
limits (degrees, left side; the right mirrors Z and Y) are the usual clinical ranges plus
:data:`MARGIN_DEG`, wide enough that a healthy subject stays inside: only a heading error can
take a joint out. The neck hangs from the hip, so its range takes up the spine's twist and bend
too.

For each joint, the relative orientation is turned about the vertical by trial offsets around
the correction applied, and the share of samples out of range is kept per offset over the last
``memory_s`` (:class:`RangeCounts`). Like Lehmann et al., a correction is only a heading that
puts many samples out of range: a pose out of the box now and then (a dancer's leg) moves
nothing.
"""
from __future__ import annotations

import numpy as np

from limbstream import quat
from limbstream.calibration import axis_angle

MARGIN_DEG = 10.0
"""Added to each clinical limit, degrees."""

LIMITS_DEG: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "hip": ((-140.0, 40.0), (-50.0, 60.0), (-60.0, 60.0)),
    "neck": ((-70.0, 90.0), (-60.0, 60.0), (-110.0, 110.0)),
    "lumbar": ((-40.0, 90.0), (-40.0, 40.0), (-50.0, 50.0)),
    "ankle": ((-30.0, 55.0), (-35.0, 25.0), (-30.0, 30.0)),
    "wrist": ((-25.0, 40.0), (-85.0, 75.0), (-80.0, 80.0)),
}
"""Joint kind -> (X, Z, Y) angle limits, degrees, left side (X: turning the bone backwards is
positive, so flexion is negative for a leg and positive for the neck). Wide: a rest pose is not
always anatomically neutral (BVH skeletons stand with their legs apart), and the range is a
guard against large heading errors, not a fine measure. The shoulders have none: with the trunk
unmeasured, an upper arm can take nearly any orientation relative to the pelvis.

Where a body has them (the ``full`` layout): the lumbar spine (chest on pelvis: flexion, X
positive, to 90, extension 40, bending 40, twist 50 each way); the ankle (foot on shank: X
positive is plantarflexion, to 55, dorsiflexion 30; Z, about the foot's long axis, eversion to
25 and inversion to 35; the foot turned in or out 30); the wrist (hand on forearm, the palm
against the thigh at rest: X positive the ulnar deviation, to 40, radial 25; Z extension to 75
and flexion to 85; Y, the twist the forearm's sensor leaves to the hand, 80 each way)."""

TRIALS_DEG = np.array([0.0, 1.0, -1.0, 2.0, -2.0, 3.0, -3.0, 5.0, -5.0, 7.0, -7.0, 10.0, -10.0, 14.0, -14.0,
                       20.0, -20.0, 28.0, -28.0, 40.0, -40.0, 56.0, -56.0, 80.0, -80.0, 110.0, -110.0])
"""Offsets tried, nearest first, degrees."""

def limits(joints: list[str]) -> np.ndarray:
    """(J, 3, 2) radians: each joint's range (mirrored for the right side; +-pi where it has
    none)."""
    out = []
    for name in joints:
        kind = name.split("_")[0]
        if kind not in LIMITS_DEG:
            out.append(np.tile([-np.pi, np.pi], (3, 1)))
            continue
        box = np.radians(np.array(LIMITS_DEG[kind]))
        box = box + np.radians(MARGIN_DEG) * np.array([-1.0, 1.0])
        if name.endswith("_r"):
            box[1:] = -box[1:, ::-1]
        out.append(box)
    return np.array(out).reshape(-1, 3, 2)


def angles(r: np.ndarray) -> np.ndarray:
    """(..., 3) the intrinsic X, Z, Y angles (rad) of relative orientations ``r`` (..., 4)."""
    w, x, y, z = np.moveaxis(np.asarray(r, np.float64), -1, 0)
    # R = Rx(a) Rz(b) Ry(c): R[0,1] = -sin b; R[2,1] = cos b sin a; R[1,1] = cos a cos b;
    # R[0,2] = cos b sin c; R[0,0] = cos b cos c
    r01 = 2 * (x * y - w * z)
    r21 = 2 * (y * z + w * x)
    r11 = 1 - 2 * (x * x + z * z)
    r02 = 2 * (x * z + w * y)
    r00 = 1 - 2 * (y * y + z * z)
    return np.stack([np.arctan2(r21, r11), np.arcsin(np.clip(-r01, -1.0, 1.0)), np.arctan2(r02, r00)], axis=-1)


def out_of_range(r: np.ndarray, g: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(..., J, K) whether relative orientations ``r`` (..., J, 4), turned about the vertical
    ``g`` (..., J, 3) by each of :data:`TRIALS_DEG`, leave their ranges ``box`` (J, 3, 2)."""
    trials = np.radians(TRIALS_DEG)
    turned = quat.multiply(axis_angle(g[..., None, :], np.broadcast_to(trials, g.shape[:-1] + trials.shape)),
                           r[..., None, :])  # (..., J, K, 4)
    a = angles(turned)
    return ~np.all((a >= box[:, None, :, 0]) & (a <= box[:, None, :, 1]), axis=-1)


class RangeCounts:
    """The share of ``shape`` joints' samples out of range at each trial offset, over the last
    ``memory_s`` s (exponentially), and the offset it asks for."""

    def __init__(self, shape: tuple[int, ...], memory_s: float, min_share: float):
        self.memory_s, self.min_share = memory_s, min_share
        self.out = np.zeros(shape + (len(TRIALS_DEG),))
        self.seen = np.zeros(shape)

    def add(self, out: np.ndarray, mask: np.ndarray, dt: float) -> None:
        """Count one sample ``out`` (..., K) where ``mask`` (...), ``dt`` s after the last."""
        keep = np.exp(-dt / self.memory_s)
        self.out = keep * self.out + out * mask[..., None]
        self.seen = keep * self.seen + mask

    def asked(self) -> tuple[np.ndarray, np.ndarray]:
        """(...) the offset (rad) nearest to none whose share out of range is lowest (within 0.05),
        and (...) bool: whether it is asked for (more than ``min_share`` out now, at most half
        of that there)."""
        share = self.out / np.maximum(self.seen, 1e-9)[..., None]
        best = share.min(axis=-1)
        first = np.argmax(share <= best[..., None] + 0.05, axis=-1)  # trials are nearest first
        asked = (share[..., 0] > self.min_share) & (best <= 0.5 * share[..., 0])
        return np.radians(TRIALS_DEG)[first], asked

    def forget(self, mask: np.ndarray) -> None:
        """Joints of ``mask`` (...) start counting again."""
        self.out = np.where(mask[..., None], 0.0, self.out)
        self.seen = np.where(mask, 0.0, self.seen)
