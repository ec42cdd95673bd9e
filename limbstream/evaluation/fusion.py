"""Fusion error: a filter's orientation estimate against a reference, as BROAD scores it.

Both orientations are the sensor's in the same Z-up earth frame. The error quaternion is taken in
the earth frame, ``e = estimate * truth^-1`` (BROAD: Laidig et al., Data 2021), and split into a
rotation about the vertical and one about a horizontal axis, ``e = heading(psi) * tilt``:

- total error: the angle of ``e``, ``2 arccos |e_w|``;
- heading error: ``psi = 2 atan2(e_z, e_w)``, wrapped to (-180, 180] degrees;
- inclination error: the tilt's angle, ``2 arccos sqrt(e_w^2 + e_z^2)``, which is also the angle
  between the vertical and ``e`` applied to it: how far the estimate's idea of "up" is off.

Each is reported as its RMS over the scored samples: those in the movement phases (where the
recording marks them) whose reference and estimate are both finite.

A 6D filter (no magnetometer) has no absolute heading: its heading is aligned once with the
reference's at the start (the circular mean of ``psi`` over the first :data:`ALIGN_S` of samples
with a reference is taken off every estimate), and from then on the heading error is its drift.
The **heading drift** is the slope of a least-squares line through the (unwrapped, aligned)
heading error over the scored samples, in degrees per minute. The inclination error does not
depend on the alignment (a turn about the vertical on the left does not move "up").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from limbstream import quat

ALIGN_S = 1.0
"""A 6D estimate's heading is aligned with the reference's over this first stretch of samples
with a reference, s."""


def error_quaternion(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(..., 4) ``estimate * truth^-1``: the estimate's error in the earth frame (both (..., 4),
    scalar-first, the sensor's orientation in the earth frame)."""
    return quat.multiply(estimate, quat.conjugate(truth))


def heading_inclination(e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heading and inclination angles (rad) of error quaternions ``e`` (..., 4): heading in
    (-pi, pi] (about the earth's Z), inclination in [0, pi]."""
    e = np.asarray(e, np.float64)
    heading = np.angle(np.exp(2j * np.arctan2(e[..., 3], e[..., 0])))
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(e[..., 0] ** 2 + e[..., 3] ** 2), 0.0, 1.0))
    return heading, inclination


@dataclass(frozen=True)
class FusionError:
    """RMS errors over the scored samples, degrees (``heading_drift_dpm`` in deg/min, 6D only:
    NaN when the heading is absolute)."""

    total_deg: float
    heading_deg: float
    inclination_deg: float
    heading_drift_dpm: float
    samples: int


def fusion_error(estimate: np.ndarray, truth: np.ndarray, t: np.ndarray | None = None,
                 movement: np.ndarray | None = None, align_heading: bool = False) -> FusionError:
    """A filter's error against the reference.

    Parameters
    ----------
    estimate, truth : (n, 4) the sensor's orientation in the earth frame (Z up), scalar-first;
        NaN rows are not scored.
    t : (n,) sample times, s (needed with ``align_heading``).
    movement : (n,) bool, the samples to score (None: all).
    align_heading : 6D: align the heading once at the start and report its drift.

    Raises
    ------
    ValueError if no sample can be scored, or shapes disagree.
    """
    estimate, truth = np.asarray(estimate, np.float64), np.asarray(truth, np.float64)
    if estimate.shape != truth.shape or estimate.ndim != 2 or estimate.shape[1] != 4:
        raise ValueError(f"estimate and truth must both be (n, 4), got {estimate.shape} and {truth.shape}")
    valid = np.isfinite(estimate).all(axis=1) & np.isfinite(truth).all(axis=1)
    scored = valid if movement is None else valid & np.asarray(movement, bool)
    if not scored.any():
        raise ValueError("no sample to score (no finite estimate and reference in the movement phases)")
    e = error_quaternion(np.where(valid[:, None], estimate, 1.0), np.where(valid[:, None], truth, 1.0))
    heading, inclination = heading_inclination(e)
    drift = float("nan")
    if align_heading:
        if t is None:
            raise ValueError("aligning the heading needs the sample times t")
        t = np.asarray(t, np.float64)
        start = valid & (t <= t[valid][0] + ALIGN_S)
        offset = np.angle(np.mean(np.exp(1j * heading[start])))
        heading = np.angle(np.exp(1j * (heading - offset)))
        e = quat.multiply(_about_z(-offset), e)
        drift = _drift_dpm(t[valid], heading[valid], scored[valid])
    total = 2.0 * np.arccos(np.clip(np.abs(e[:, 0]), 0.0, 1.0))

    def rms(angle):
        return float(np.degrees(np.sqrt(np.mean(angle[scored] ** 2))))

    return FusionError(rms(total), rms(heading), rms(inclination), drift, int(scored.sum()))


