"""Declarations of the C kernels' library (``limbstream._kernels``, built from ``firmware_c/``):
its functions' signatures, the structs the bindings share with it (their sizes checked against
the library's at import), and the conversions every binding uses (seconds to ticks, settings,
body rates)."""
from __future__ import annotations

import ctypes
from typing import Any
import importlib.machinery
from pathlib import Path

import numpy as np

from limbstream import quat, wire

TICK_HZ = 1_000_000.0
"""Kernel ticks per second used by the bindings (microseconds)."""

NONE, POINT, REJECTED = 0, 1, 2
"""FastswStatus values (fastsw.h)."""


def _load_library() -> ctypes.CDLL:
    here = Path(__file__).resolve().parent.parent  # limbstream/
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        candidate = here / f"_kernels{suffix}"
        if candidate.exists():
            return ctypes.CDLL(str(candidate))
    raise ImportError(
        f"limbstream C kernels not built in {here}: run `pip install -e .` in the repository"
    )


_lib = _load_library()
MAX_DIM: int = _lib.fastsw_max_dim()


class Settings(ctypes.Structure):
    """FastswSettings: SSR threshold, max segment length (samples), dimension D, live rule bound
    (degrees; 0 off)."""

    _fields_ = [("threshold", ctypes.c_float), ("max_len", ctypes.c_uint32), ("dim", ctypes.c_uint32),
                ("live_bound_deg", ctypes.c_float)]


class BatchOut(ctypes.Structure):
    """FastswBatchOut (fastsw_batch.h): optional per-point outputs of a batch run."""

    _fields_ = [("index", ctypes.c_void_p), ("points", ctypes.c_void_p), ("call", ctypes.c_void_p),
                ("rates", ctypes.c_void_p)]


class Point(ctypes.Structure):
    """FastswPoint: a segment point (sample index, tick, value)."""

    _fields_ = [("index", ctypes.c_uint32), ("t", ctypes.c_uint32), ("y", ctypes.c_float * MAX_DIM)]


_u32p = np.ctypeslib.ndpointer(np.uint32, flags="C_CONTIGUOUS")
_f32p = np.ctypeslib.ndpointer(np.float32, flags="C_CONTIGUOUS")
_u8p = np.ctypeslib.ndpointer(np.uint8, flags="C_CONTIGUOUS")
_sizep = ctypes.POINTER(ctypes.c_size_t)

_lib.fastsw_state_size.restype = ctypes.c_size_t
_lib.sw_state_size.restype = ctypes.c_size_t
_lib.fastsw_init.argtypes = [ctypes.c_void_p, ctypes.POINTER(Settings)]
_lib.fastsw_init.restype = ctypes.c_int
_lib.fastsw_update.argtypes = [ctypes.c_void_p, ctypes.c_uint32, _f32p, ctypes.POINTER(Point)]
_lib.fastsw_update.restype = ctypes.c_int
_lib.fastsw_flush.argtypes = [ctypes.c_void_p, ctypes.POINTER(Point)]
_lib.fastsw_flush.restype = ctypes.c_int
_lib.fastsw_retune.argtypes = [ctypes.c_void_p, ctypes.POINTER(Settings)]
_lib.fastsw_retune.restype = ctypes.c_int
_lib.fastsw_point_rate.argtypes = [ctypes.c_void_p, _f32p]
_lib.fastsw_point_rate.restype = None
_lib.fastsw_segment.argtypes = [ctypes.POINTER(Settings), _u32p, _f32p, ctypes.c_size_t,
                                ctypes.POINTER(BatchOut), _sizep]
_lib.fastsw_segment.restype = ctypes.c_size_t
_lib.sw_segment.argtypes = [
    ctypes.c_void_p, ctypes.POINTER(Settings), _u32p, _f32p, ctypes.c_size_t, _u32p, _sizep,
]
_lib.sw_segment.restype = ctypes.c_size_t
_lib.fastsw_update_many.argtypes = [
    ctypes.c_void_p, ctypes.c_size_t, _u32p, _f32p, _u8p, ctypes.c_void_p, ctypes.c_void_p,
]
_lib.fastsw_update_many.restype = ctypes.c_size_t


