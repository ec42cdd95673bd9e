"""The device side: what every kind of device shares, whoever runs it.

A device takes samples, runs fastSW on them and publishes its segment points. Two questions are
kept apart, so that a new kind of device, or a new stage between the sample and fastSW, touches
one place:

- **where its samples come from**: a motion feed sampled on each device's own clock (the
  emulator, ``device_emulator/``), a tracker's packets put on a grid (the SlimeVR gateway), the
  device's own IMU or a feed sent over its serial link (the serial gateway);
- **what a device does with a sample**: fastSW in this process for many devices at once
  (:class:`~.bank.DeviceBank`), or the device's firmware behind a serial link.

==================  =============================================================
module              what it holds
==================  =============================================================
:mod:`.host`        :class:`~.host.DeviceHost`: the Zenoh side of a process's devices
                    (declare and undeclare, liveliness, config queries and status,
                    the shared :class:`~.host.HostSettings`)
:mod:`.bank`        :class:`~.bank.DeviceBank`: fastSW of a host's devices in one call
                    per tick, their streams and segment points
:mod:`.io`          a device's publishers and token; the answer to a config query
:mod:`.clocks`      device clocks (offset, drift, jitter) and true time
:mod:`.sync`        the devices' time exchanges with the time service and their stamps
:mod:`.feeds`       motion feeds: a subject's IMU samples at sample k
==================  =============================================================

Every process that works in ticks (these and the aggregator) paces them with
:class:`limbstream.pacing.PacedLoop`.
"""
