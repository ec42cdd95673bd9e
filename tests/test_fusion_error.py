"""Fusion error metrics (limbstream.evaluation.fusion) against scipy's Rotation and known cases,
and the reference VQF on a BROAD trial."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import require_data
from limbstream import quat
from limbstream.evaluation.fusion import (ALIGN_S, error_quaternion, fusion_error, heading_inclination,
                                          reference_vqf)
from limbstream.sources import load_raw


def q_of(r: Rotation) -> np.ndarray:
    return quat.from_rotation(r)


def about(axis, degrees) -> Rotation:
    return Rotation.from_rotvec(np.outer(np.radians(np.atleast_1d(degrees)), axis))


def test_heading_and_inclination_against_scipy():
    truth = Rotation.random(500, random_state=1)
    estimate = Rotation.random(500, random_state=2)
    heading, inclination = heading_inclination(error_quaternion(q_of(estimate), q_of(truth)))
    e = estimate * truth.inv()  # the error in the earth frame
    # inclination: how far the estimate's "up" is off, measured directly
    up = e.apply([0.0, 0.0, 1.0])
    assert np.allclose(inclination, np.arccos(np.clip(up[:, 2], -1, 1)), atol=1e-9)
    # heading: turning e back by it about Z leaves a pure tilt (rotation axis horizontal)
    tilt = Rotation.from_rotvec(np.outer(-heading, [0.0, 0.0, 1.0])) * e
    assert np.abs(tilt.as_rotvec()[:, 2]).max() < 1e-9
    assert np.allclose(tilt.magnitude(), inclination, atol=1e-9)
    assert np.all(np.abs(heading) <= np.pi) and np.all((0 <= inclination) & (inclination <= np.pi))


def test_known_errors():
    truth = Rotation.random(6, random_state=3)
    psi, theta = np.array([10.0, -150.0, 179.0, 0.0, 45.0, -30.0]), np.array([0.0, 0.0, 0.0, 20.0, 5.0, 60.0])
    axis = np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 3, 6)])  # horizontal axes
    e = Rotation.from_rotvec(np.outer(np.radians(psi), [0, 0, 1])) * Rotation.from_rotvec(axis * np.radians(theta)[:, None])
    heading, inclination = heading_inclination(error_quaternion(q_of(e * truth), q_of(truth)))
    assert np.allclose(np.degrees(heading), psi, atol=1e-9) and np.allclose(np.degrees(inclination), theta, atol=1e-9)
    err = fusion_error(q_of(e * truth), q_of(truth))
    assert err.total_deg == pytest.approx(np.degrees(np.sqrt(np.mean(e.magnitude() ** 2))))
    assert err.heading_deg == pytest.approx(np.sqrt(np.mean(psi**2)))
    assert err.inclination_deg == pytest.approx(np.sqrt(np.mean(theta**2)))
    assert np.isnan(err.heading_drift_dpm) and err.samples == 6


def test_only_movement_samples_with_a_reference_are_scored():
    n = 100
    truth = q_of(Rotation.random(n, random_state=4))
    tilt = np.where(np.arange(n) < 50, 2.0, 7.0)  # 2 deg in the first half, 7 in the second
    estimate = q_of(about([1.0, 0.0, 0.0], tilt) * quat.to_rotation(truth))
    truth[[60, 61]] = np.nan  # the reference lost the sensor
    estimate[70] = np.nan  # the filter gave nothing
    movement = np.arange(n) >= 40
    err = fusion_error(estimate, truth, movement=movement)
    assert err.samples == 60 - 3
    want = np.sqrt((10 * 2.0**2 + 47 * 7.0**2) / 57)
    assert err.inclination_deg == pytest.approx(want) and err.total_deg == pytest.approx(want)
    with pytest.raises(ValueError, match="no sample to score"):
        fusion_error(estimate, truth, movement=np.zeros(n, bool))
    with pytest.raises(ValueError, match=r"\(n, 4\)"):
        fusion_error(estimate[:, :3], truth[:, :3])


def test_6d_heading_is_aligned_once_and_its_drift_measured():
    rate, seconds = 100.0, 600.0
    t = np.arange(int(seconds * rate)) / rate
    truth = Rotation.random(len(t), random_state=5)
    drift = 3.0  # deg/min: a 6D filter's heading wandering off from an arbitrary start of 140 deg
    psi = 140.0 + drift * t / 60.0 + 0.5 * np.sin(t)  # passes +-180 on the way
    e = about([0.0, 0.0, 1.0], psi) * about([0.0, 1.0, 0.0], 1.5)  # and a 1.5 deg tilt
    err = fusion_error(q_of(e * truth), q_of(truth), t, align_heading=True)
    assert err.heading_drift_dpm == pytest.approx(drift, abs=0.01)
    assert err.inclination_deg == pytest.approx(1.5)
    # aligned over the first ALIGN_S: the heading error grows from about 0 to drift * 10 min
    wander = drift * t / 60.0 + 0.5 * np.sin(t)
    aligned = wander - np.mean(wander[t <= ALIGN_S])
    assert err.heading_deg == pytest.approx(np.sqrt(np.mean(aligned**2)), rel=1e-3)
    with pytest.raises(ValueError, match="sample times"):
        fusion_error(q_of(e * truth), q_of(truth), align_heading=True)


def test_reference_vqf_on_a_broad_trial():
    r = load_raw(require_data("broad/10_undisturbed_slow_translation_A.mat"))
    nine = reference_vqf(r.gyr, r.acc, r.fs, mag=r.mag)[:, 0]
    six = reference_vqf(r.gyr, r.acc, r.fs)[:, 0]
    e9 = fusion_error(nine, r.truth[:, 0], r.t, r.movement)
    e6 = fusion_error(six, r.truth[:, 0], r.t, r.movement, align_heading=True)
    assert e9.total_deg < 3.0 and e9.inclination_deg < 1.0, e9  # VQF's own figures: about 2 and 0.3
    assert e6.inclination_deg == pytest.approx(e9.inclination_deg, abs=1e-6)  # 9D = heading * 6D
    assert abs(e6.heading_drift_dpm) < 5.0, e6