class BankWire(ctypes.Structure):
    """LswBankWire (lsw_bank.h): pointers to the wire fields of a bank's streams."""

    _fields_ = [("stream", ctypes.c_void_p), ("seq", ctypes.c_void_p), ("base", ctypes.c_void_p),
                ("sample", ctypes.c_void_p), ("t_us", ctypes.c_void_p), ("rate", ctypes.c_void_p),
                ("ring", ctypes.c_uint32), ("stride", ctypes.c_uint32)]


_lib.lsw_bank_update.argtypes = [
    ctypes.c_void_p, ctypes.c_size_t, _u32p, _f32p, _u8p, ctypes.c_void_p, ctypes.c_void_p,
    ctypes.POINTER(BankWire), ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
]
_lib.lsw_bank_update.restype = ctypes.c_size_t

_lib.cplr_segment.argtypes = [ctypes.POINTER(Settings), _u32p, _f32p, ctypes.c_size_t, ctypes.c_void_p, _sizep]
_lib.cplr_segment.restype = ctypes.c_size_t
_lib.swing_segment.argtypes = [ctypes.POINTER(Settings), _u32p, _f32p, ctypes.c_size_t, ctypes.c_void_p, _sizep]
_lib.swing_segment.restype = ctypes.c_size_t


class _Sync(ctypes.Structure):
    """LswSync (lsw_clock.h)."""

    _fields_ = [(name, ctypes.c_void_p) for name in ("a", "b", "ref", "c", "c_local", "step", "ever", "stepped")] + [
        ("slew", ctypes.c_double)]


