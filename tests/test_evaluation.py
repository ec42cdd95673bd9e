"""limbstream.evaluation: the paper's protocol (ICR, AAD, p99, max, segment-point deviation).

The oracle rebuilds every stream on its own with scipy (Slerp, Rotation.magnitude) and pools the
deviations in plain Python; it shares no code with the evaluator's vectorised reconstruction.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from support.sw_oracle import live_sliding_window, live_view

from limbstream import cli, evaluation, kernel
from limbstream.sources import load


def _rotation(q: np.ndarray) -> Rotation:
    """(n, 4) scalar-first -> Rotation (scipy normalises)."""
    return Rotation.from_quat(np.asarray(q, np.float64)[:, [1, 2, 3, 0]])


def oracle(
    streams: list[evaluation.Stream], algorithm: str, threshold: float, max_len: int = 1000
) -> dict:
    """Brute force: per stream, scipy Slerp at every timestamp; deviations pooled over all streams."""
    rec_dev, point_dev = [], []
    n_points = n_samples = 0
    for s in streams:
        seg = kernel.segment(s.t, s.q, threshold, max_len, algorithm=algorithm)
        n_points += len(seg.t)
        n_samples += len(s.t)
        truth = _rotation(s.q)
        if len(seg.t) == 1:
            recon = _rotation(np.repeat(seg.q, len(s.t), axis=0))
        else:
            recon = Slerp(seg.t, _rotation(seg.q))(np.clip(s.t, seg.t[0], seg.t[-1]))
        rec_dev.extend(np.degrees((truth.inv() * recon).magnitude()))
        for t_point, q_point in zip(seg.t, seg.q):
            i = int(np.flatnonzero(s.t == t_point)[0])
            point_dev.append(np.degrees((truth[i].inv() * _rotation(q_point[None])[0]).magnitude()))
    dev = np.array(rec_dev)
    return {
        "icr": n_points / n_samples,
        "aad": dev.mean(),
        "std": dev.std(),
        "p99": np.percentile(dev, 99),
        "max": dev.max(),
        "point_aad": float(np.mean(point_dev)),
        "point_max": float(np.max(point_dev)),
    }


def synthetic_streams(count: int, m: int, seed: int) -> list[evaluation.Stream]:
    """Random smooth rotations with jittered timestamps (not a common time base)."""
    rng = np.random.default_rng(seed)
    streams = []
    for j in range(count):
        t = np.cumsum(rng.uniform(0.015, 0.025, m)) + rng.uniform(0, 100)
        rotvec = np.cumsum(np.cumsum(rng.normal(0, 0.02, (m, 3)), axis=0), axis=0)
        q = Rotation.from_rotvec(rotvec).as_quat()[:, [3, 0, 1, 2]]
        q *= np.where(np.cumsum(np.r_[0, np.sum(q[1:] * q[:-1], axis=1) < 0]) % 2, -1.0, 1.0)[
            :, None
        ]
        streams.append(evaluation.Stream(t, q, f"synthetic/{j}"))
    return streams


@pytest.fixture(scope="module")
def cmu_motions(cmu_npz):
    return load(cmu_npz)


def _compare(rows, expected, label):
    for field in ("aad", "std", "p99", "max", "point_aad", "point_max"):
        assert rows[field] == pytest.approx(expected[field], abs=2e-4), (
            f"{label} {field}: evaluator {rows[field]!r}, oracle {expected[field]!r}"
        )
    assert rows["icr"] == pytest.approx(expected["icr"], rel=1e-12), f"{label} icr"


@pytest.mark.parametrize("algorithm", ["fastsw", "cplr", "swing"])
def test_matches_oracle_on_cmu(cmu_motions, algorithm):
    streams = evaluation.streams_of(cmu_motions[1:3])  # two clips, 20 streams
    thresholds = {
        "fastsw": [0.0, 1e-4, 1e-2, 1.0],
        "cplr": [1e-4, 1e-2, 1.0],
        "swing": [1e-3, 1e-2, 1e-1],
    }[algorithm]
    rows = evaluation.evaluate(streams, [algorithm], thresholds)
    for row, th in zip(rows, thresholds):
        assert row["algorithm"] == algorithm and row["threshold"] == th
        _compare(row, oracle(streams, algorithm, th), f"{algorithm} TH={th}")


@pytest.mark.parametrize("algorithm", ["sw", "cplr", "swing"])
def test_matches_oracle_on_jittered_streams(algorithm):
    """Streams of different lengths and time bases, pooled in one vectorised pass."""
    streams = synthetic_streams(3, 250, seed=1) + synthetic_streams(2, 97, seed=2)
    for th in (1e-3, 3e-2):
        row = evaluation.evaluate(streams, [algorithm], [th])[0]
        _compare(row, oracle(streams, algorithm, th), f"{algorithm} TH={th}")


def test_fastsw_reference_numbers(cmu_motions):
    """Independent brute-force SW on all CMU clips at TH = 1e-2: ICR 0.099, AAD 2.43 deg, max 10.9 deg."""
    row = evaluation.evaluate(cmu_motions, ["fastsw"], [1e-2])[0]
    assert row["icr"] == pytest.approx(0.099, abs=0.001), row
    assert row["aad"] == pytest.approx(2.43, abs=0.01), row
    assert row["max"] == pytest.approx(10.9, abs=0.05), row
    assert row["point_max"] < 1e-4, f"fastSW points are samples, deviation {row['point_max']}"


def test_baseline_points_drift_as_icr_falls(cmu_motions):
    """CPLR's and the Swing filter's points deviate more the fewer there are; fastSW's never."""
    thresholds = np.logspace(-6, 3, 25)
    rows = evaluation.evaluate(cmu_motions[:3], ["fastsw", "cplr", "swing"], thresholds)
    targets = (0.5, 0.25, 0.1, 0.05, 0.02)
    fast = evaluation.at_icr(rows, "fastsw", targets)
    assert max(r["point_max"] for r in fast) < 1e-4, fast
    for name in ("cplr", "swing"):
        point_aad = [r["point_aad"] for r in evaluation.at_icr(rows, name, targets)]
        assert all(np.diff(point_aad) > 0), f"{name} point AAD at ICR {targets}: {point_aad}"
        assert point_aad[-1] > 10.0, f"{name} point AAD at ICR 0.02: {point_aad[-1]:.2f} deg"


