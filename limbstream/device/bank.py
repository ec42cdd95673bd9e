"""What the devices of a host do with a sample when their kernels run in this process: fastSW
for every device in one :class:`limbstream.kernel.SegmenterBank` call per tick, their segment
points encoded by the kernel in the same call and published as they are.

Devices fed raw IMU samples (:class:`RawStage`) run the raw-sample stage in front of fastSW:
raw samples -> VQF -> the device's instants -> fastSW with the live rule, encoded in C
(:class:`limbstream.kernel.fusion.ImuBank`, one call per raw sample of every device; the
firmware runs the same code), and report their filter in their status.

The bank keeps, per device, the sample numbers and stamps of its last ``ring`` kernel calls (a
point refers to one of them), its samples taken, and the wire fields of its stream (id, next
sequence number, base: ``kernel.stream[slot]`` ...). A stream ends with a FINAL point
(docs/protocol.md): the kernel's newest sample flushed, or, when that already went out as a
point, the newest point repeated with FINAL.
"""
from __future__ import annotations

import random
from dataclasses import dataclass, replace

import numpy as np

from limbstream import kernel, wire
from limbstream.body import Body
from limbstream.device.host import Device, DeviceHost
from limbstream.kernel import fusion


@dataclass(frozen=True)
class RawStage:
    """The raw-sample stage of a bank's devices (:class:`limbstream.kernel.fusion.ImuBank`).

    Attributes
    ----------
    rate_hz : the sensors' sample rate, Hz (the device rate stays the host's).
    headings : (size,) each device's filter start heading, rad (None: 0).
    rest_th_gyr_dps, rest_th_acc : VQF's rest thresholds (the device's defaults).
    vqf_precision : VQF's precision, ``"single"`` or ``"double"`` (default the firmware's).
    """

    rate_hz: float
    headings: np.ndarray | None = None
    rest_th_gyr_dps: float = fusion.REST_TH_GYR_DPS
    rest_th_acc: float = fusion.REST_TH_ACC
    vqf_precision: str = fusion.DEFAULT_VQF_PRECISION


