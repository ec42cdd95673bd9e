"""Knee angles of a real recording after calibration, for plausibility (docs/evaluation.md,
"Calibration").

Loading the recording turns its world Y up and calibrates each sensor from its first still second,
where the subject stands in the rest pose (the full reset: segment = reading * S0^-1, the still
mean S0; limbstream.sources.imu_files.to_body). The knee's
rotation (thigh -> shank) is then taken as a rotation vector; without a magnetometer-free body
frame (which way the subject faces is unknown in the recording's world frame), the flexion axis
is found from the motion itself, as functional calibrations do: the principal axis of those
rotation vectors over the recording (the knee is nearly a hinge), signed so that the knee bends
forward. Flexion is the rotation about that axis, ab/adduction about the horizontal axis
perpendicular to it (the subject's forward), both in degrees; printed as the 2nd / 50th / 98th
percentiles and the range.

    python bench/knee_angles.py ../shared/data/xio_lower_body
    python bench/knee_angles.py ../shared/data/xsens_opensense --names opensense

The Xsens MTw files name their sensors by serial number only; ``--names`` maps them as every
command's does (limbstream.sources.names; ``opensense``: OpenSim's OpenSense example).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from limbstream import calibration, quat  # noqa: E402
from limbstream.sources import load, names as sensor_names  # noqa: E402


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


def knee_table(path: str, names: dict[str, str] | None = None) -> str:
    """The table of one recording's knees (markdown); ``names``: its sensors' segments."""
    (motion,) = load(path, names)
    fs = 1.0 / float(np.median(np.diff(motion.t)))
    still = slice(0, round(calibration.START_STILL_S * fs))
    seg = {s: motion.q[still.stop:, k] for k, s in enumerate(motion.segments)}
    lines = [f"{motion.name}: {len(motion.t)} samples at {fs:.1f} Hz, calibrated from the first "
             f"{calibration.START_STILL_S:g} s",
             "", "| knee | flexion p2 / p50 / p98 (deg) | flexion range | ab/adduction p2 / p50 / p98 (deg) | "
             "flexion axis tilt (deg) |", "|---|---|---|---|---|"]
    for side in ("l", "r"):
        thigh, shank = seg[f"{side}_thigh"], seg[f"{side}_shank"]
        ok = np.isfinite(thigh).all(axis=1) & np.isfinite(shank).all(axis=1)
        flexion, abduction, tilt = knee_angles(thigh[ok], shank[ok], calibration.VERTICAL)
        f = np.percentile(flexion, [2, 50, 98])
        a = np.percentile(abduction, [2, 50, 98])
        lines.append(f"| {side} | {f[0]:.1f} / {f[1]:.1f} / {f[2]:.1f} | {f[2] - f[0]:.1f} | "
                     f"{a[0]:.1f} / {a[1]:.1f} / {a[2]:.1f} | {tilt:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", help="a recording with l_/r_thigh and l_/r_shank sensors (e.g. x-IMU3 lower body)")
    parser.add_argument("--names", default=None, metavar="NAME|FILE|SENSOR=SEGMENT,...",
                        help=f"the sensors' segments (named: {', '.join(sensor_names.NAMED)})")
    args = parser.parse_args(argv)
    try:
        names = None if args.names is None else sensor_names.parse(args.names)
    except ValueError as exc:
        parser.error(str(exc))
    print(knee_table(args.path, names))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