def test_at_icr_interpolates_in_log_icr():
    rows = [
        {
            "algorithm": "x",
            "threshold": th,
            "icr": icr,
            "aad": aad,
            "std": 0.0,
            "p99": 0.0,
            "max": 0.0,
            "point_aad": 0.0,
            "point_max": 0.0,
        }
        for th, icr, aad in [
            (1e-4, 0.4, 1.0),
            (1e-3, 0.1, 3.0),
            (1e-3, 0.1, 5.0),
            (1e-2, 0.025, 9.0),
        ]
    ]
    out = evaluation.at_icr(rows, "x", (0.2, 0.05, 0.5, 0.01))
    assert out[0]["aad"] == pytest.approx(1.0 + 3.0 * 0.5), out[
        0
    ]  # halfway in log ICR; ties averaged to 4
    assert out[0]["threshold"] == pytest.approx(10**-3.5), out[0]
    assert out[1]["aad"] == pytest.approx(4.0 + 5.0 * 0.5), out[1]
    assert np.isnan(out[2]["aad"]) and np.isnan(out[3]["aad"]), "outside the swept ICR range"


RAW_SENSOR_MEASURES = [k for k in evaluation.MEASURES if k.startswith(("fusion_", "chain_"))]


def test_bad_samples_are_left_out():
    """A NaN sample and a time step backwards: rejected by the kernels, not a NaN result."""
    streams = synthetic_streams(2, 200, seed=3)
    q = streams[0].q.copy()
    q[40] = np.nan
    t = streams[0].t.copy()
    t[90] = t[88]
    broken = [evaluation.Stream(t, q, "broken"), streams[1]]
    rows = evaluation.evaluate(broken, ["fastsw", "cplr"], [1e-3], live_bound_deg=[0.0])
    for predictor in evaluation.PREDICTORS:
        rows += evaluation.evaluate(broken, ["fastsw"], [1e-3], live_bound_deg=[5.0], predictor=predictor)
    for r in rows:
        skipped = ("body_aad", "joint_aad", "pos_cm", *RAW_SENSOR_MEASURES)
        assert all(np.isfinite(r[k]) for k in evaluation.MEASURES if k not in skipped), r
        assert np.isnan(r["body_aad"]), "no sensor model: no body error"
        assert np.isnan(r["joint_aad"]) and np.isnan(r["pos_cm"]), "streams of no body's segments: no joint error"
        assert all(np.isnan(r[k]) for k in RAW_SENSOR_MEASURES), "no raw sensors: no fusion or chain error"
        assert 0 < r["icr"] < 1, r
    assert all(r["live_max"] <= 5.002 for r in rows[2:]), rows[2:]
    plain = evaluation.evaluate(broken, ["fastsw"], [1e-3])[0]  # no live bounds: no live error
    assert plain["predictor"] is None and np.isnan(plain["live_aad"]) and plain["icr"] == rows[0]["icr"]


