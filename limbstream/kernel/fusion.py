"""Sensor fusion on the device: VQF (built from the ``vqf`` package's C++ into the kernel library)
on raw IMU samples, offline (:func:`fuse`) and as a device's raw-sample pipeline, raw samples ->
VQF -> orientation at the device's instants -> fastSW with the live rule -> segment points, for
many devices in one C call per raw sample (:class:`ImuBank`; C: ``firmware_c/include/lsw_imu.h``,
the firmware runs the same code).

Orientations are scalar-first (w, x, y, z): the sensor frame in VQF's earth frame, z up (9D:
east, north, up, heading from the magnetometer; 6D: the heading is wherever the sensor started).
"""
from __future__ import annotations

import ctypes

import numpy as np

from limbstream import wire
from limbstream.kernel._lib import TICK_HZ, ImuSettings, RawSample, _lib
from limbstream.kernel.streaming import SegmenterBank

IMU_STATE_SIZE: int = _lib.lsw_imu_state_size()
FAULTS: tuple[str, ...] = ("invalid", "time_back", "gap", "saturated", "gyr_stuck")
"""Bad raw samples by kind, in the C order (LswImuFault; docs/kernel.md, "Raw samples")."""
SAMPLE, NO_OUTPUT, SKIPPED = 0, 3, 4
"""lsw_imu statuses beyond fastSW's NONE/POINT/REJECTED: a device-rate sample made (offline),
a raw sample fused without a device instant, a raw sample skipped (bad)."""

RAW_DTYPE = np.dtype({"names": ["t", "gyr", "acc", "mag"],
                      "formats": [np.uint32, (np.float32, 3), (np.float32, 3), (np.float32, 3)],
                      "offsets": [0, 4, 16, 28], "itemsize": ctypes.sizeof(RawSample)})
"""numpy layout of :class:`RawSample` (LswRawSample, lsw_imu.h): tick, gyr rad/s, acc m/s^2, mag uT."""

_DEFAULTS = ImuSettings.in_dll(_lib, "lsw_imu_default_settings")
REST_TH_GYR_DPS: float = round(float(_DEFAULTS.rest_th_gyr), 6)
"""The device's VQF rest threshold on the angular rate, deg/s (a body tracker's; lsw_imu.h)."""
REST_TH_ACC: float = round(float(_DEFAULTS.rest_th_acc), 6)
"""The device's VQF rest threshold on the specific force, m/s^2 (VQF's own)."""
VQF_PRECISIONS: tuple[str, ...] = ("single", "double")
"""VQF's precisions (lsw_vqf.h): its low-pass filter states, their coefficients and its 3x3 inverse in
float, the accelerometer low-pass filter's in float-float (single), or all in double (VQF's own); the
host library holds both, the firmware one."""
DEFAULT_VQF_PRECISION: str = VQF_PRECISIONS[int(_DEFAULTS.vqf_precision)]
"""The firmware's precision (LSW_VQF_DEFAULT_DOUBLE, fastsw_config.h): single."""
VQF_REST_TH_GYR_DPS = 2.0
"""VQF's own default rest threshold on the angular rate, deg/s (``VQFParams.restThGyr``)."""