def _about_z(angle: float) -> np.ndarray:
    """(4,) rotation about the earth's Z by ``angle`` rad."""
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


def _drift_dpm(t: np.ndarray, heading: np.ndarray, scored: np.ndarray) -> float:
    """Slope (deg/min) of a least-squares line through the heading error (rad), unwrapped over
    the valid samples ``t`` (s), fitted on the ``scored`` ones."""
    unwrapped = np.unwrap(heading)
    if scored.sum() < 2 or np.ptp(t[scored]) == 0:
        return float("nan")
    slope = np.polyfit(t[scored], unwrapped[scored], 1)[0]
    return float(np.degrees(slope) * 60.0)


VQF_VERSION = "2.1.2"
"""The PyPI ``vqf`` release the reference runs are made with (the test extra pins it)."""


def reference_vqf(gyr: np.ndarray, acc: np.ndarray, rate: float, mag: np.ndarray | None = None,
                  start_heading: np.ndarray | None = None, params: dict | None = None) -> np.ndarray:
    """Online VQF from the PyPI ``vqf`` package (default parameters: rest and motion bias
    estimation on), sensor by sensor: the reference a device's fusion is measured against.

    Parameters
    ----------
    gyr, acc : (n, S, 3) rad/s and m/s^2; mag : (n, S, 3) uT for 9D, None for 6D.
    rate : sample rate, Hz.
    start_heading : (S, 4) each filter's start heading (its gyroscope quaternion before the first
        sample, :func:`limbstream.imu.earth_heading`); None: identity.
    params : VQF parameters to override (``VQFParams`` names, e.g. ``{"restThGyr": 1.0}``).

    Returns
    -------
    (n, S, 4) float64 each sensor's orientation in the filter's earth frame (Z up): VQF's 9D
    quaternion with ``mag``, else its 6D one.
    """
    try:
        from vqf import VQF
    except ImportError as exc:  # pragma: no cover - the test extra installs it
        raise ImportError(f"the reference fusion needs the PyPI vqf package: pip install vqf=={VQF_VERSION}") from exc
    out = np.empty(gyr.shape[:2] + (4,))
    for s in range(gyr.shape[1]):
        f = VQF(1.0 / rate, **(params or {}))
        if start_heading is not None:
            state = f.state
            state["gyrQuat"] = np.asarray(start_heading[s], np.float64)
            f.state = state
        columns = [np.ascontiguousarray(x[:, s], np.float64) for x in (gyr, acc) + (() if mag is None else (mag,))]
        out[:, s] = f.updateBatch(*columns)["quat9D" if mag is not None else "quat6D"]
    return out


@dataclass(frozen=True)
class EarthTruth:
    """The reference a device's stream is scored against with BROAD's metric (a raw sensor's
    stream: :class:`limbstream.evaluation.sweep.Stream`'s ``earth``).

    Attributes
    ----------
    truth : (m, 4) the sensor's true orientation in the filter's earth frame (Z up) at each of
        the stream's samples; NaN rows where unseen.
    movement : (m,) bool, the samples scored.
    align_heading : 6D: the heading is aligned once at the start and its drift reported.
    """

    truth: np.ndarray
    movement: np.ndarray
    align_heading: bool


FIGURES: tuple[str, ...] = ("total", "heading", "incl", "drift")
"""The figures of :func:`pooled_error`, in order (the eval row keys ``fusion_*`` and ``chain_*``)."""


def pooled_error(parts: list[tuple[np.ndarray, np.ndarray, EarthTruth]]) -> dict[str, float]:
    """BROAD's figures of several streams at once: ``total``, ``heading``, ``incl`` the RMS over
    every scored sample of all of them (deg), ``drift`` the median of the streams' heading drifts
    (deg/min; NaN unless aligned).

    Parameters
    ----------
    parts : per stream (estimate (m, 4) in the earth frame, Z up; t (m,) s; its EarthTruth).
    """
    squares = np.zeros(3)
    count = 0
    drifts = []
    for estimate, t, ref in parts:
        try:
            e = fusion_error(estimate, ref.truth, t, ref.movement, ref.align_heading)
        except ValueError:  # nothing of this stream to score
            continue
        squares += e.samples * np.array([e.total_deg, e.heading_deg, e.inclination_deg]) ** 2
        count += e.samples
        drifts.append(e.heading_drift_dpm)
    if not count:
        return dict.fromkeys(FIGURES, float("nan"))
    total, heading, incl = np.sqrt(squares / count)
    finite = [d for d in drifts if np.isfinite(d)]
    return {"total": float(total), "heading": float(heading), "incl": float(incl),
            "drift": float(np.median(finite)) if finite else float("nan")}