def test_thresholds_are_the_papers():
    th = evaluation.THRESHOLDS
    assert len(th) == 206 and th[0] == 0.0
    assert th[1] == pytest.approx(1e-6) and th[-1] == pytest.approx(1e3)
    assert np.allclose(np.diff(np.log10(th[1:])), 9 / 204)


def test_cli_writes_table_json_and_plot(cmu_npz, tmp_path, capsys):
    out_json, out_png = tmp_path / "rows.json", tmp_path / "fig.png"
    code = cli.main(
        [
            "eval",
            str(cmu_npz),
            "--algorithms",
            "fastsw,swing",
            "--thresholds",
            "0,1e-2,1",
            "--json",
            str(out_json),
            "--plot",
            str(out_png),
        ]
    )
    text = capsys.readouterr().out
    assert code == 0, text
    assert "60 streams" in text and "fastsw" in text and "swing" in text, text
    main, _, per_joint = text.partition("joint error per joint")
    table = [line.split() for line in main.splitlines() if line.startswith(("fastsw ", "swing "))]
    assert len(table) == 6 and all(line[-6:-2] == ["–"] * 4 for line in table), text  # no live error, no body
    assert all(float(line[-2]) >= 0 and float(line[-1]) >= 0 for line in table), text  # joint and position errors
    per_joint, _, positions = per_joint.partition("joint positions")
    assert len([line for line in per_joint.splitlines() if line.startswith(("fastsw ", "swing "))]) == 6 * 5, text
    assert len([line for line in positions.splitlines() if line.startswith(("fastsw ", "swing "))]) == 6 * 8, text
    assert "  –" in text and "does not apply to the row" in text and "nan" not in text, text
    assert "  AAD (deg)" in text and "  ICR  " in text, "a legend under the table"
    rows = json.loads(out_json.read_text())
    assert len(rows) == 6, rows
    assert all(list(r) == [*evaluation.KEYS, "joint_kinds", "positions"] for r in rows), rows[0]
    fast = next(r for r in rows if r["algorithm"] == "fastsw" and r["threshold"] == 1e-2)
    assert fast["icr"] == pytest.approx(0.099, abs=0.001), fast
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_cli_table_at_icr(cmu_npz, capsys):
    code = cli.main(["eval", str(cmu_npz), "--algorithms", "fastsw,cplr", "--max-len", "1000"])
    text = capsys.readouterr().out
    assert code == 0, text
    lines = [ln.split() for ln in text.splitlines() if ln.startswith(("fastsw ", "cplr "))]
    assert [(ln[0], ln[1], float(ln[2])) for ln in lines] == [
        (a, "0", c) for a in ("fastsw", "cplr") for c in evaluation.ICR_TARGETS
    ], text
    assert 2.2 < float(lines[1][4]) < 2.6, f"fastSW AAD at ICR 0.10: {lines[1]}"
    assert "does not apply to the row" in text, "the same legend as with --thresholds"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["eval", "/no/such/file.npz"], "no such file"),
        (["eval", "{npz}", "--json", "/no/such/dir/out.json"], "does not exist"),
        (["eval", "{npz}", "--plot", "{tmp}/fig.svg"], ".png"),
    ],
)
def test_cli_bad_paths_exit_2(cmu_npz, tmp_path, capsys, argv, message):
    argv = [a.format(npz=cmu_npz, tmp=tmp_path) for a in argv]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "error" in err and message in err and "Traceback" not in err, err


@pytest.mark.parametrize("argv", [
    ["eval", "x.npz", "--algorithms", "bogus"],
    ["eval", "x.npz", "--thresholds", "-1"],
    ["eval", "x.npz", "--thresholds", "abc"],
    ["eval", "x.npz", "--thresholds", "1e-2", "1e-3"],  # one list syntax: A,B
    ["eval", "x.npz", "--calibration", "mounting"],
    ["eval", "x.npz", "--max-len", "0"],
    ["eval", "x.npz", "--live-bound", "-1"],
    ["eval", "x.npz", "--live-bound", "200"],
    ["eval", "x.npz", "--live-bound", "nan"],
    ["eval", "x.npz", "--live-bound", "five"],
    ["eval", "x.npz", "--predictor", "gyro"],
])
def test_cli_bad_arguments_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "error" in err and "Traceback" not in err, err


# ----------------------------------------------------------------------------- live mode


