"""Knee angles of a real recording after calibration, for plausibility (docs/evaluation.md,
"Calibration").

Each sensor is calibrated from the recording's first still second, where the subject stands in
the rest pose (the full reset: segment = reading * S0^-1, the still mean S0). The knee's
rotation (thigh -> shank) is then taken as a rotation vector; without a magnetometer-free body
frame (which way the subject faces is unknown in the recording's world frame), the flexion axis
is found from the motion itself, as functional calibrations do: the principal axis of those
rotation vectors over the recording (the knee is nearly a hinge), signed so that the knee bends
forward. Flexion is the rotation about that axis, ab/adduction about the horizontal axis
perpendicular to it (the subject's forward), both in degrees; printed as the 2nd / 50th / 98th
percentiles and the range.

    python bench/knee_angles.py ../shared/data/xio_lower_body --up z
    python bench/knee_angles.py ../shared/data/xsens_opensense --up z --names opensense

The Xsens MTw files name their sensors by serial number only; ``--names opensense`` maps those of
OpenSim's OpenSense example (the assignment of OpenSim's own example and test code: 00B4227C right
femur, 00B4227D right tibia, 00B421EE left femur, 00B421ED left tibia, 00B42279 pelvis).
"""
from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream import calibration, quat
from limbstream.sources import load
from limbstream.sources.imu_files import load_xsens_folder


NAMES = {"opensense": {"00B4227C": "r_thigh", "00B4227D": "r_shank", "00B421EE": "l_thigh",
                       "00B421ED": "l_shank", "00B42279": "hip"}}
"""Sensor file stem -> segment, per recording whose files carry no segment names."""

UP = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


def knee_angles(thigh: np.ndarray, shank: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(flexion (m,), ab/adduction (m,) degrees, the flexion axis' tilt from horizontal, deg) of
    calibrated thigh and shank orientations (m, 4)."""
    rel = quat.multiply(quat.conjugate(thigh), shank)
    v = np.degrees(Rotation.from_quat(rel[:, [1, 2, 3, 0]]).as_rotvec())  # (m, 3) in the thigh's rest frame
    axis = np.linalg.svd(v, full_matrices=False)[2][0]  # principal direction (about 0: the rest pose)
    flexion = v @ axis
    if abs(np.percentile(flexion, 2)) > abs(np.percentile(flexion, 98)):
        axis, flexion = -axis, -flexion  # the knee bends one way: that way is positive
    forward = np.cross(up, axis)
    forward /= np.linalg.norm(forward)
    tilt = float(np.degrees(np.arcsin(abs(axis @ up))))
    return flexion, v @ forward, tilt


def knee_table(path: str, up: np.ndarray, still_s: float = 1.0, names: dict[str, str] | None = None) -> str:
    """The table of one recording's knees (markdown); ``names``: an Xsens folder's stem -> segment."""
    (motion,) = [load_xsens_folder(path, names)] if names else load(path)
    fs = 1.0 / float(np.median(np.diff(motion.t)))
    still = slice(0, round(still_s * fs))
    cal = {s: calibration.calibrate(motion.q[:, k], still, None, None, s) for k, s in enumerate(motion.segments)}
    seg = {s: cal[s].apply(motion.q[still.stop:, k]) for k, s in enumerate(motion.segments)}
    lines = [f"{motion.name}: {len(motion.t)} samples at {fs:.1f} Hz, calibrated from the first {still_s:g} s",
             "", "| knee | flexion p2 / p50 / p98 (deg) | flexion range | ab/adduction p2 / p50 / p98 (deg) | "
             "flexion axis tilt (deg) |", "|---|---|---|---|---|"]
    for side in ("l", "r"):
        thigh, shank = seg[f"{side}_thigh"], seg[f"{side}_shank"]
        ok = np.isfinite(thigh).all(axis=1) & np.isfinite(shank).all(axis=1)
        flexion, abduction, tilt = knee_angles(thigh[ok], shank[ok], up)
        f = np.percentile(flexion, [2, 50, 98])
        a = np.percentile(abduction, [2, 50, 98])
        lines.append(f"| {side} | {f[0]:.1f} / {f[1]:.1f} / {f[2]:.1f} | {f[2] - f[0]:.1f} | "
                     f"{a[0]:.1f} / {a[1]:.1f} / {a[2]:.1f} | {tilt:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", help="a recording with l_/r_thigh and l_/r_shank sensors (e.g. x-IMU3 lower body)")
    parser.add_argument("--up", choices=sorted(UP), default="z", help="the recording's up axis (x-IMU3: z)")
    parser.add_argument("--still-s", type=float, default=1.0, help="the still rest pose at the start, s (default 1)")
    parser.add_argument("--names", choices=sorted(NAMES), help="segment names of an Xsens folder's sensors")
    args = parser.parse_args(argv)
    print(knee_table(args.path, UP[args.up], args.still_s, NAMES.get(args.names)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