def imu_settings(rate_hz: float, device_rate_hz: float = wire.DEVICE_RATE_HZ, nine_d: bool = False, max_gap_s: float | None = None,
                 acc_limit: float | None = None, rest_th_gyr_dps: float = REST_TH_GYR_DPS,
                 rest_th_acc: float = REST_TH_ACC, heading_rad: float = 0.0,
                 vqf_precision: str = DEFAULT_VQF_PRECISION) -> ImuSettings:
    """Validated pipeline settings (LswImuSettings).

    Parameters
    ----------
    rate_hz : the sensor's sample rate, Hz (> 0).
    device_rate_hz : the device's output rate, Hz (> 0, at most ``rate_hz``).
    nine_d : fuse the magnetometer (9D) instead of 6D.
    max_gap_s : a time step longer than this resets the filter (default 0.1 s).
    acc_limit : an accelerometer component at or beyond this (m/s^2) is saturated (default 156).
    rest_th_gyr_dps, rest_th_acc : VQF's rest detection thresholds, deg/s and m/s^2 (> 0; the
        device's defaults :data:`REST_TH_GYR_DPS`, :data:`REST_TH_ACC`).
    heading_rad : the filter's start heading about the earth's vertical, rad (|h| <= 2 pi).
    vqf_precision : ``"single"`` or ``"double"`` (:data:`VQF_PRECISIONS`; default the firmware's).
    """
    rate_hz, device_rate_hz = float(rate_hz), float(device_rate_hz)
    if not np.isfinite(rate_hz) or rate_hz <= 0:
        raise ValueError(f"rate_hz must be a positive number, got {rate_hz}")
    if not np.isfinite(device_rate_hz) or not 0 < device_rate_hz <= rate_hz:
        raise ValueError(f"device_rate_hz must be in (0, rate_hz={rate_hz}], got {device_rate_hz}")
    for name, value in (("rest_th_gyr_dps", rest_th_gyr_dps), ("rest_th_acc", rest_th_acc)):
        if not (np.isfinite(value) and 0 < value <= 1000):
            raise ValueError(f"{name} must be in (0, 1000], got {value}")
    if not (np.isfinite(heading_rad) and abs(heading_rad) <= 2 * np.pi):
        raise ValueError(f"heading_rad must be within +-2 pi, got {heading_rad}")
    if vqf_precision not in VQF_PRECISIONS:
        raise ValueError(f"vqf_precision must be one of {VQF_PRECISIONS}, got {vqf_precision!r}")
    gap = _DEFAULTS.max_gap if max_gap_s is None else int(round(float(max_gap_s) * TICK_HZ))
    return ImuSettings(1.0 / rate_hz, int(round(TICK_HZ / device_rate_hz)), gap,
                       _DEFAULTS.acc_limit if acc_limit is None else float(acc_limit), int(bool(nine_d)),
                       float(rest_th_gyr_dps), float(rest_th_acc), heading_turn(heading_rad),
                       VQF_PRECISIONS.index(vqf_precision))


def heading_turn(heading_rad: float):
    """The start heading as LswImuSettings carries it: (cos, sin) of half the angle, computed
    here in double (the device does no trigonometry for it)."""
    return (ctypes.c_float * 2)(np.cos(0.5 * heading_rad), np.sin(0.5 * heading_rad))


def y_up(q: np.ndarray) -> np.ndarray:
    """(n, 4) float32 orientations in VQF's earth frame (z up) turned into limbstream's world (y up),
    as a device does before fastSW (lsw_imu_y_up, in the same float32 steps: bit for bit).
    The same turn as ``quat.multiply(quat.Z_UP_TO_Y_UP, q)``."""
    q = np.asarray(q, np.float32)
    c = np.float32(np.sqrt(0.5))
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([c * (w + x), c * (x - w), c * (y + z), c * (z - y)], axis=-1)


def device_instants(t: np.ndarray, device_rate_hz: float = wire.DEVICE_RATE_HZ,
                    max_gap_s: float | None = None) -> np.ndarray:
    """The raw samples a device takes as its samples (lsw_imu.c's rule): the first, then the first
    at or after each instant every 1 / device_rate_hz from it (a sample more than a period late
    restarts the instants at itself; a step beyond ``max_gap_s``, default 0.1 s, starts anew).

    Parameters
    ----------
    t : (n,) raw sample times, s, increasing (taken to microsecond ticks as :func:`fuse` does).

    Returns
    -------
    (k,) int64 indices into ``t``.
    """
    t = np.asarray(t, np.float64)
    ticks = np.round((t - (t[0] if len(t) else 0.0)) * TICK_HZ).astype(np.int64)
    period = int(round(TICK_HZ / float(device_rate_hz)))
    gap = _DEFAULTS.max_gap if max_gap_s is None else int(round(float(max_gap_s) * TICK_HZ))
    out, next_instant, last = [], None, None
    for i, tick in enumerate(ticks.tolist()):
        if next_instant is None or tick - last > gap:
            out.append(i)
            next_instant = tick + period
        elif tick >= next_instant:
            out.append(i)
            next_instant += period
            if tick >= next_instant:
                next_instant = tick + period
        last = tick
    return np.asarray(out, np.int64)


def raw_samples(ticks: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None = None) -> np.ndarray:
    """(n,) :data:`RAW_DTYPE` from ticks (n,) uint32 (us), gyr and acc (n, 3) and optional mag (n, 3);
    ValueError naming the argument whose shape is wrong."""
    n = len(ticks)
    raw = np.zeros(n, RAW_DTYPE)
    raw["t"] = np.asarray(ticks, np.uint32)
    for name, values in (("gyr", gyr), ("acc", acc), ("mag", mag)):
        if values is None:
            continue
        values = np.asarray(values)
        if values.shape != (n, 3):
            raise ValueError(f"{name} must be ({n}, 3), got {values.shape}")
        raw[name] = values
    return raw


