"""Devices that run the device firmware (``limbstream emulate --firmware``): one QEMU process per
device, each fed its segment of its subject's motion over its serial link by a
:class:`~limbstream.services.gateway.serial_gateway.SerialGateway`, all paced by one loop.

Fed the same motion with the same settings, these devices send the same segment points (sample
index, quaternion, rate, end-of-stream point) as the host's emulated devices: the firmware runs
the same C code on the same inputs (each sample on its device's own clock grid). What differs:
stream ids (drawn per stream) and stamps (the gateway stamps samples with this host's clock,
on the sample grid from the start). A QEMU process that dies is a device gone offline; it is
started again and its device begins a new stream.
"""
from __future__ import annotations

import threading
from pathlib import Path

from limbstream import zconfig
from limbstream.device.host import HostSettings
from limbstream.device.readings import RawSensors
from limbstream.kernel import fusion
from limbstream.services.gateway import firmware, serial_gateway
from limbstream.services.gateway.serial_port import SerialLink


class FirmwareConnector:
    """A device's link: its QEMU process, started by :meth:`launch` or on the first open, and
    started anew on every later open (the previous one died or its link failed)."""

    def __init__(self, elf: Path, link_timeout_s: float = 15.0):
        self.elf, self.link_timeout_s = elf, link_timeout_s
        self.device: firmware.FirmwareDevice | None = None
        self.starts = 0
        self._fresh = False

    def launch(self) -> None:
        """Start QEMU now (many devices start in parallel before their links are opened)."""
        self.stop()
        self.device = firmware.FirmwareDevice(self.elf)
        self.starts += 1
        self._fresh = True

    def __call__(self) -> SerialLink:
        if not self._fresh:
            self.launch()
        self._fresh = False
        assert self.device is not None
        return SerialLink(self.device.port, self.link_timeout_s)

    def stop(self) -> None:
        if self.device is not None:
            self.device.stop()
            self.device = None


def feedings(feeds: dict, raw: RawSensors | None = None, rate_hz: float = 200.0, fs: float = 50.0,
             vqf_precision: str = fusion.DEFAULT_VQF_PRECISION) -> list[tuple[str, str, serial_gateway.Feeding]]:
    """(subject, segment, feeding) of every device of ``feeds`` ({subject: feed}); with raw
    sensors (``raw``: made over the feeds in the emulator's slot order, longest first) each is
    fed its own sensor's readings and its filter's settings (VQF's precision is the one its
    firmware is built with: :func:`firmware.build`)."""
    first: dict[int, int] = {}  # id of a feed -> its first slot among raw's sensors
    for f in raw.feeds if raw is not None else ():
        first[id(f)] = sum(len(g.segments) for g in raw.feeds[:len(first)])
    out = []
    for subject, feed in feeds.items():
        for column, segment in enumerate(feed.segments):
            if raw is None:
                out.append((subject, segment, serial_gateway.Feeding(feed, column)))
                continue
            slot = first[id(feed)] + column
            settings = fusion.imu_settings(rate_hz, fs, heading_rad=float(raw.devices.heading[slot]),
                                           vqf_precision=vqf_precision)
            out.append((subject, segment, serial_gateway.Feeding(feed, column, raw, slot, settings)))
    return out


def run(feeds: dict, settings: HostSettings, speed: float, zenoh: zconfig.ZenohSettings, elf: Path,
        duration: float | None = None, stop: threading.Event | None = None, raw: RawSensors | None = None,
        raw_rate_hz: float = 200.0, vqf_precision: str = fusion.DEFAULT_VQF_PRECISION) -> int:
    """Run one firmware device per segment of each feed ({subject: feed}) at ``speed`` until
    ``stop``, a signal or ``duration`` s of device time (a finite feed: its end, then idle); with
    ``raw``, devices fed raw samples at ``raw_rate_hz`` (their firmware's VQF in ``vqf_precision``); exit code."""
    stop, session = zconfig.part_session(zenoh, stop)
    if session is None:
        return 0
    connectors: list[FirmwareConnector] = []
    gateways: list[serial_gateway.SerialGateway] = []
    with session:
        host = serial_gateway.serial_host(session, settings)
        host.declare()
        try:
            for subject, segment, feeding in feedings(feeds, raw, raw_rate_hz, settings.fs, vqf_precision):
                connector = FirmwareConnector(elf)
                connectors.append(connector)
                gateways.append(serial_gateway.SerialGateway(host, connector, subject, segment, feeding,
                                                             feeds[subject].rest_pose, body=feeds[subject].body))
            for connector in connectors:
                connector.launch()
            online = sum(g.open() for g in gateways)
            for feed in feeds.values():
                feed.sample(0)  # the first chunk before the clock starts
            print(f"emulating {len(gateways)} firmware devices ({online} online) of {len(feeds)} subjects "
                  f"({', '.join(feeds)}) at {settings.fs:g} Hz x{speed:g} under QEMU", flush=True)
            ticks = serial_gateway.run(host, gateways, stop, speed, duration)
            restarts = sum(c.starts for c in connectors) - len(connectors)
            print(f"emulator: {ticks} ticks, {restarts} firmware restarts", flush=True)
        finally:
            for g in gateways:
                print(f"emulator: {g.summary()}", flush=True)
                g.close()
            host.close()
            for connector in connectors:
                connector.stop()
    return 0
