"""The elementary functions VQF calls on every target (firmware_c/src/lsw_math.hpp): within their
specification against float64 (numpy's libm, far more exact than the float results checked), C99's
special values, and VQF in either precision fused with them (the firmware's bits are
tests/test_firmware_imu.py's and tests/test_emulate_firmware.py's)."""
from __future__ import annotations

import ctypes

import numpy as np
import pytest

from limbstream.kernel import fusion
from limbstream.kernel._lib import _lib

_lib.lsw_math_eval.argtypes = [ctypes.c_int, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                               ctypes.c_int]
_lib.lsw_math_eval.restype = ctypes.c_size_t
FUNCTIONS = ("sin", "cos", "tan", "exp", "asin", "acos", "atan2")
REFERENCE = {"sin": np.sin, "cos": np.cos, "tan": np.tan, "exp": np.exp, "asin": np.arcsin, "acos": np.arccos,
             "atan2": lambda x, y: np.arctan2(y, x)}


def evaluate(name: str, x, y=None, double: bool = False) -> np.ndarray:
    """lsw_math's ``name`` at x (atan2: at (y, x)), in double or float (arguments rounded to float)."""
    x = np.ascontiguousarray(x, np.float64)
    y = np.ascontiguousarray(np.zeros_like(x) if y is None else y, np.float64)
    out = np.empty_like(x)
    _lib.lsw_math_eval(FUNCTIONS.index(name), len(x), x.ctypes.data, y.ctypes.data, out.ctypes.data, int(double))
    return out


def ulp_error(name: str, x, y, double: bool) -> float:
    """Largest error in ulps of the result type over the arguments (rounded to that type first)."""
    kind = np.float64 if double else np.float32
    x, y = (np.asarray(v, kind).astype(np.float64) for v in (x, y))
    got = evaluate(name, x, y, double)
    ref = REFERENCE[name](x, y) if name == "atan2" else REFERENCE[name](x)
    scored = np.isfinite(ref) & (np.abs(ref) >= np.finfo(kind).tiny)
    ulp = np.spacing(np.abs(ref[scored]).astype(kind)).astype(np.float64)
    return float(np.max(np.abs(got[scored] - ref[scored]) / ulp))


SPEC = [  # function, argument range, ulps in float, ulps in double (lsw_math.hpp's specification)
    ("sin", 100.0, 2.0, 2.0), ("cos", 100.0, 2.0, 2.0), ("tan", 100.0, 4.0, 3.0), ("exp", 80.0, 2.0, 2.0),
    ("asin", 1.0, 3.0, 3.0), ("acos", 1.0, 3.0, 3.0), ("atan2", 3.0, 3.0, 3.0)]


@pytest.mark.parametrize("name,bound,float_ulps,double_ulps", SPEC)
def test_functions_meet_their_specification(name, bound, float_ulps, double_ulps):
    rng = np.random.default_rng(7)
    x = np.concatenate([rng.uniform(-bound, bound, 200_000), rng.uniform(-0.8, 0.8, 100_000),
                        np.linspace(-bound, bound, 20_001)])
    y = rng.uniform(-3, 3, len(x)) * np.where(rng.random(len(x)) < 0.5, 1.0, 1e-3)
    assert ulp_error(name, x, y, double=False) <= float_ulps
    assert ulp_error(name, x, y, double=True) <= double_ulps


def test_sin_and_cos_stay_close_over_the_pipelines_argument_range():
    """Half a raw step's turn at the pipeline's input range (|gyr| <= 1e6 rad/s at 200 Hz: up to
    4,330 rad): absolute error below 1e-7 up to 12,868."""
    x = np.random.default_rng(3).uniform(-12_868, 12_868, 200_000).astype(np.float32).astype(np.float64)
    for name in ("sin", "cos"):
        assert np.max(np.abs(evaluate(name, x) - REFERENCE[name](x))) < 1e-7


def test_special_values_are_c99s():
    inf, nan = np.inf, np.nan
    for double in (False, True):
        assert np.isnan(evaluate("sin", [inf, -inf, nan], double=double)).all()
        assert np.isnan(evaluate("cos", [inf, nan], double=double)).all()
        assert np.isnan(evaluate("asin", [1.0000001, -2.0, nan], double=double)).all()
        assert np.isnan(evaluate("acos", [1.5, nan], double=double)).all()
        assert list(evaluate("acos", [1.0, -1.0], double=double)) == pytest.approx([0.0, np.pi])
        assert list(evaluate("exp", [0.0, inf, -inf, 1e4, -1e4], double=double)) == [1.0, inf, 0.0, inf, 0.0]
        assert np.isnan(evaluate("exp", [nan], double=double)).all()
        got = evaluate("atan2", [0.0, -0.0, 1.0, -1.0, inf, -inf, inf, 2.0],
                       [0.0, 0.0, 0.0, -0.0, 1.0, 1.0, inf, inf], double=double)
        expect = np.arctan2([0.0, 0.0, 0.0, -0.0, 1.0, 1.0, inf, inf], [0.0, -0.0, 1.0, -1.0, inf, -inf, inf, 2.0])
        np.testing.assert_allclose(got, expect, rtol=1e-7)
        assert np.array_equal(np.signbit(got), np.signbit(expect))
        assert np.isnan(evaluate("atan2", [nan, 1.0], [1.0, nan], double=double)).all()


@pytest.mark.parametrize("precision", fusion.VQF_PRECISIONS)
def test_vqf_runs_in_either_precision(precision):
    """Both of the host library's builds of VQF turn with the gyroscope as it turns and level
    from the accelerometer; the two differ (single keeps VQF's filter states in float)."""
    n, rate = 2000, 200.0
    gyr = np.tile([0.0, 0.0, 0.5], (n, 1))  # 0.5 rad/s about the vertical
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    q = fusion.fuse(gyr, acc, rate_hz=rate, vqf_precision=precision)
    turned = np.angle(np.exp(2j * np.arctan2(q[-1, 3], q[-1, 0])))
    assert turned == pytest.approx(np.angle(np.exp(1j * 0.5 * n / rate)), abs=2e-3)
    other = fusion.fuse(gyr + 0.01, acc, rate_hz=rate, vqf_precision=[p for p in fusion.VQF_PRECISIONS
                                                                       if p != precision][0])
    mine = fusion.fuse(gyr + 0.01, acc, rate_hz=rate, vqf_precision=precision)
    assert not np.array_equal(mine, other)


def test_an_unknown_precision_is_refused():
    with pytest.raises(ValueError, match="vqf_precision must be one of"):
        fusion.imu_settings(200.0, vqf_precision="half")