def fuse(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None = None, rate_hz: float = 200.0,
         t: np.ndarray | None = None, rest_th_gyr_dps: float = REST_TH_GYR_DPS, rest_th_acc: float = REST_TH_ACC,
         heading_rad: float = 0.0, vqf_precision: str = DEFAULT_VQF_PRECISION) -> np.ndarray:
    """The device's orientation after each raw sample (VQF in the kernel library, exactly as a
    device computes it, bad samples handled as there).

    Parameters
    ----------
    gyr : (n, 3) angular rate, rad/s, sensor frame.
    acc : (n, 3) specific force, m/s^2, sensor frame.
    mag : (n, 3) magnetic field (uT), or None: 9D with it, else 6D.
    rate_hz : the sensor's sample rate, Hz (VQF's time step is 1 / rate_hz).
    t : (n,) sample times, s (default: uniform at rate_hz); used for the bad-time checks.
    rest_th_gyr_dps, rest_th_acc, heading_rad, vqf_precision : as :func:`imu_settings`.

    Returns
    -------
    (n, 4) float64, w x y z, unit norm: sensor frame in VQF's earth frame (z up).
    """
    gyr = np.asarray(gyr, np.float64)
    n = len(gyr)
    times = np.arange(n) / float(rate_hz) if t is None else np.asarray(t, np.float64)
    ticks = np.round((times - (times[0] if n else 0.0)) * TICK_HZ).astype(np.int64) & 0xFFFFFFFF
    raw = raw_samples(ticks, gyr, acc, mag)
    state = ctypes.create_string_buffer(IMU_STATE_SIZE)
    settings = imu_settings(rate_hz, rate_hz, mag is not None, None, None, rest_th_gyr_dps, rest_th_acc, heading_rad,
                            vqf_precision)
    _lib.lsw_imu_init(state, ctypes.byref(settings))
    q = np.zeros((n, 4), np.float32)
    _lib.lsw_imu_fuse_batch(state, raw.ctypes.data, n, q.ctypes.data)
    return q.astype(np.float64)


