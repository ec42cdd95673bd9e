"""The SlimeVR gateway's report: everything it knows, for its log (``limbstream gateway slimevr``
prints it every ``--report-s``) and its tests: trackers, sensors without a device, devices,
datagrams dropped and packets ignored by reason, its ticks."""
from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from limbstream.services.gateway.slimevr import SlimeVRGateway


def report(gateway: SlimeVRGateway) -> dict:
    """The gateway's report (JSON-ready)."""
    now = time.monotonic()
    trackers = gateway.sessions.trackers.values()
    bank, grid = gateway.bank, gateway.grid
    return {
        "trackers": {t.name: {"online": t.online, "packets": t.packets, "lost": t.lost,
                              "pps": t.pps(now), "battery_pct": t.battery_pct, "signal_dbm": t.signal_dbm,
                              "rtt_ms": t.rtt_ms,
                              "sensors": {s.sensor: (s.device.id if s.device else None) for s in t.sensors.values()}}
                     for t in trackers},
        "unassigned": {s.name: s.why for t in trackers for s in t.sensors.values() if s.device is None},
        "devices": {d.id: {"online": d.online, "streams": d.streams, "points": d.points,
                           "samples": int(bank.n[d.slot] - bank.kernel.base[d.slot]),
                           "held": grid.devices[d.slot].held, "truth_dropped": grid.devices[d.slot].truth_dropped,
                           "jitter_p99_ms": (round(float(np.percentile(jitter, 99)) / 1e3, 3)
                                             if len(jitter := grid.jitter_us(d.slot)) else None),
                           "sensor": d.source.name if d.source else None} for d in gateway.host.devices},
        "dropped": dict(gateway.dropped), "ignored": dict(gateway.ignored),
        "unassigned_samples": gateway.unassigned_samples, "ticks": gateway.ticks, "late": gateway.loop.stats.late,
    }
