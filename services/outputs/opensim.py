"""OpenSim's files: joint angles as a motion file (``.mot``) and segment orientations as OpenSense's
orientation file (``.sto``), the inputs of OpenSim's tools and of OpenSense's IMU inverse kinematics
(docs/outputs.md, "OpenSim").

``.mot`` (an OpenSim Storage): a name line, ``version=1``, ``nRows``, ``nColumns`` (time
included), ``inDegrees=yes``, a line saying which calibration the angles rest on, ``endheader``,
then a tab-separated table: ``time`` and one column per joint angle the subject has, in its
layout's order (``wire.joint_angles(layout)``: the Rajagopal model's coordinate names; the
10-segment body's :data:`limbstream.joints.ANGLES`, the ``full`` layout's with its ankles,
subtalar inversion, lumbar and wrist angles), degrees; a frame without a valid angle (a segment
without data) holds ``NaN`` (:func:`mot_of` leaves such frames out).

``.sto`` (OpenSense's orientation table): ``DataRate``, ``DataType=Quaternion``, ``version=3``,
``OpenSimVersion``, ``endheader``, then ``time`` and one column per segment named after the body
it is on plus ``_imu`` (``pelvis_imu``, ``femur_r_imu``, ...), each cell ``w,x,y,z``. The
quaternions are the segments' anatomical frames in OpenSim's ground axes (X forward of the rest
pose, Y up, Z right), identity in the standing rest pose: OpenSense's IMU placer then needs no
``sensor_to_opensim_rotations`` (0 0 0), with ``pelvis_imu`` as the base IMU and ``x`` as its
heading axis.
"""
from __future__ import annotations

import numpy as np

from limbstream import joints, wire
from limbstream.body import Layout

IMU_NAMES: dict[str, str] = {"hip": "pelvis_imu", "neck": "torso_imu", "chest": "torso_imu",
                             "l_thigh": "femur_l_imu", "r_thigh": "femur_r_imu",
                             "l_shank": "tibia_l_imu", "r_shank": "tibia_r_imu",
                             "l_foot": "calcn_l_imu", "r_foot": "calcn_r_imu",
                             "l_upperarm": "humerus_l_imu", "r_upperarm": "humerus_r_imu",
                             "l_lowerarm": "ulna_l_imu", "r_lowerarm": "ulna_r_imu",
                             "l_hand": "hand_l_imu", "r_hand": "hand_r_imu", "head": "head_imu"}
"""Segment -> OpenSense IMU column (the Rajagopal model's body plus ``_imu``). The model has no
neck: in the 10-segment body (no trunk sensor) the neck's sensor stands in for the torso's; the
``full`` layout's chest is the torso, its feet the calcanei. The model has no head body either
(its torso carries the head): ``head_imu`` names the head's sensor for a model that has one."""
OPENSIM_VERSION = "4.5"
"""The OpenSim version an orientation file says it is for (its format is OpenSense's since 4.1)."""


def _number(values: np.ndarray, digits: int) -> list[str]:
    """Numbers as text with ``digits`` decimals, NaN as ``NaN`` (no ``-0.0...``)."""
    values = np.where(np.abs(values) < 0.5 * 10.0 ** -digits, 0.0, values)
    return ["NaN" if not np.isfinite(v) else f"{v:.{digits}f}" for v in values]


def mot_text(name: str, t: np.ndarray, angles: np.ndarray, columns: tuple[str, ...], basis: str) -> str:
    """An OpenSim motion file.

    Parameters
    ----------
    name : the first header line (the motion's name; no newline).
    t : (F,) seconds; angles : (F, C) degrees (NaN: no value); columns : (C,) their names.
    basis : one line saying which calibration the angles rest on.
    """
    header = [name.replace("\n", " ") or "joint angles", "version=1", f"nRows={len(t)}",
              f"nColumns={len(columns) + 1}", "inDegrees=yes",
              f"limbstream joint angles, OpenSim Rajagopal 2015 coordinate conventions; {basis}".replace("\n", " "),
              "endheader", "\t".join(("time", *columns))]
    rows = ["\t".join([f"{t[k]:.6f}", *_number(angles[k], 4)]) for k in range(len(t))]
    return "\n".join(header + rows) + "\n"


def mot_of(name: str, t: np.ndarray, q: np.ndarray, basis: str, layout: str | Layout = "paper10",
           rest_pose: str = wire.DEFAULT_REST_POSE, present: np.ndarray | None = None) -> str:
    """An OpenSim motion file of calibrated segment orientations: ``layout``'s joint angles
    (``wire.joint_angles(layout)``, the model's coordinate names) that have a value in some
    frame, over the frames in which all of them have one (OpenSim's readers take no NaN).

    Parameters
    ----------
    name : the first header line; basis : the calibration line (:func:`mot_text`).
    t : (F,) s; q : (F, S, 4) anatomical segment orientations in the layout's segment order.
    layout : a built-in layout's name, a layout file or a Layout; rest_pose : what identity
        means for ``q``; present : (S,) or (F, S) bool, the segments with data (None: the finite).

    ValueError if no joint has both of its segments or no frame has every written angle.
    """
    angles, _ = joints.joint_angles(q, present, rest_pose, layout=layout)
    names = joints.angle_names(layout)
    valid = np.isfinite(angles)
    columns = np.flatnonzero(valid.any(axis=0))
    if not len(columns):
        raise ValueError(f"{name}: no joint has both of its segments")
    rows = valid[:, columns].all(axis=1)
    if not rows.any():
        raise ValueError(f"{name}: no frame has every joint angle written")
    t = np.asarray(t, np.float64)[rows]
    return mot_text(name, t - t[0], angles[rows][:, columns], tuple(names[k] for k in columns), basis)


def sto_text(t: np.ndarray, q: np.ndarray, segments: tuple[str, ...], rate_hz: float) -> str:
    """An OpenSense orientation file of ``segments`` (their :data:`IMU_NAMES` columns).

    Parameters
    ----------
    t : (F,) seconds; q : (F, len(segments), 4) scalar-first anatomical frames in OpenSim's axes
        (:func:`limbstream.joints.anatomical`); rate_hz : the frame rate.
    """
    header = [f"DataRate={rate_hz:.6f}", "DataType=Quaternion", "version=3", f"OpenSimVersion={OPENSIM_VERSION}",
              "endheader", "\t".join(("time", *(IMU_NAMES[s] for s in segments)))]
    rows = []
    for k in range(len(t)):
        cells = [",".join(_number(q[k, j], 8)) for j in range(len(segments))]
        rows.append("\t".join([f"{t[k]:.6f}", *cells]))
    return "\n".join(header + rows) + "\n"


def segments_with_data(present: np.ndarray) -> tuple[str, ...]:
    """The segments (SEGMENTS order) that have data in some frame of ``present`` (F, 10)."""
    with_data = np.flatnonzero(np.asarray(present, bool).reshape(-1, len(wire.SEGMENTS)).any(axis=0))
    return tuple(wire.SEGMENTS[k] for k in with_data)