class ImuBank:
    """Many devices' raw-sample pipelines (VQF + fastSW), one raw sample each per C call.

    Each device fuses its raw samples at ``rate_hz`` and takes the orientation at its own
    instants, every 1 / ``device_rate_hz`` from its first sample (the first raw sample at or after
    each instant, stamped with that sample's own time); those go through its fastSW state in
    ``segments`` (a :class:`SegmenterBank`: settings, points, rates, wire encoding, retune, flush),
    advanced by the same C call.

    Parameters
    ----------
    count : int, number of devices.
    rate_hz, device_rate_hz, nine_d, max_gap_s, acc_limit, rest_th_gyr_dps, rest_th_acc, vqf_precision :
        as :func:`imu_settings`, shared.
    threshold, max_len, live_bound_deg, ring : as :class:`SegmenterBank`.
    headings : (count,) each device's filter start heading, rad (default 0).

    Devices send their orientations in limbstream's world (Y up: VQF's earth frame turned by
    :data:`limbstream.quat.Z_UP_TO_Y_UP`, in C).
    """

    def __init__(self, count: int, rate_hz: float, device_rate_hz: float = wire.DEVICE_RATE_HZ, nine_d: bool = False,
                 threshold=wire.THRESHOLD.default, max_len=wire.MAX_LEN.default,
                 live_bound_deg=wire.LIVE_BOUND_DEG.default, ring: int = 0, max_gap_s: float | None = None,
                 acc_limit: float | None = None, rest_th_gyr_dps: float = REST_TH_GYR_DPS,
                 rest_th_acc: float = REST_TH_ACC, headings: np.ndarray | None = None,
                 vqf_precision: str = DEFAULT_VQF_PRECISION):
        self.count = count
        self.segments = SegmenterBank(count, threshold, max_len, 4, live_bound_deg, ring)
        self.nine_d = bool(nine_d)
        self.imu_settings = imu_settings(rate_hz, device_rate_hz, nine_d, max_gap_s, acc_limit, rest_th_gyr_dps,
                                         rest_th_acc, vqf_precision=vqf_precision)
        self.vqf_precision = vqf_precision
        self.headings = np.zeros(count) if headings is None else np.asarray(headings, np.float64).reshape(count)
        self._imus = ctypes.create_string_buffer(IMU_STATE_SIZE * max(count, 1))
        for k in range(count):
            self.reset_imu(k)
        self._t_us = np.zeros(max(count, 1), np.int64)

    @property
    def mode(self) -> str:
        """The fusion every device runs: ``"9D"`` (magnetometer) or ``"6D"``."""
        return "9D" if self.nine_d else "6D"

    def reset_imu(self, k: int) -> None:
        """Device k's filter from scratch (its start heading, zero bias, counters zero); its fastSW
        stream is ``segments.reset``'s."""
        _lib.lsw_imu_init(ctypes.addressof(self._imus) + k * IMU_STATE_SIZE, ctypes.byref(self.device_settings(k)))

    def device_settings(self, k: int) -> ImuSettings:
        """Device k's pipeline settings: the bank's, with its own start heading (what a firmware
        device is given in its FUSION message)."""
        own = ImuSettings.from_buffer_copy(self.imu_settings)
        own.heading = heading_turn(float(self.headings[k]))
        return own

    def _raw(self, ticks, gyr, acc, mag) -> tuple[np.ndarray, int]:
        if mag is None and self.nine_d:
            raise ValueError("mag is required: this bank fuses 9D")
        raw = raw_samples(ticks, gyr, acc, mag)
        if len(raw) > self.count:
            raise ValueError(f"at most {self.count} devices, got {len(raw)} samples")
        return raw, len(raw)

    def update_raw(self, ticks: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fuse one raw sample of each of the first n devices (n = len(ticks)).

        Parameters
        ----------
        ticks : (n,) uint32, each sample's time, us (each device's own clock).
        gyr, acc : (n, 3) rad/s and m/s^2; mag : (n, 3) uT (9D banks only).

        Returns
        -------
        status : (n,) uint8 view: NONE / POINT / REJECTED (a device-rate sample went to fastSW),
            :data:`NO_OUTPUT` or :data:`SKIPPED`; valid until the next call.
        index, y : as :meth:`SegmenterBank.update` where status == POINT.
        """
        raw, n = self._raw(ticks, gyr, acc, mag)
        return self.segments.advance(lambda states, *out: _lib.lsw_imu_bank_update(
            self._imus, states, n, raw.ctypes.data, self._t_us.ctypes.data, *out), n)

    def update_raw_wire(self, ticks: np.ndarray, t_us: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
                        mag: np.ndarray | None = None) -> tuple[np.ndarray, bytes, np.ndarray]:
        """:meth:`update_raw`, every point encoded as :meth:`SegmenterBank.update_wire` does; the C side
        writes the wire ring (``sample``: each device's device-rate sample number plus ``base``;
        ``t_us``: the stamp of its raw sample). ``t_us`` (n,) int64: each raw sample's stamp, us
        since the epoch. Returns slots, payload, ends as :meth:`SegmenterBank.update_wire`."""
        raw, n = self._raw(ticks, gyr, acc, mag)
        self._t_us[:n] = t_us
        return self.segments.advance_wire(lambda states, *out: _lib.lsw_imu_bank_update(
            self._imus, states, n, raw.ctypes.data, self._t_us.ctypes.data, *out), n)

    def imu_status(self, first: int = 0, count: int | None = None) -> dict[str, np.ndarray]:
        """The fusion report of devices ``first .. first + count - 1`` (default: every device):
        ``bias`` (count, 3) rad/s, ``rest`` (count,) bool, ``outputs`` (count,) device-rate samples
        made, and one (count,) count per :data:`FAULTS`."""
        count = self.count - first if count is None else count
        if not (0 <= first and count >= 0 and first + count <= self.count):
            raise ValueError(f"devices {first}..{first + count - 1} of {self.count}")
        bias = np.zeros((count, 3), np.float32)
        rest = np.zeros(count, np.uint8)
        faults = np.zeros((count, len(FAULTS)), np.uint32)
        outputs = np.zeros(count, np.uint32)
        _lib.lsw_imu_bank_status(ctypes.addressof(self._imus) + first * IMU_STATE_SIZE, count, bias.ctypes.data,
                                 rest.ctypes.data, faults.ctypes.data, outputs.ctypes.data)
        report = {"bias": bias.astype(np.float64), "rest": rest.astype(bool), "outputs": outputs}
        report.update({name: faults[:, i] for i, name in enumerate(FAULTS)})
        return report
