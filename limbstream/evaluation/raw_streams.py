"""The streams of raw sensors for the sweep: what each device's fastSW is given, its filter's
orientation at its own instants in limbstream's world (Y up), computed as the device computes it
(:func:`limbstream.kernel.fusion.fuse`, :func:`~limbstream.kernel.fusion.device_instants`,
:func:`~limbstream.kernel.fusion.y_up`), with the references its errors are taken against:

- a raw recording (:func:`recording_streams`): its reference orientations where it has them
  (BROAD's optical truth, in the filter's earth frame: the fusion and chain errors); none for the
  qmt recording, whose streams are scored for compression alone;
- emulated sensors on a motion (:func:`emulated_streams`, ``--imu raw``): the calibration script,
  then the motion, read by each device's sensor (:func:`limbstream.imu.record`); the segments'
  true orientations for the body error after calibration, and each sensor's true orientation in
  its filter's earth frame for the fusion and chain errors (6D: heading aligned once).
"""
from __future__ import annotations

import math

import numpy as np

from limbstream import calibration, imu, quat, wire
from limbstream.body import Layout
from limbstream.evaluation.fusion import EarthTruth
from limbstream.evaluation.positions import source_of
from limbstream.evaluation.body import layout_of
from limbstream.evaluation.sweep import Stream
from limbstream.imu.feed import script_samples
from limbstream.kernel import fusion
from limbstream.sources import Motion
from limbstream.sources import raw
from limbstream.sources.raw import RawRecording


def device_stream(t: np.ndarray, q_earth: np.ndarray, device_rate_hz: float = wire.DEVICE_RATE_HZ
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(indices (k,) of the raw samples the device takes, its samples (k, 4) float64 Y up) from a
    filter's orientation after every raw sample ``q_earth`` (n, 4), Z up, at times ``t`` (n,)."""
    idx = fusion.device_instants(t, device_rate_hz)
    return idx, fusion.y_up(q_earth[idx]).astype(np.float64)


def recording_streams(rec: RawRecording, mag: bool = False, rest_th_gyr_dps: float = fusion.REST_TH_GYR_DPS,
                      vqf_precision: str = fusion.DEFAULT_VQF_PRECISION) -> list[Stream]:
    """One stream per sensor of a raw recording, fused 6D (9D with ``mag``; ValueError without a
    magnetometer) by VQF in ``vqf_precision`` (``fusion.VQF_PRECISIONS``); with a reference, scored
    over its movement phases (all samples if unmarked)."""
    fused = raw.fuse(rec, mag, rest_th_gyr_dps, vqf_precision)
    out = []
    for s, sensor in enumerate(rec.sensors):
        idx, samples = device_stream(rec.t, fused[:, s])
        earth = None
        if rec.truth is not None:
            movement = np.ones(len(idx), bool) if rec.movement is None else rec.movement[idx]
            earth = EarthTruth(rec.truth[idx, s], movement, align_heading=not mag)
        out.append(Stream(rec.t[idx], samples, f"{rec.name}/{sensor}", earth=earth))
    return out


def emulated_streams(motions: list[Motion], sensors: calibration.SensorModel, model: imu.ImuModel,
                     rate_hz: float = imu.DEFAULT_RATE_HZ, vqf_precision: str = fusion.DEFAULT_VQF_PRECISION,
                     layout: Layout | None = None) -> list[Stream]:
    """Every motion's segment streams as devices with raw sensors of ``model`` at ``rate_hz``
    (mountings and filter headings of ``sensors``, drawn per motion; VQF in ``vqf_precision``) send
    them, after the calibration script; their bodies of ``layout`` (None: each motion's own)."""
    out = []
    for index, motion in enumerate(motions):
        devices = imu.ImuDevices(len(motion.segments), model, rate_hz, sensors, stream=index)
        rec = imu.record(motion, devices)
        assert rec.truth is not None and rec.movement is not None  # (an emulated recording has both)
        script_s = script_samples(motion.fs) / motion.fs
        pose = calibration.mounting_pose(motion.segments)
        back = quat.conjugate(devices.mounting)
        for s, segment in enumerate(motion.segments):
            q = fusion.fuse(rec.gyr[:, s], rec.acc[:, s], rate_hz=rate_hz, heading_rad=float(devices.heading[s]),
                            vqf_precision=vqf_precision)
            idx, samples = device_stream(rec.t, q)
            t = rec.t[idx]
            segment_truth = quat.multiply(quat.multiply(quat.Z_UP_TO_Y_UP, rec.truth[idx, s]), back[s])
            out.append(Stream(t, samples, f"{motion.name}/{segment}", truth=segment_truth,
                              rest=_window(t, 0.0, calibration.REST_S),
                              mounting=_window(t, calibration.REST_S + calibration.MOVE_S,
                                               calibration.REST_S + calibration.MOVE_S + calibration.MOUNTING_S),
                              pose=pose[s], motion_from=int(np.searchsorted(t, script_s - 1e-9)),
                              rest_pose=motion.rest_pose, layout=layout_of(motion, layout), **source_of(motion, script_s),
                              earth=EarthTruth(rec.truth[idx, s], rec.movement[idx], align_heading=True),
                              full_scale=float(model.at_full_scale(rec.gyr[:, s], rec.acc[:, s]).mean())))
    return out


def _window(t: np.ndarray, start_s: float, end_s: float) -> slice:
    """The samples of ``t`` in a still pose held from ``start_s`` to ``end_s`` (the calibration
    script's), less :data:`limbstream.calibration.STILL_MARGIN_S` at each end."""
    margin = calibration.STILL_MARGIN_S
    return slice(int(np.searchsorted(t, start_s + margin - 1e-9)), int(np.searchsorted(t, end_s - margin + 1e-9)))


def looped(motions: list[Motion], minutes: float) -> list[Motion]:
    """Each motion played looped for ``minutes`` of motion (:func:`limbstream.sources.loop.looped`,
    seams joined smoothly; a looped clip turns about a fixed root)."""
    from limbstream.sources.loop import looped as loop

    return [loop([m], minutes * 60.0) for m in motions] if math.isfinite(minutes) else motions