def live_oracle(streams: list[evaluation.Stream], threshold: float, max_len: int, bound: float,
                predictor: str) -> dict:
    """Brute force: the oracle's points (tests/sw_oracle.py, scipy rotations) and the live error of
    every sample from them, pooled; plain rows (bound 0) are plain fastSW's points, held or with
    the rate through the sample they are emitted at (rate) or the point before (slope)."""
    errors, n_points, n_samples = [], 0, 0
    for s in streams:
        if bound > 0:
            points, known, omega = live_sliding_window(s.t, s.q, threshold, max_len, bound, predictor)
        else:
            points = kernel.segment(s.t, s.q, threshold, max_len).index
            known = np.r_[0, np.minimum(points[1:] + 1, len(s.t))]
            omega = np.zeros((len(points), 3))
            for k in range(1, len(points)):
                other = known[k] if predictor == "rate" else points[k - 1]  # the sample it passes through
                if predictor != "hold" and known[k] < len(s.t):
                    step = (_rotation(s.q[[points[k]]]).inv() * _rotation(s.q[[other]])).as_rotvec()[0]
                    phi = np.linalg.norm(step)
                    omega[k] = step / phi * 2 * np.tan(phi / 2) / (s.t[other] - s.t[points[k]])
        errors.append(live_view(s.t, s.q, points, known, omega))
        n_points += len(points)
        n_samples += len(s.t)
    err = np.concatenate(errors)
    return {"icr": n_points / n_samples, "live_aad": err.mean(), "live_p99": np.percentile(err, 99),
            "live_max": err.max()}


@pytest.mark.parametrize("predictor", evaluation.PREDICTORS)
def test_live_rows_match_the_oracle(cmu_motions, predictor):
    """ICR and live error of every (threshold, bound) row equal the brute-force oracle's: the C
    kernel for the live rule with ``rate``, simulate_live for ``slope`` and ``hold``, and the
    plain rules' points with each predictor."""
    streams = evaluation.streams_of(cmu_motions[1:3])  # two clips, 20 streams
    rows = evaluation.evaluate(streams, ["fastsw"], [1e-3, 1e-2], 25, [0.0, 5.0, 10.0], predictor)
    for row in rows:
        want = live_oracle(streams, row["threshold"], 25, row["live_bound_deg"], predictor)
        label = f"{predictor} TH={row['threshold']} bound={row['live_bound_deg']}"
        assert row["predictor"] == predictor and list(row) == [*evaluation.KEYS, "joint_kinds", "positions"], label
        assert row["icr"] == pytest.approx(want["icr"], rel=2e-3), label
        for field in ("live_aad", "live_p99", "live_max"):
            assert row[field] == pytest.approx(want[field], rel=2e-3, abs=2e-3), f"{label} {field}"
        if row["live_bound_deg"] > 0:
            assert row["live_max"] <= row["live_bound_deg"] + 0.002, label


def test_simulated_rate_rule_is_the_kernels(cmu_motions):
    """simulate_live with the rate predictor (float64) makes the C kernel's points: the slope and
    hold rows differ from it in the rates only."""
    same = total = 0
    for s in evaluation.streams_of(cmu_motions)[::3]:
        for threshold, bound in ((1e-3, 5.0), (1e-2, 2.0), (1e-2, 10.0)):
            index, known, omega = evaluation.simulate_live(s.t, s.q, threshold, 25, bound, "rate")
            got = kernel.segment(s.t, s.q, threshold, 25, live_bound_deg=bound)
            same += len(np.intersect1d(index, got.index))
            total += len(np.union1d(index, got.index))
            if np.array_equal(index, got.index):
                assert np.array_equal(known, got.known_from)
                assert np.allclose(omega, got.omega, rtol=1e-3, atol=1e-3)
    assert same / total >= 0.995, f"{same}/{total}"


def test_live_reference_numbers(cmu_motions):
    """CMU clips, max_len 25, TH 1e-2, live bound 5 degrees, rate: ICR 0.196 and every sample
    within 5 degrees (brute-force prototype of the rule: 0.198); plain fastSW held: 12.4 deg mean,
    55 deg p99."""
    live, plain = evaluation.evaluate(cmu_motions, ["fastsw"], [1e-2], 25, [5.0, 0.0], "rate")
    assert live["icr"] == pytest.approx(0.1955, abs=0.001) and live["icr"] < 0.198, live
    assert live["live_max"] <= 5.002 and live["aad"] == pytest.approx(1.14, abs=0.01), live
    held = evaluation.evaluate(cmu_motions, ["fastsw"], [1e-2], 25, [0.0], "hold")[0]
    assert held["live_aad"] == pytest.approx(12.4, abs=0.1) and held["live_p99"] == pytest.approx(55.3, abs=0.3), held
    assert plain["icr"] == held["icr"] and plain["live_p99"] < held["live_p99"], (plain, held)


