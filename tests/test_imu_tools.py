"""The raw-sensor tools: ``limbstream fuse`` (the device's orientation per sample of a raw
recording) and ``limbstream eval`` on raw recordings and with ``--imu raw``."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.io

from limbstream import cli, quat
from limbstream.kernel import fusion
from limbstream.sources.raw import load_raw
from support import require_data

BROAD_TRIAL = "broad/24_disturbed_tapping_A.mat"
QMT = "qmt_full_body/full_body_example_data.mat"


def test_fuse_writes_the_devices_orientation_of_a_broad_trial(tmp_path):
    """9D with --mag: ``t``, the sensor's array and ``quat``, exactly the kernel's fusion; the
    orientation is the sensor in the earth frame (BROAD's truth is in it: a few degrees off)."""
    path = require_data(BROAD_TRIAL)
    out = tmp_path / "trial.npz"
    assert cli.main(["fuse", str(path), "-o", str(out), "--mag"]) == 0
    d = np.load(out)
    rec = load_raw(path)
    assert sorted(d.files) == ["imu", "quat", "t"] and np.array_equal(d["t"], rec.t)
    assert np.array_equal(d["quat"], d["imu"])
    want = fusion.fuse(rec.gyr[:, 0], rec.acc[:, 0], rec.mag[:, 0], rate_hz=rec.fs, t=rec.t)
    assert np.array_equal(d["quat"], want)
    ok = rec.movement & np.isfinite(rec.truth[:, 0]).all(axis=1)
    assert np.sqrt(np.mean(quat.angle_deg(d["quat"][ok], rec.truth[ok, 0]) ** 2)) < 3.0


def test_fuse_writes_every_sensor_of_the_qmt_recording(tmp_path, capsys):
    """16 sensors, 6D (the recording has no magnetometer: --mag is refused naming the channel)."""
    path = require_data(QMT)
    out = tmp_path / "qmt.npz"
    assert cli.main(["fuse", str(path), "-o", str(out)]) == 0
    d = np.load(out)
    assert len(d.files) == 17 and "quat" not in d.files and d["head"].shape == (10000, 4)
    assert np.allclose(np.linalg.norm(d["hip"], axis=1), 1.0, atol=1e-5)
    assert cli.main(["fuse", str(path), "-o", str(out), "--mag"]) == 2
    assert "no magnetometer channel (imu_mag)" in capsys.readouterr().err


@pytest.mark.parametrize("drop, words", [("imu_acc", "no imu_acc (accelerometer)"),
                                         ("imu_gyr", "no imu_gyr (gyroscope)")])
def test_fuse_names_a_missing_channel(tmp_path, capsys, drop, words):
    data = {"imu_gyr": np.zeros((50, 3)), "imu_acc": np.tile([0.0, 0.0, 9.81], (50, 1)), "sampling_rate": 100.0}
    del data[drop]
    path = tmp_path / "broken.mat"
    scipy.io.savemat(path, data)
    assert cli.main(["fuse", str(path), "-o", str(tmp_path / "out.npz")]) == 2
    assert words in capsys.readouterr().err
