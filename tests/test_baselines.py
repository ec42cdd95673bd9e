"""The CPLR and Swing filter baselines (firmware_c/src/cplr.c, swing.c) through limbstream.kernel.

References: brute-force float64 re-implementations written from the definitions in
baselines.h (every decision recomputed from the buffered samples), plus the error guarantees each
algorithm promises, checked on its output alone.
"""

from __future__ import annotations

import ctypes

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from limbstream import kernel

FS = 50.0


def smooth_quaternions(m: int, seed: int, speed: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """(t (m,) s, q (m, 4) float32 scalar-first): a random smooth rotation at 50 Hz."""
    rng = np.random.default_rng(seed)
    omega = np.cumsum(rng.normal(0.0, 0.4, (m, 3)), axis=0)  # rad/s, random walk
    omega = np.clip(omega, -speed * 3, speed * 3)
    r = Rotation.from_rotvec(rng.normal(0, 1, 3))
    rotations = [r]
    for w in omega[1:]:
        r = r * Rotation.from_rotvec(w / FS)
        rotations.append(r)
    q = Rotation.concatenate(rotations).as_quat()[:, [3, 0, 1, 2]]
    sign = np.where(np.cumsum(np.r_[0, np.sum(q[1:] * q[:-1], axis=1) < 0]) % 2, -1.0, 1.0)
    return np.arange(m) / FS, (q * sign[:, None]).astype(np.float32)


def reference(kind: str, t: np.ndarray, y: np.ndarray, threshold: float, max_len: int):
    """Float64 brute force of baselines.h.

    Returns
    -------
    points : list of (sample index, value (D,)).
    first_tie : sample index of the first decision within rounding of the threshold (or len(t)).
    """
    ticks = kernel.to_ticks(t).astype(np.float64)
    y = np.asarray(y, np.float64)
    a_t, a_y = ticks[0], y[0].copy()
    points = [(0, y[0].copy())]
    buf: list[int] = []
    first_tie = len(t)

    def close(end: int):
        nonlocal a_t, a_y
        tr = ticks[buf] - a_t
        yr = y[buf] - a_y
        beta = (tr @ yr) / (tr @ tr)
        if kind == "swing":
            lo = np.max((yr - threshold) / tr[:, None], axis=0)
            hi = np.min((yr + threshold) / tr[:, None], axis=0)
            beta = np.minimum(np.maximum(beta, lo), hi)
        value = a_y + beta * (ticks[end] - a_t)
        points.append((end, value))
        a_t, a_y = ticks[end], value

    for n in range(1, len(t)):
        split = len(buf) >= max_len
        if not split and buf:
            tr = ticks[buf + [n]] - a_t
            yr = y[buf + [n]] - a_y
            if kind == "cplr":
                beta = (tr @ yr) / (tr @ tr)
                ssr = np.sum((yr - tr[:, None] * beta) ** 2)
                split = ssr > threshold
                near = abs(ssr - threshold) < 1e-5 * (np.sum(yr**2) + threshold)
            else:
                lo = np.max((yr[:-1] - threshold) / tr[:-1, None], axis=0)
                hi = np.min((yr[:-1] + threshold) / tr[:-1, None], axis=0)
                gap = np.minimum(
                    hi * tr[-1] - (yr[-1] - threshold), (yr[-1] + threshold) - lo * tr[-1]
                )
                split = bool(np.any(gap < 0))
                near = np.min(np.abs(gap)) < 1e-6
            if near:
                first_tie = min(first_tie, n)
        if split:
            close(n - 1)
            buf = []
        buf.append(n)
    if buf:
        close(len(t) - 1)
    return points, first_tie


@pytest.mark.parametrize("kind", ["cplr", "swing"])
@pytest.mark.parametrize("seed", range(6))
def test_matches_float64_reference(kind, seed):
    """Same points as the float64 brute force, up to the first decision that ties to rounding."""
    t, q = smooth_quaternions(400, seed)
    thresholds = {"cplr": [1e-5, 1e-3, 1e-1], "swing": [1e-3, 1e-2, 5e-2]}[kind]
    identical = 0
    for threshold in thresholds:
        for max_len in (1000, 17):
            msg = f"{kind} seed={seed} TH={threshold} max_len={max_len}"
            seg = kernel.segment(t, q, threshold, max_len, algorithm=kind)
            ref, tie = reference(kind, t, q, threshold, max_len)
            got_index = np.searchsorted(t, seg.t)
            ref_index = np.array([i for i, _ in ref])
            n = min(len(got_index), len(ref_index))
            differ = np.flatnonzero(got_index[:n] != ref_index[:n])
            agree = differ[0] if len(differ) else n
            if agree < n or len(got_index) != len(ref_index):
                assert ref_index[min(agree, len(ref_index) - 1)] >= tie - 1, (
                    f"{msg}: first different point at sample {ref_index[min(agree, n - 1)]}, "
                    f"no near-tie decision before it (first at {tie})"
                )
            else:
                identical += 1
            ref_values = np.array([v for _, v in ref[:agree]])
            err = np.max(np.abs(seg.q[:agree] - ref_values))
            assert err < 1e-4, f"{msg}: point values differ by {err}"
    assert identical >= 4, f"{kind} seed={seed}: only {identical} of 6 runs fully identical"


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("eps", [1e-3, 1e-2, 1e-1])
def test_swing_every_sample_within_eps(seed, eps):
    """The swing filter's guarantee: every sample within eps of the polyline, per component."""
    t, q = smooth_quaternions(500, seed + 10)
    seg = kernel.segment(t, q, eps, 1000, algorithm="swing")
    for d in range(4):
        line = np.interp(t, seg.t, seg.q[:, d])
        err = np.max(np.abs(line - q[:, d]))
        assert err <= eps * (1 + 1e-4) + 2e-6, f"eps={eps} component {d}: deviation {err}"


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("threshold", [1e-5, 1e-3, 1e-1])
def test_cplr_segment_ssr_within_threshold(seed, threshold):
    """CPLR's guarantee: each segment's SSR against its line (anchor -> point) is <= TH."""
    t, q = smooth_quaternions(500, seed + 20)
    seg = kernel.segment(t, q, threshold, 1000, algorithm="cplr")
    index = np.searchsorted(t, seg.t)
    q64 = q.astype(np.float64)
    worst = 0.0
    for k in range(len(index) - 1):
        i0, i1 = index[k], index[k + 1]
        u = (t[i0 + 1 : i1 + 1] - t[i0]) / (t[i1] - t[i0])
        line = seg.q[k] + u[:, None] * (seg.q[k + 1] - seg.q[k])
        ssr = np.sum((q64[i0 + 1 : i1 + 1] - line) ** 2)
        worst = max(worst, ssr / threshold)
    assert worst <= 1 + 1e-3, f"TH={threshold}: a segment's SSR is {worst:.6f} x TH"
    assert len(seg.t) < len(t), f"TH={threshold}: {len(seg.t)} points for {len(t)} samples"


@pytest.mark.parametrize("kind", ["cplr", "swing"])
def test_point_layout(kind):
    t, q = smooth_quaternions(300, 3)
    seg = kernel.segment(t, q, 1e-2, 1000, algorithm=kind)
    assert seg.index is None
    assert seg.n_samples == 300 and seg.rejected == 0
    assert seg.t[0] == t[0] and seg.t[-1] == t[-1], (
        f"first/last point times {seg.t[0]}, {seg.t[-1]}"
    )
    assert np.all(np.isin(seg.t, t)), "every point carries a sample's timestamp"
    assert np.all(np.diff(seg.t) > 0)
    np.testing.assert_array_equal(seg.q[0], q[0].astype(np.float64))
    interior = np.searchsorted(t, seg.t[1:])
    # extrapolated, not copied: most points differ from their samples
    differs = np.any(seg.q[1:] != q[interior], axis=1)
    assert differs.mean() > 0.5, f"only {differs.mean():.2f} of points differ from the samples"
    assert 0 < seg.icr < 0.5, f"ICR {seg.icr}"


@pytest.mark.parametrize("kind", ["cplr", "swing"])
def test_threshold_zero_keeps_every_sample(kind):
    t, q = smooth_quaternions(200, 4)
    seg = kernel.segment(t, q, 0.0, 1000, algorithm=kind)
    assert len(seg.t) == len(t), f"{len(seg.t)} points for {len(t)} samples"
    err = np.max(np.abs(seg.q - q))
    assert err < 1e-5, f"points deviate from the samples by {err}"


@pytest.mark.parametrize("kind", ["cplr", "swing"])
def test_larger_threshold_fewer_points(kind):
    t, q = smooth_quaternions(600, 5)
    counts = [
        len(kernel.segment(t, q, th, 1000, algorithm=kind).t) for th in (1e-6, 1e-4, 1e-2, 1.0)
    ]
    assert counts == sorted(counts, reverse=True) and counts[0] > counts[-1], counts


@pytest.mark.parametrize("kind", ["cplr", "swing"])
def test_max_len_caps_segments(kind):
    t, q = smooth_quaternions(300, 6)
    seg = kernel.segment(t, q, 1e3, 25, algorithm=kind)
    steps = np.diff(np.searchsorted(t, seg.t))
    assert steps.max() <= 25 and steps.min() >= 1, f"segment lengths {steps.min()}..{steps.max()}"


@pytest.mark.parametrize("kind", ["cplr", "swing"])
def test_bad_samples_rejected_like_fastsw(kind):
    """NaN rows and non-increasing times are rejected and leave the result unchanged."""
    t, q = smooth_quaternions(300, 7)
    clean = kernel.segment(t, q, 1e-3, 1000, algorithm=kind)
    bad_t = np.insert(t, [50, 120, 121], [t[49], t[119] - 0.001, t[120] + 0.0])
    bad_q = np.insert(q, [50, 120, 121], [q[49], q[119], q[120]], axis=0)
    bad_q[200] = np.nan  # after insertion: a NaN sample replacing a real one
    keep, last = [], -np.inf  # what the kernel should accept: finite rows, time increasing
    for i in range(len(bad_t)):
        if np.all(np.isfinite(bad_q[i])) and bad_t[i] > last:
            keep.append(i)
            last = bad_t[i]
    expected = kernel.segment(bad_t[keep], bad_q[keep], 1e-3, 1000, algorithm=kind)
    got = kernel.segment(bad_t, bad_q, 1e-3, 1000, algorithm=kind)
    assert got.rejected == 4, f"rejected {got.rejected}, expected 4"
    np.testing.assert_array_equal(got.t, expected.t)
    np.testing.assert_array_equal(got.q, expected.q)
    assert len(clean.t) > 2


def test_bad_dim_is_a_status_not_a_crash():
    lib = kernel._lib
    for name in ("cplr", "swing"):
        init = getattr(lib, f"{name}_init")
        state = ctypes.create_string_buffer(getattr(lib, f"{name}_state_size")())
        for dim in (0, kernel.MAX_DIM + 1):
            settings = kernel.Settings(1e-2, 1000, dim)
            assert init(state, ctypes.byref(settings)) == -1, f"{name}_init accepted dim {dim}"
    with pytest.raises(ValueError, match="dim"):
        kernel.segment(np.arange(3.0), np.zeros((3, kernel.MAX_DIM + 1)), 1e-2, algorithm="cplr")
