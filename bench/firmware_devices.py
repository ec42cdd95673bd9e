"""Firmware devices in real time: N copies of the device firmware under QEMU (one process each),
each fed one segment of a CMU subject (looped) at 50 Hz over its serial link in live mode
(wire.LIVE_MODE, max_len 25), as ``limbstream emulate --firmware`` runs them (no Zenoh here:
only the devices and their links).

    python bench/firmware_devices.py [--devices 10] [--seconds 30] [--rate 50] [--elf build/device.elf]

Prints, per run: the host loop's late ticks (a tick started more than one period after its
deadline) and the largest lateness; this process's CPU (the host side of the links) and each QEMU process's CPU (utime + stime over the run, from
/proc); how far each device lags behind the samples sent (samples sent minus the samples its
heartbeat reports, every second); the link's bytes per second each way per device; points
per second per device; the firmware's stack high-water mark (bytes, from its status).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from limbstream import wire
from limbstream.device.feeds import GeneratorFeed, LoopFeed
from limbstream.services.gateway import firmware
from limbstream.services.gateway.serial_port import SerialLink
from limbstream.sources import load

CMU = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "cmu_10seg_50hz.npz"
LIVE = wire.DeviceConfig(**wire.LIVE_MODE)


def cpu_s(pid: int) -> float:
    """utime + stime of a process, seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--devices", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--rate", type=float, default=50.0)
    parser.add_argument("--elf", type=Path, default=None, help="default: make -C firmware_c device")
    args = parser.parse_args()
    elf = args.elf or firmware.build()
    if CMU.exists():
        feed, source = LoopFeed(load(CMU)[0], args.rate), f"CMU {load(CMU)[0].name}"
    else:
        feed, source = GeneratorFeed(seed=1, fs=args.rate), "generator"
    devices = [firmware.FirmwareDevice(elf) for _ in range(args.devices)]
    try:
        links = [SerialLink(d.port) for d in devices]
        for k, port in enumerate(links):
            assert port.configure(LIVE).ok and port.start(k).ok
        cpu0 = [cpu_s(d.process.pid) for d in devices]
        in0, out0 = [p.bytes_in for p in links], [p.bytes_out for p in links]
        period = 1.0 / args.rate
        ticks = int(args.seconds * args.rate)
        late, max_late, lag, points = 0, 0.0, [], [0] * len(links)
        sent = 0
        start, host0 = time.perf_counter(), time.process_time()
        for k in range(ticks):
            deadline = start + k * period
            now = time.perf_counter()
            if now < deadline:
                time.sleep(deadline - now)
            elif now - deadline > period:
                late += 1
                max_late = max(max_late, now - deadline)
            q = feed.sample(k)
            for s, port in enumerate(links):
                port.sample(int(round(k * 1e6 / args.rate)), int(k * 1e6 / args.rate), q[s % q.shape[0]])
            sent = k + 1
            for s, port in enumerate(links):
                while not port.inbox.empty():
                    kind, message = port.inbox.get_nowait()
                    if kind == "point":
                        points[s] += 1
                    elif kind == "status":
                        lag.append(sent - message.samples)
        wall = time.perf_counter() - start
        host = (time.process_time() - host0) / wall
        cpu = [(cpu_s(d.process.pid) - c) / wall for d, c in zip(devices, cpu0)]
        stack = max(port.status().stack_bytes for port in links)
        rx = [(p.bytes_in - b) / wall for p, b in zip(links, in0)]
        tx = [(p.bytes_out - b) / wall for p, b in zip(links, out0)]
        for port in links:
            port.close()
    finally:
        for d in devices:
            d.stop()
    lag_a = np.array(lag or [0])
    print(f"{args.devices} firmware devices under QEMU, {args.rate:g} Hz, live mode, {source}, "
          f"{wall:.1f} s on {os.cpu_count()} cores ({sys.platform})")
    print("| figure | value |")
    print("|---|---|")
    print(f"| host loop: late ticks | {late} of {ticks} ({100 * late / ticks:.2f} %), max {1e3 * max_late:.1f} ms |")
    print(f"| CPU per QEMU process, mean / max | {100 * np.mean(cpu):.1f} % / {100 * max(cpu):.1f} % of a core |")
    print(f"| CPU of the host side (this process: pacing, framing, {args.devices} link reader threads) | "
          f"{100 * host:.1f} % of a core |")
    print(f"| device lag behind the samples sent (at its heartbeats), median / max | "
          f"{np.median(lag_a):.0f} / {lag_a.max()} samples ({len(lag)} heartbeats) |")
    print(f"| link host -> device, per device | {np.mean(tx):.0f} B/s |")
    print(f"| link device -> host, per device (points + heartbeat) | {np.mean(rx):.0f} B/s |")
    print(f"| points per device | {np.mean(points) / wall:.1f} /s |")
    print(f"| stack high-water mark | {stack} B |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
