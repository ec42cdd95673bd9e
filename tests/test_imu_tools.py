"""The raw-sensor tools: ``limbstream fuse`` (the device's orientation per sample of a raw
recording) and ``limbstream eval`` on raw recordings and with ``--imu raw``."""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from limbstream import cli, quat
from limbstream.evaluation.fusion import fusion_error
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


def test_fuse_and_eval_take_vqfs_precision(tmp_path, capsys):
    """``--vqf-precision single|double``: ``fuse`` writes the kernel's fusion in that precision
    (the default is the firmware's), ``eval`` scores it; an unknown one is refused."""
    path = require_data(BROAD_TRIAL)
    rec = load_raw(path)
    got = {}
    for precision in fusion.VQF_PRECISIONS:
        out = tmp_path / f"{precision}.npz"
        assert cli.main(["fuse", str(path), "-o", str(out), "--mag", "--vqf-precision", precision]) == 0
        got[precision] = np.load(out)["quat"]
        want = fusion.fuse(rec.gyr[:, 0], rec.acc[:, 0], rec.mag[:, 0], rate_hz=rec.fs, t=rec.t, vqf_precision=precision)
        assert np.array_equal(got[precision], want)
    assert not np.array_equal(got["single"], got["double"])
    assert cli.main(["fuse", str(path), "-o", str(tmp_path / "d.npz"), "--mag"]) == 0
    assert np.array_equal(np.load(tmp_path / "d.npz")["quat"], got[fusion.DEFAULT_VQF_PRECISION])
    with pytest.raises(SystemExit):
        cli.main(["fuse", str(path), "-o", str(tmp_path / "x.npz"), "--vqf-precision", "half"])
    assert "invalid choice: 'half'" in capsys.readouterr().err
    scores = {}
    for precision in fusion.VQF_PRECISIONS:
        out = tmp_path / f"{precision}.json"
        assert cli.main(["eval", str(path), "--mag", "--thresholds", "9e-4", "--max-len", "25", "--live-bound", "5",
                         "--vqf-precision", precision, "--json", str(out)]) == 0
        scores[precision] = out.read_text()
    assert scores["single"] != scores["double"]


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


def eval_rows(capsys, *argv) -> dict:
    """``limbstream eval ARGV --thresholds 9e-4 --live-bound 5`` (make run's settings): its one
    row, read back from --json."""
    out = Path(tempfile.mkdtemp()) / "rows.json"
    assert cli.main(["eval", *map(str, argv), "--thresholds", "9e-4", "--live-bound", "5", "--json", str(out)]) == 0
    capsys.readouterr()
    [row] = json.loads(out.read_text())
    return row


def test_eval_on_a_broad_trial_reports_fusion_and_chain_error(capsys):
    """9D: the fusion error is BROAD's total RMSE of the device's own samples (its filter at its
    instants); the chain (points SLERPed) adds at most 0.5 deg at make run's settings; 6D reports
    inclination and heading drift."""
    path = require_data(BROAD_TRIAL)
    rec = load_raw(path)
    row = eval_rows(capsys, path, "--mag")
    q = fusion.fuse(rec.gyr[:, 0], rec.acc[:, 0], rec.mag[:, 0], rate_hz=rec.fs, t=rec.t)
    idx = fusion.device_instants(rec.t)
    want = fusion_error(q[idx], rec.truth[idx, 0], rec.t[idx], rec.movement[idx])
    assert row["fusion_total"] == pytest.approx(want.total_deg, abs=2e-3)  # (the samples sent are float32)
    assert row["fusion_incl"] == pytest.approx(want.inclination_deg, abs=2e-3)
    assert row["fusion_total"] < row["chain_total"] <= row["fusion_total"] + 0.5, row
    assert 0.05 < row["icr"] < 0.5 and row["live_max"] <= 5.0 + 1e-3 and row["fusion_drift"] is None, row
    six = eval_rows(capsys, path)
    assert six["fusion_incl"] == pytest.approx(row["fusion_incl"], abs=0.05)  # 9D's is 6D's turned about z
    assert six["fusion_drift"] is not None and six["fusion_incl"] < six["chain_incl"] < six["fusion_incl"] + 1.0, six


def test_eval_on_the_qmt_recording_has_no_reference(capsys):
    """No reference orientation: compression figures only, and a note that says so."""
    path = require_data(QMT)
    out = Path(tempfile.mkdtemp()) / "rows.json"
    assert cli.main(["eval", str(path), "--thresholds", "9e-4", "--live-bound", "5", "--json", str(out)]) == 0
    err = capsys.readouterr().err
    assert "no reference orientation: no fusion or chain error" in err, err
    [row] = json.loads(out.read_text())
    assert 0 < row["icr"] < 0.5 and row["aad"] < 2.0
    assert all(row[k] is None for k in row if k.startswith(("fusion_", "chain_"))), row
    assert cli.main(["eval", str(path), "--loop-minutes", "1"]) == 2
    assert "--loop-minutes loops motion clips, not raw recordings" in capsys.readouterr().err


def test_eval_with_emulated_raw_sensors_calibrates_and_loops(cmu_npz, capsys):
    """``--imu raw``: sensors strapped at up to 90 deg with headings anywhere, fused on the
    devices, calibrated from the script: the body error is about the ideal fusion's; the fusion
    columns split it into inclination and heading. ``--loop-minutes`` plays the clip longer."""
    row = eval_rows(capsys, cmu_npz, "--imu", "raw", "--mounting-deg", "90", "--heading-deg", "180",
                    "--calibration", "rest,mounting")
    assert row["body_aad"] < 2.0 and row["fusion_incl"] < 2.0 and abs(row["fusion_drift"]) < 1.0, row
    assert row["chain_total"] <= row["fusion_total"] + 0.5, row
    looped = eval_rows(capsys, cmu_npz, "--imu", "raw", "--loop-minutes", "1.5")
    assert looped["body_aad"] < 2.0, looped