def test_frontier_keeps_the_best_aad_per_icr():
    rows = [{"icr": icr, "aad": aad, "live_max": mx} for icr, aad, mx in
            [(0.1, 2.0, 4.0), (0.2, 1.5, 4.9), (0.15, 2.5, 3.0), (0.3, 1.6, 2.0), (0.25, 1.0, 9.0), (0.4, 0.5, 5.0)]]
    icr, aad = evaluation.frontier(rows, 5.0)
    assert icr.tolist() == [0.1, 0.2, 0.4] and aad.tolist() == [2.0, 1.5, 0.5]
    assert evaluation.frontier(rows, None)[0].tolist() == [0.1, 0.2, 0.25, 0.4]


@pytest.mark.slow
def test_cli_live_bounds_json_table_and_frontier(cmu_npz, tmp_path, capsys):
    out_json, out_png = tmp_path / "live.json", tmp_path / "frontier.png"
    code = cli.main(["eval", str(cmu_npz), "--live-bound", "0,5", "--max-len", "25", "--thresholds", "1e-2",
                     "--predictor", "slope", "--json", str(out_json), "--plot", str(out_png)])
    text = capsys.readouterr().out
    assert code == 0, text
    rows = json.loads(out_json.read_text())
    assert [(r["algorithm"], r["live_bound_deg"], r["predictor"]) for r in rows] == [
        ("fastsw", 0.0, "slope"), ("fastsw", 5.0, "slope")], rows
    assert rows[1]["live_max"] <= 5.002 < rows[0]["live_max"], rows
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    code = cli.main(["eval", str(cmu_npz), "--live-bound", "5", "--max-len", "25"])
    text = capsys.readouterr().out
    lines = [ln.split() for ln in text.splitlines() if ln.startswith("fastsw ")]
    assert code == 0 and [(ln[1], ln[2]) for ln in lines][2] == ("5", "0.2500"), text


@pytest.mark.parametrize("argv, message", [
    (["eval", "{npz}", "--live-bound", "5", "--algorithms", "fastsw,cplr"], "fastsw"),
])
def test_cli_live_bound_needs_fastsw(cmu_npz, capsys, argv, message):
    assert cli.main([a.format(npz=cmu_npz) for a in argv]) == 2
    err = capsys.readouterr().err
    assert "error" in err and message in err and "Traceback" not in err, err


# ----------------------------------------------------------------------------- tables and notes


def test_table_columns_legend_and_dashes():
    """A table says each column's name and unit, shows – where a value does not apply (None,
    NaN), and its legend lists every column with its unit and meaning."""
    from limbstream.evaluation.table import DASH, Column, render
    columns = [Column("name", "what", "", "the thing", ""), Column("err", "error", "deg", "how far off", ".2f")]
    text = render(columns, [{"name": "a", "err": 1.234}, {"name": "b", "err": float("nan")}, {"name": "c"}])
    lines = text.splitlines()
    assert lines[0].split() == ["what", "error"] and lines[1].split() == ["(deg)"], text
    assert [ln.split() for ln in lines[3:6]] == [["a", "1.23"], ["b", DASH], ["c", DASH]], text
    assert "  error (deg)  how far off" in text and f"  {DASH}" in text and "does not apply" in text, text


def test_progress_speaks_only_on_long_runs():
    from limbstream.evaluation.table import Progress
    out: list[str] = []
    quick = Progress("rows", out.append, after_s=60.0)
    for k in range(1, 11):
        quick(k, 10)
    assert out == []
    slow = Progress("rows", out.append, after_s=0.0, every_s=0.0)
    slow(3, 10)
    assert out and out[0].startswith("rows 3/10 (30 %)") and "left" in out[0], out


def test_cli_notes_what_a_sensor_model_adds_and_a_calibration_without_one(cmu_npz, capsys):
    assert cli.main(["eval", str(cmu_npz), "--thresholds", "1e-2", "--algorithms", "fastsw",
                     "--calibration", "rest"]) == 0
    err = capsys.readouterr().err
    assert "--calibration rest has nothing to act on without a sensor model" in err, err
    assert cli.main(["eval", str(cmu_npz), "--thresholds", "1e-2", "--algorithms", "fastsw",
                     "--mounting-deg", "30", "--calibration", "rest"]) == 0
    captured = capsys.readouterr()
    assert "calibration script" in captured.err and "48,510 samples instead of 30,510" in captured.err, captured.err
    row = next(ln.split() for ln in captured.out.splitlines() if ln.startswith("fastsw "))
    body = [c.key for c in evaluation.report.EVAL_COLUMNS].index("body_aad")
    assert row[body] != "–", captured.out  # the body error, after the rest calibration
