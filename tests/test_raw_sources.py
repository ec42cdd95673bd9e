"""Raw sensor recordings: the BROAD and qmt readers on the shared files, and bad files."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.io import savemat

from support import require_data
from limbstream.sources import SEGMENTS, MotionFileError, RawRecording, load, load_raw
from limbstream.sources.qmt import QMT_OFF_BODY, QMT_SEGMENTS

G = 9.81


def test_a_broad_trial():
    path = require_data("broad/01_undisturbed_slow_rotation_A.mat")
    r = load_raw(path)
    assert r.fs == pytest.approx(285.714, abs=1e-3) and r.t[0] == 0.0
    assert r.gyr.shape == r.acc.shape == r.mag.shape == (len(r.t), 1, 3) and r.truth.shape == (len(r.t), 1, 4)
    assert r.sensors == r.segments == ("imu",) and r.movement.dtype == bool
    assert 0.3 < r.movement.mean() < 0.9
    seen = np.isfinite(r.truth[:, 0]).all(axis=1)
    assert 0 < (~seen).sum() < 0.01 * len(seen)  # the reference lost the markers a few times
    assert np.allclose(np.linalg.norm(r.truth[seen, 0], axis=1), 1.0)
    # the trial starts at rest: gravity up in the truth's earth frame (Z up)
    from limbstream import quat

    first = np.flatnonzero(seen)[0]
    up = quat.rotate(r.truth[first, 0], r.acc[first, 0])
    assert up[2] == pytest.approx(G, abs=0.3) and np.hypot(*up[:2]) < 0.3


def test_the_qmt_full_body_recording_on_the_10_imu_body():
    r = load_raw(require_data("qmt_full_body/full_body_example_data.mat"))
    assert len(r.sensors) == 16 and r.fs == pytest.approx(100.0) and r.t[-1] == pytest.approx(99.99)
    assert r.mag is None and r.truth is None
    body = r.body()
    assert body.segments == SEGMENTS
    assert body.sensors == tuple({v: k for k, v in QMT_SEGMENTS.items()}[s] for s in SEGMENTS)
    assert set(r.sensors) - set(body.sensors) == set(QMT_OFF_BODY)
    still = r.t < 2.0  # it starts standing still (a person sways: a few deg/s)
    assert np.degrees(np.abs(r.gyr[still])).max() < 10.0
    assert np.abs(np.linalg.norm(r.acc[still], axis=-1) - G).max() < 1.0


def test_missing_and_malformed_channels_are_named(tmp_path):
    n = 50
    trial = {"imu_gyr": np.zeros((n, 3)), "imu_acc": np.zeros((n, 3)), "sampling_rate": 100.0}
    for drop in ("imu_acc", "imu_gyr", "sampling_rate"):
        path = tmp_path / f"no_{drop}.mat"
        savemat(path, {k: v for k, v in trial.items() if k != drop})
        with pytest.raises(MotionFileError, match=drop):
            load_raw(path)
    path = tmp_path / "short_acc.mat"
    savemat(path, {**trial, "imu_acc": np.zeros((n - 1, 3))})
    with pytest.raises(MotionFileError, match=r"imu_acc has shape \(49, 3\), expected \(50, 3\)"):
        load_raw(path)
    path = tmp_path / "body.mat"
    savemat(path, {"t": np.arange(n) / 100.0, "hip": {"acc": np.zeros((n, 3)), "gyr": np.zeros((n, 3))},
                   "head": {"acc": np.zeros((n, 3))}})
    with pytest.raises(MotionFileError, match="sensor head has no gyr"):
        load_raw(path)
    path = tmp_path / "empty.mat"
    savemat(path, {"x": np.zeros(3)})
    with pytest.raises(MotionFileError, match="neither a qmt-style nor a BROAD"):
        load_raw(path)
    junk = tmp_path / "junk.mat"
    junk.write_bytes(b"not a mat file at all")
    with pytest.raises(MotionFileError, match="not a readable MATLAB file"):
        load_raw(junk)
    with pytest.raises(MotionFileError, match="limbstream fuse, eval and export fuse it"):  # the commands that take it
        load(path)


def test_a_minimal_qmt_style_file_reads(tmp_path):
    n = 30
    rng = np.random.default_rng(0)
    gyr, acc = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    path = tmp_path / "two.mat"
    savemat(path, {"t": 40.0 + np.arange(n) / 50.0, "forearm_left": {"acc": acc, "gyr": gyr},
                   "foot_left": {"acc": acc, "gyr": gyr}})
    r = load_raw(path)
    assert r.t[0] == 0.0 and r.fs == pytest.approx(50.0)
    assert r.segments == ("l_lowerarm", "foot_left") and np.array_equal(r.gyr[:, 0], gyr)
    assert r.body().sensors == ("forearm_left",)


def test_a_raw_recording_checks_its_shapes():
    t = np.arange(5) / 10.0
    with pytest.raises(ValueError, match=r"acc \(specific force, m/s\^2\) must be \(5, 1, 3\)"):
        RawRecording(t, np.zeros((5, 1, 3)), np.zeros((5, 2, 3)), ("a",), ("a",))
    with pytest.raises(ValueError, match="increasing"):
        RawRecording(t[::-1], np.zeros((5, 1, 3)), np.zeros((5, 1, 3)), ("a",), ("a",))
    with pytest.raises(ValueError, match="movement"):
        RawRecording(t, np.zeros((5, 1, 3)), np.zeros((5, 1, 3)), ("a",), ("a",), movement=np.ones(4, bool))
