"""What the devices of a host do with a sample when their kernels run in this process: fastSW
for every device in one :class:`limbstream.kernel.SegmenterBank` call per tick, their segment
points encoded by the kernel in the same call and published as they are.

The bank keeps, per device, the sample numbers and stamps of its last ``ring`` kernel calls (a
point refers to one of them), its samples taken, and the wire fields of its stream (id, next
sequence number, base: ``kernel.stream[slot]`` ...). A stream ends with a FINAL point
(docs/protocol.md): the kernel's newest sample flushed, or, when that already went out as a
point, the newest point repeated with FINAL.
"""
from __future__ import annotations

import random
from dataclasses import replace

import numpy as np

from limbstream import kernel, wire
from limbstream.device.host import Device, DeviceHost


class DeviceBank:
    """The kernels of ``size`` devices of ``host`` (bank slot = host slot).

    Parameters
    ----------
    host : their device host (its settings give the initial config).
    size : devices the bank can hold.
    ring : kernel calls remembered per device (at least the calls back to a device's newest
        point and the sample before it).
    """

    def __init__(self, host: DeviceHost, size: int, ring: int):
        c = host.settings.config
        self.host, self.ring = host, ring
        self.kernel = kernel.SegmenterBank(size, c.threshold, c.max_len, live_bound_deg=c.live_bound_deg, ring=ring)
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
        slots, payload, ends = self.kernel.update_wire(ticks, y)
        self.calls[:m] += 1
        self.host.publish_points(slots, payload, ends)

    def start_stream(self, d: Device, base: int | None = None, reset: bool = False) -> None:
        """A new stream of device d: a new id, numbering from 0, its sample 0 is the device's
        sample ``base`` (default: its next); ``reset``: the kernel starts afresh too (its next
        sample is a first point)."""
        k = d.slot
        if reset:
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
               link: wire.LinkStatus | None = None) -> wire.DeviceStatus:
        """Device d's own view: its config and the counters of its current stream, its clock and link."""
        b = self.kernel
        return wire.DeviceStatus(d.id, d.config, int(b.stream[d.slot]), int(self.n[d.slot] - b.base[d.slot]),
                                 d.points, clock, rest_pose, link)