_lib.lsw_stamp.argtypes = [ctypes.POINTER(_Sync), ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
_lib.lsw_stamp.restype = ctypes.c_size_t

GRID_HISTORY, GRID_TRUTH, GRID_JITTER = 16, 512, 500
"""LSW_GRID_HISTORY, LSW_GRID_TRUTH, LSW_GRID_JITTER (lsw_grid.h)."""


class GridSettings(ctypes.Structure):
    """LswGridSettings (lsw_grid.h): what every device of a grid bank shares."""

    _fields_ = [(name, ctypes.c_double) for name in ("period_us", "hold_us", "late_us", "early_us", "phase_gain",  # type: ignore[assignment]  # fields of mixed types
                                                     "offset_us")] + [
        ("axes", ctypes.c_double * 4), ("rise_after", ctypes.c_uint32), ("truth", ctypes.c_uint32)]


class GridDevice(ctypes.Structure):
    """LswGridDevice (lsw_grid.h): one device's history, grid and truth samples."""

    _fields_ = [("hist_t", ctypes.c_double * GRID_HISTORY), ("hist_q", (ctypes.c_double * 4) * GRID_HISTORY),  # type: ignore[assignment]  # fields of mixed types
                ("truth_t", ctypes.c_int64 * GRID_TRUTH), ("truth_a", ctypes.c_double * GRID_TRUTH),
                ("truth_q", (ctypes.c_float * 4) * GRID_TRUTH), ("jitter", ctypes.c_float * GRID_JITTER)] + [
        (name, ctypes.c_double) for name in ("instant", "anchor", "shift", "truth_since")] + [
        (name, ctypes.c_int64) for name in ("last_t", "held", "truth_dropped")] + [
        (name, ctypes.c_uint32) for name in ("hist_len", "hist_head", "truth_len", "jitter_len", "jitter_head",
                                             "no_rise", "quiet")] + [
        (name, ctypes.c_uint8) for name in ("has_instant", "has_anchor", "online")] + [("pad", ctypes.c_uint8 * 5)]


class SvrTracker(ctypes.Structure):
    """LswSvrTracker (lsw_slimevr.h): a SlimeVR tracker's link counters."""

    _fields_ = [(name, ctypes.c_int64) for name in ("last_number", "lost", "packets", "arrived")] + [  # type: ignore[assignment]  # fields of mixed types
        ("last_seen", ctypes.c_double), ("online", ctypes.c_uint32), ("pad", ctypes.c_uint32)]


class SvrRoute(ctypes.Structure):
    """LswSvrRoute (lsw_slimevr.h): rotations of (ip, port, sensor) go to device ``slot``."""

    _fields_ = [("tracker", ctypes.POINTER(SvrTracker)), ("ip", ctypes.c_uint32), ("port", ctypes.c_uint16),
                ("sensor", ctypes.c_uint8), ("pad", ctypes.c_uint8), ("slot", ctypes.c_uint32),
                ("pad2", ctypes.c_uint32)]


SVR_MAX_DATAGRAM = 2048
"""LSW_SVR_MAX_DATAGRAM (lsw_slimevr.h)."""


class SvrSlow(ctypes.Structure):
    """LswSvrSlow (lsw_slimevr.h): a datagram left to Python."""

    _fields_ = [("data", ctypes.c_uint8 * SVR_MAX_DATAGRAM), ("len", ctypes.c_uint32), ("ip", ctypes.c_uint32),
                ("port", ctypes.c_uint16), ("ready", ctypes.c_uint16), ("t_us", ctypes.c_double)]


_vp, _d, _sz, _u32 = ctypes.c_void_p, ctypes.c_double, ctypes.c_size_t, ctypes.c_uint32
for _name, _args, _res in (
        ("lsw_grid_reset", [_vp], None),
        ("lsw_grid_push", [_vp, _vp, _d, _vp, _d], None),
        ("lsw_grid_tick", [_vp, _vp, _sz, _d, _vp, _vp, _vp, _vp], _sz),
        ("lsw_grid_truth_due", [_vp, _vp, _sz, _d, _u32, _d, _vp, _vp], _sz),
        ("lsw_grid_take_truth", [_vp, _u32, _vp, _vp, _d], _u32),
        ("lsw_svr_rx_size", [], _sz),
        ("lsw_svr_rx_init", [_vp, ctypes.c_int, _vp, _vp], ctypes.c_int),
        ("lsw_svr_rx_routes", [_vp, _vp, _u32], None),
        ("lsw_svr_rx_overflows", [_vp], _u32),
        ("lsw_svr_datagram", [_vp, ctypes.c_char_p, _sz, _u32, ctypes.c_uint16, _d, _d], ctypes.c_int),
        ("lsw_svr_drain", [_vp, _d, _u32, _vp, _vp], _u32)):
    getattr(_lib, _name).argtypes = _args
    getattr(_lib, _name).restype = _res

class RawSample(ctypes.Structure):
    """LswRawSample (lsw_imu.h): one raw IMU sample (tick; gyr rad/s, acc m/s^2, mag uT)."""

    _fields_ = [("t", ctypes.c_uint32), ("gyr", ctypes.c_float * 3), ("acc", ctypes.c_float * 3),
                ("mag", ctypes.c_float * 3)]


class ImuSettings(ctypes.Structure):
    """LswImuSettings (lsw_imu.h): sensor period (s), device period, largest time step (ticks),
    accelerometer saturation (m/s^2), 9D, VQF's rest thresholds (deg/s, m/s^2), start heading (cos, sin
    of half its angle), VQF's precision (0 single, 1 double)."""

    _fields_ = [("raw_period_s", ctypes.c_float), ("out_period", ctypes.c_uint32), ("max_gap", ctypes.c_uint32),
                ("acc_limit", ctypes.c_float), ("nine_d", ctypes.c_uint32), ("rest_th_gyr", ctypes.c_float),
                ("rest_th_acc", ctypes.c_float), ("heading", ctypes.c_float * 2), ("vqf_precision", ctypes.c_uint32)]


class FuseRows(ctypes.Structure):
    """LswFuseRows (lsw_fuse.h): the aggregator's point rows (times, orientations, rates, counts,
    capacity; limbstream.kernel.reconstruct)."""

    _fields_ = [("t", ctypes.c_void_p), ("q", ctypes.c_void_p), ("w", ctypes.c_void_p), ("n", ctypes.c_void_p),
                ("cap", ctypes.c_int64), ("spans", ctypes.c_void_p)]


class RootState(ctypes.Structure):
    """LswRootState (lsw_root.h): pointers to a root tracker's state arrays, and its point count."""

    _fields_ = [(name, ctypes.c_void_p) for name in ("root", "velocity", "pace", "anchor", "anchor_xyz", "t",
                                                     "height", "points", "seen", "refused")] + [
        ("n_points", ctypes.c_int64)]


class RootConst(ctypes.Structure):
    """LswRootConst (lsw_root.h): a root tracker's constants (limbstream.body.translation)."""

    _fields_ = [(name, ctypes.c_double) for name in ("gravity", "take_off_mps", "contact_m", "low_m", "keep_mps",
                                                     "velocity_s", "pace_s", "still_mps", "unseen_mps",
                                                     "off_feet_m")] + [
        (name, ctypes.c_int64) for name in ("first", "flight", "coast", "off_feet_flag")]


_imu_calls: tuple[tuple[str, list[Any], Any], ...] = (
        ("lsw_imu_state_size", [], _sz),
        ("lsw_imu_init", [_vp, ctypes.POINTER(ImuSettings)], None),
        ("lsw_imu_fuse_batch", [_vp, _vp, _sz, _vp], _sz),
        ("lsw_imu_bank_update", [_vp, _vp, _sz, _vp, _vp, _u8p, _vp, _vp, _vp, _vp, _vp, _vp], _sz),
        ("lsw_imu_bank_status", [_vp, _sz, _vp, _vp, _vp, _vp], None))
for _name, _args, _res in _imu_calls:
    getattr(_lib, _name).argtypes = _args
    getattr(_lib, _name).restype = _res

STATE_SIZE: int = _lib.fastsw_state_size()
SW_STATE_SIZE: int = _lib.sw_state_size()

_POINT_DTYPE = np.dtype(
    {"names": ["index", "t", "y"], "formats": [np.uint32, np.uint32, (np.float32, MAX_DIM)],
     "offsets": [0, 4, 8], "itemsize": ctypes.sizeof(Point)}
)
"""numpy layout of :class:`Point` (FastswPoint)."""


def _check_abi() -> None:
    """Each struct copied here has the size the C library was built with (lsw_abi.h): a copy
    that drifted from its declaration fails here, at import, instead of corrupting memory."""
    _lib.lsw_abi_size.argtypes = [ctypes.c_int]
    _lib.lsw_abi_size.restype = ctypes.c_size_t
    for which, struct in enumerate((Settings, Point, BatchOut, BankWire, _Sync, GridSettings, GridDevice, SvrTracker,
                                    SvrRoute, SvrSlow, RawSample, ImuSettings, FuseRows, RootState, RootConst)):
        size = _lib.lsw_abi_size(which)
        if size != ctypes.sizeof(struct):
            raise ImportError(f"limbstream C kernels: {struct.__name__} is {size} bytes in C, "
                              f"{ctypes.sizeof(struct)} in the binding: rebuild with `pip install -e .`")


_check_abi()


def to_ticks(t: np.ndarray, t0: float | None = None) -> np.ndarray:
    """Seconds -> uint32 kernel ticks relative to ``t0`` (default: ``t[0]``), modulo 2**32.

    Parameters
    ----------
    t : (m,) float64, seconds.
    """
    t = np.asarray(t, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0, np.uint32)
    origin = t[0] if t0 is None else t0
    ticks = np.round((t - origin) * TICK_HZ)
    ticks = np.where(np.isfinite(ticks), ticks, 0.0)
    return (ticks.astype(np.int64) & 0xFFFFFFFF).astype(np.uint32)


LIVE_BOUND = wire.LIVE_BOUND_DEG
"""The live rule's bound as the binding accepts it (0 and 180: off): the device tunable."""


def make_settings(threshold: float, max_len: int, dim: int, live_bound_deg: float = 0.0) -> Settings:
    """Validated :class:`Settings`; raises ValueError naming the bad argument. The bounds of
    threshold and max_len are the device tunables' (limbstream.wire.TUNABLES), those of
    live_bound_deg :data:`LIVE_BOUND`'s; the live rule needs dim 4 (quaternions)."""
    if not 1 <= dim <= MAX_DIM:
        raise ValueError(f"dim must be in 1..{MAX_DIM}, got {dim}")
    live = LIVE_BOUND.check(live_bound_deg)
    if 0.0 < live < 180.0 and dim != 4:
        raise ValueError(f"live_bound_deg needs quaternion samples (dim 4), got dim {dim}")
    return Settings(wire.THRESHOLD.check(threshold), wire.MAX_LEN.check(max_len), int(dim), live)


def live_rule(settings: Settings) -> bool:
    """Whether the kernel runs the live rule with these settings (bound in (0, 180) as float32)."""
    return 0.0 < settings.live_bound_deg < 180.0


def body_rates(y: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Kernel rates (value units per tick, tangent to their points) -> body angular rates.

    Parameters
    ----------
    y : (K, 4) float, the points; rates : (K, 4) float, their rates per tick.

    Returns
    -------
    (K, 3) float64, rad/s: ``2 vec(conj(y) v) TICK_HZ`` (:func:`limbstream.quat.body_rate`).
    """
    return quat.body_rate(y, np.asarray(rates, np.float64) * TICK_HZ)
