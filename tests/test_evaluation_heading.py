"""``limbstream eval``'s whole bodies (limbstream.evaluation.body): the joint error per joint kind,
heading correction by the joints (``--heading-correction joints``) and the dump from which every
figure can be recomputed (``--dump``)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from limbstream import calibration, cli, evaluation, quat, wire
from limbstream.evaluation.body import KINDS
from limbstream.heading.joints import kind
from limbstream.joints.convention import JOINT_TABLE
from limbstream.sources.generator import generate

DRIFTING = ["--mounting-deg", "90", "--heading-deg", "180", "--yaw-drift-dps", "0.1"]


def test_every_joint_kind_has_its_line():
    assert {kind(j.name) for table in wire.JOINT_TABLES.values() for j in table} == set(KINDS)
    assert {kind(j.name) for j in JOINT_TABLE} == {"knee", "elbow", "hip", "shoulder", "neck"}


def test_heading_correction_holds_the_joints_of_drifting_sensors():
    """90 s of motion seen through sensors whose headings drift: the joints' error of the
    calibrated reconstruction grows from its first minute to its last; held by the joints it
    grows less, and the body error does not grow for it."""
    motion = generate(90.0, 50.0, seed=3)
    streams = evaluation.streams_of([motion], calibration.SensorModel(90, 180, 0.1, seed=2))
    off, on = (evaluation.evaluate(streams, ["fastsw"], [9e-4], 25, heading=h)[0] for h in (False, True))
    grown = {k: off["joint_kinds"][k]["last"] - off["joint_kinds"][k]["first"] for k in ("knee", "hip")}
    held = {k: on["joint_kinds"][k]["last"] - on["joint_kinds"][k]["first"] for k in ("knee", "hip")}
    assert all(grown[k] > 1.0 for k in grown), off["joint_kinds"]
    assert all(held[k] < 0.6 * grown[k] for k in grown), (grown, held)
    assert on["joint_aad"] < off["joint_aad"] and on["body_aad"] < off["body_aad"] + 0.5, (on, off)
    assert on["icr"] == off["icr"] and on["aad"] == off["aad"]  # the compression is the same


def test_the_dump_recomputes_every_figure(cmu_npz, tmp_path, capsys):
    out = tmp_path / "rows.json"
    code = cli.main(["eval", str(cmu_npz), "--algorithms", "fastsw", "--thresholds", "9e-4", "--max-len", "25",
                     *DRIFTING, "--heading-correction", "joints", "--dump", str(tmp_path), "--json", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "heading correction joints" in text and "its headings held by the joints" in text, text
    [row] = json.loads(out.read_text())
    assert set(row["joint_kinds"]) == {kind(j.name) for j in JOINT_TABLE}  # a paper10 body: no ankles, wrists, lumbar
    assert all(f"{k}s" in text or k == "neck" for k in row["joint_kinds"]), text
    files = sorted(tmp_path.glob("*.npz"))
    assert len(files) == 6, files
    body, joints, per_kind = [], [], {k: [] for k in KINDS}
    for f in files:
        d = np.load(f)
        est, truth = d["estimated"], d["truth"]
        assert est.shape == truth.shape == (len(d["t"]), 10, 4) and list(d["segment_names"])[-1] == "hip"
        assert str(d["heading_correction"]) == "joints"
        ok = np.isfinite(est).all(axis=-1) & np.isfinite(truth).all(axis=-1)
        body.append(quat.angle_deg(est[ok], truth[ok]))
        p, c = d["joint_parent"], d["joint_child"]
        e, tr = np.nan_to_num(est), np.nan_to_num(truth)  # the relative orientations, parent -> child
        err = quat.angle_deg(quat.multiply(quat.conjugate(e[:, p]), e[:, c]),
                             quat.multiply(quat.conjugate(tr[:, p]), tr[:, c]))
        both = ok[:, p] & ok[:, c]
        joints.append(err[both])
        for j, name in enumerate(d["joints"]):
            per_kind[kind(str(name))].append(err[both[:, j], j])
    assert np.concatenate(body).mean() == pytest.approx(row["body_aad"], rel=1e-9)
    assert np.concatenate(joints).mean() == pytest.approx(row["joint_aad"], rel=1e-9)
    for k in row["joint_kinds"]:
        assert np.concatenate(per_kind[k]).mean() == pytest.approx(row["joint_kinds"][k]["mean"], rel=1e-9), k


@pytest.mark.parametrize("argv, message", [
    (["--heading-correction", "joints"], "explicit rows"),
    (["--thresholds", "1e-3,1e-2", "--dump", "{tmp}"], "one row"),
    (["--thresholds", "1e-3", "--algorithms", "fastsw", "--dump", "{tmp}/none"], "not a folder"),
])
def test_cli_refuses_what_it_cannot_do(cmu_npz, tmp_path, capsys, argv, message):
    assert cli.main(["eval", str(cmu_npz), *[a.format(tmp=tmp_path) for a in argv]]) == 2
    err = capsys.readouterr().err
    assert "error" in err and message in err and "Traceback" not in err, err


def test_heading_correction_without_a_sensor_model_says_so(cmu_npz, capsys):
    code = cli.main(["eval", str(cmu_npz), "--algorithms", "fastsw", "--thresholds", "1e-2",
                     "--heading-correction", "joints"])
    captured = capsys.readouterr()
    assert code == 0 and "nothing to act on" in captured.err, captured.err