class DeviceBank:
    """The kernels of ``size`` devices of ``host`` (bank slot = host slot).

    Parameters
    ----------
    host : their device host (its settings give the initial config and the device rate).
    size : devices the bank can hold.
    ring : kernel calls remembered per device (at least the calls back to a device's newest
        point and the sample before it).
    raw : the devices are fed raw IMU samples (:meth:`update_raw`), None: orientations
        (:meth:`update`).
    """

    def __init__(self, host: DeviceHost, size: int, ring: int, raw: RawStage | None = None):
        c = host.settings.config
        self.host, self.ring = host, ring
        self.imus: fusion.ImuBank | None = None
        if raw is None:
            self.kernel = kernel.SegmenterBank(size, c.threshold, c.max_len, live_bound_deg=c.live_bound_deg, ring=ring)
        else:
            self.imus = fusion.ImuBank(size, raw.rate_hz, host.settings.fs, False, c.threshold, c.max_len,
                                       c.live_bound_deg, ring, rest_th_gyr_dps=raw.rest_th_gyr_dps,
                                       rest_th_acc=raw.rest_th_acc, headings=raw.headings,
                                       vqf_precision=raw.vqf_precision)
            self.kernel = self.imus.segments
        self.n = np.zeros(size, np.int64)      # samples each device has taken
        self.calls = np.zeros(size, np.int64)  # kernel calls of each device since its reset (the kernel's index)
        self._lockstep = True                  # no device was reset: every device called so far has had as many calls

    def update(self, ticks: np.ndarray, y: np.ndarray, taken: np.ndarray, stamps: np.ndarray) -> None:
        """One kernel call for the first m devices (m = len(ticks)) and their segment points
        published.

        Parameters
        ----------
        ticks : (m,) uint32 kernel ticks (each device's own clock, us mod 2**32).
        y : (m, 4) float32 samples; a NaN row (a device without a sample this tick) is rejected
            without touching its state.
        taken : (j,) the devices with a sample, increasing.
        stamps : (j,) their samples' stamps on the common time base, us.
        """
        m = len(ticks)
        sample, t_us = self.kernel.sample, self.kernel.t_us
        if self._lockstep:
            row = int(self.calls[0]) % self.ring if m else 0
            sample[row, :m] = -1
            sample[row, taken] = self.n[taken]
            t_us[row, taken] = stamps
        else:
            rows = self.calls[:m] % self.ring
            sample[rows, np.arange(m)] = -1
            sample[rows[taken], taken] = self.n[taken]
            t_us[rows[taken], taken] = stamps
        self.n[taken] += 1
        self.host.publish_points(*self.kernel.update_wire(ticks, y))
        self.calls[:m] += 1

    def update_raw(self, ticks: np.ndarray, t_us: np.ndarray, gyr: np.ndarray, acc: np.ndarray) -> np.ndarray:
        """One raw sample of each of the first m devices (m = len(ticks)) through the raw-sample
        stage; the segment points published.

        Parameters
        ----------
        ticks : (m,) uint32 each sample's time on the device's own clock, us mod 2**32.
        t_us : (m,) int64 its stamp on the common time base, us.
        gyr, acc : (m, 3) rad/s and m/s^2, sensor frame.

        Returns
        -------
        (m,) bool: the devices whose sample was their sample for a device instant (a fastSW call).
        """
        if self.imus is None:
            raise ValueError("update_raw needs a bank made with a raw stage")
        self.host.publish_points(*self.imus.update_raw_wire(ticks, t_us, gyr, acc))
        took = self.kernel.status < fusion.NO_OUTPUT
        m = len(took)
        self.n[:m] += took
        self.calls[:m] += took
        self._lockstep = False
        return took

    def start_stream(self, d: Device, base: int | None = None, reset: bool = False) -> None:
        """A new stream of device d: a new id, numbering from 0, its sample 0 is the device's
        sample ``base`` (default: its next); ``reset``: the kernel starts afresh too (its next
        sample is a first point)."""
        k = d.slot
        if reset:  # (a raw stage's filter goes on: the sensor did not stop)
            self.kernel.reset(k)
            self.calls[k] = 0
            self._lockstep = False
        b = self.kernel
        b.stream[k], b.seq[k], b.base[k] = random.getrandbits(16), 0, self.n[k] if base is None else base
        d.points, d.last = 0, None
        d.streams += 1

    def held(self, d: Device, index: int, y: np.ndarray, flags: int) -> None:
        """Publish device d's sample of kernel call ``index`` (within the ring) as a point outside
        the kernel's update (a flushed point, a new stream's first point), held: rate 0 (version
        2 where the live rule is on, else version 1)."""
        b, row = self.kernel, index % self.ring
        point = wire.SegmentPoint(int(b.stream[d.slot]), int(b.seq[d.slot]), int(b.sample[row, d.slot] - b.base[d.slot]),
                                  int(b.t_us[row, d.slot]), (float(y[0]), float(y[1]), float(y[2]), float(y[3])), flags,
                                  (0.0, 0.0, 0.0) if b.live(d.slot) else None)
        self.host.publish(d, wire.encode_point(point))
        b.seq[d.slot] = (int(b.seq[d.slot]) + 1) & 0xFFFFFFFF

    def end_stream(self, d: Device) -> None:
        """End device d's stream: its last sample flushed as a point (FINAL), or, when that
        already went out as a point (the live rule closed it), that point repeated with FINAL as
        the end marker (the next sequence number)."""
        last = self.kernel.flush(d.slot)
        if last is not None:
            self.held(d, int(last[0]), last[2], wire.FLAG_FINAL)
        elif d.last is not None:
            b = self.kernel
            point = replace(wire.decode_point(d.last), seq=int(b.seq[d.slot]), flags=wire.FLAG_FINAL)
            d.publisher.put(wire.encode_point(point))
            b.seq[d.slot] = (int(b.seq[d.slot]) + 1) & 0xFFFFFFFF

    def configure(self, d: Device, config: wire.DeviceConfig) -> None:
        """Device d runs ``config`` from its next sample on."""
        self.kernel.retune(d.slot, config.threshold, config.max_len, config.live_bound_deg)
        d.config = config

    def status(self, d: Device, clock: wire.ClockStatus | None, rest_pose: str = wire.DEFAULT_REST_POSE,
               link: wire.LinkStatus | None = None, orientations: str | None = None,
               body: Body | None = None) -> wire.DeviceStatus:
        """Device d's own view: its config and the counters of its current stream, its clock and
        link, what its orientations are (wire.ORIENTATIONS), its fusion filter where it has a
        raw stage, and its wearer's dimensions (``body``; None: not said)."""
        b = self.kernel
        return wire.DeviceStatus(d.id, d.config, int(b.stream[d.slot]), int(self.n[d.slot] - b.base[d.slot]),
                                 d.points, clock, rest_pose, link, self.fusion_status(d.slot), orientations, body)

    def fusion_status(self, slot: int) -> wire.FusionStatus | None:
        """The filter of the device in ``slot`` (None without a raw stage)."""
        if self.imus is None:
            return None
        report = self.imus.imu_status(slot, 1)
        bias = np.degrees(report["bias"][0])
        return wire.FusionStatus(self.imus.mode, (float(bias[0]), float(bias[1]), float(bias[2])),
                                 bool(report["rest"][0]), {name: int(report[name][0]) for name in fusion.FAULTS})
