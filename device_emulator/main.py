"""Run emulated devices until stopped (what ``limbstream emulate`` starts), and the subjects'
names."""
from __future__ import annotations

import os
import socket
import threading

from limbstream import wire, zconfig
from limbstream.device.clocks import ClockSettings
from limbstream.device_emulator.emulator import Emulator, EmulatorSettings



def host_prefix(hostname: str | None = None) -> str:
    """``<hostname>-s``: a subject prefix unique per container (replicas get distinct hostnames).

    The hostname comes from ``$HOSTNAME`` (set by Docker to the container's) or the system;
    characters not allowed in a key chunk become ``-``.
    """
    hostname = hostname or os.environ.get("HOSTNAME") or socket.gethostname()
    return wire.to_chunk(hostname) + "-s"


def subject_names(count: int, first: int = 1, prefix: str = "s") -> list[str]:
    """``s01, s02, ...`` (valid key chunks); prefix ``auto`` is :func:`host_prefix`."""
    prefix = host_prefix() if prefix == "auto" else prefix
    return [wire.check_chunk(f"{prefix}{k:02d}", "subject") for k in range(first, first + count)]


def run(feeds: dict, settings: EmulatorSettings, zenoh: zconfig.ZenohSettings,
        duration: float | None = None, verbose: bool = False, stop: threading.Event | None = None) -> int:
    """Open the session (waiting for the router) and run the devices of ``feeds`` ({subject: feed})
    until ``stop``, a signal or ``duration`` s of device time; exit code."""
    stop, session = zconfig.part_session(zenoh, stop)
    if session is None:  # stopped while waiting for the router
        return 0
    with session:
        emulator = Emulator(session, feeds, settings)
        emulator.declare()
        print(f"emulating {len(emulator.devices)} devices of {len(feeds)} subjects "
              f"({', '.join(feeds)}) at {settings.host.fs:g} Hz x{settings.speed:g}", flush=True)
        print_clocks(emulator, settings.clock, verbose)
        emulator.start_clocks(stop)
        if emulator.sync is not None:
            synced = sum(emulator.sync.synced(d.slot, emulator.clocks.read(d.slot)) for d in emulator.devices)
            print(f"time sync: {synced}/{len(emulator.devices)} devices synced at start"
                  + ("" if emulator.sync.service_present() else " (no time service reachable)"), flush=True)
        ticks = emulator.run(stop, duration)
        emulator.undeclare()
    late, own = (100.0 * n / max(ticks.ticks, 1) for n in (ticks.late, ticks.late_own))
    print(f"emulator: {ticks.ticks} ticks, {late:.2f} % late ({own:.2f} % by its own work), busy {ticks.busy_s:.1f} s",
          flush=True)
    if emulator.sync is not None:
        print(f"emulator: {emulator.sync.summary()}", flush=True)
    return 0


def print_clocks(emulator: Emulator, clock: ClockSettings, verbose: bool, most: int = 40) -> None:
    """The clock draws (seeded): every device's with -v or up to ``most`` devices, else a summary."""
    if not clock.modelled:
        return
    lines = emulator.clocks.describe([d.id for d in emulator.devices])
    print(f"device clocks (--clock-seed {clock.seed}): offsets uniform in +-{clock.offset_ms:g} ms, drifts in "
          f"+-{clock.drift_ppm:g} ppm, read jitter +-{clock.jitter_us:g} us; sync "
          f"{'on' if clock.sync else 'off'}", flush=True)
    shown = lines if verbose or len(lines) <= most else lines[:most] + [f"... ({len(lines) - most} more with -v)"]
    for line in shown:
        print(f"  {line}", flush=True)
