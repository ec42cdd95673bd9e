"""Ten simulated SlimeVR trackers of one subject through the gateway, a real router, the time
service and the aggregator: every device online, its points arriving, ICR and errors computed
against the trackers' own full-rate stream, its link figures in the stats."""
from __future__ import annotations

import json
import math
import socket
import threading

import numpy as np
import pytest

from limbstream import wire, zconfig
from limbstream.launch import free_port
from limbstream.device_emulator.slimevr_tracker import Fleet
from support.stack import PAPER10, StatsWatch, stack, wait_until  # noqa: F401  (the fixture)
from support.slimevr import free_udp_port


def motion(fs: float, seconds: float) -> np.ndarray:
    """(T, 10, 4): each segment swings about its own axis, 0.5 Hz, +-40 degrees."""
    t = np.arange(int(fs * seconds)) / fs
    q = np.zeros((len(t), 10, 4))
    for s in range(10):
        axis = np.array([math.cos(s), math.sin(s), 0.5])
        axis /= np.linalg.norm(axis)
        angle = math.radians(40) * np.sin(2 * math.pi * 0.5 * t + s)
        q[:, s, 0] = np.cos(angle / 2)
        q[:, s, 1:] = np.sin(angle / 2)[:, None] * axis
    return q


def test_ten_trackers_reach_the_aggregator(stack):  # noqa: F811
    stack.router()
    stack.start("clock", "clock", "--connect", stack.endpoint)
    stack.aggregator()
    port = free_udp_port()
    stack.start("gateway", "gateway", "slimevr", "--connect", stack.endpoint, "--udp", f"127.0.0.1:{port}",
                "--subject", "s01", *PAPER10, "-v")
    watch = StatsWatch(stack.endpoint)
    fleet = Fleet(("127.0.0.1", port), motion(50.0, 10.0), wire.SEGMENTS, 50.0)
    stop = threading.Event()
    sender = threading.Thread(target=lambda: (fleet.connect(), fleet.run(stop)))
    sender.start()
    try:
        def ready():
            devices = [d for d in watch.poll().values() if d["subject"] == "s01"]
            return (len(devices) == 10 and all(
                d["online"] and d["points"] > 5 and 0 < d["icr"] < 1 and d["aad_deg"] is not None
                and d["live_err_deg"] is not None and d["battery_pct"] is not None for d in devices) and devices)
        devices = wait_until(ready, 90, "10 online trackers with points, ICR, errors and battery in the stats",
                             on_fail=stack.logs)
        print("\n" + "\n".join(f"{d['device']}: icr {d['icr']:.3f} aad {d['aad_deg']:.3f} live {d['live_err_deg']:.3f} "
                               f"p99 {d['p99_deg']:.3f} pps {d['link_pps']:.1f}" for d in devices))
        for d in devices:
            assert d["tracker"].endswith("/0") and d["battery_pct"] == pytest.approx(80.0) and d["signal_dbm"] == -60
            assert d["link_pps"] > 10 and d["link_loss"] == 0.0
            assert d["aad_deg"] < 3.0, d  # points against the tracker's own stream
            assert d["live_bound_deg"] == wire.LIVE_MODE["live_bound_deg"]
        assert {d["segment"] for d in devices} == set(wire.SEGMENTS)
    finally:
        stop.set()
        sender.join()
        fleet.close()
        watch.close()


def test_up_starts_the_gateway(stack, tmp_path):  # noqa: F811
    """``limbstream up --subjects 0 --slimevr PORT``: the gateway alone behind the router and the
    aggregator; a tracker finds it and its device reaches the stats."""
    port = free_udp_port()
    stack.start("up", "up", "--router", stack.endpoint, "--no-dashboard",
                "--subjects", "0", "--slimevr", f"127.0.0.1:{port}", "--slimevr-subject", "sv07",
                "--status-file", str(tmp_path / "status.json"))
    fleet = Fleet(("127.0.0.1", port), motion(50.0, 4.0)[:, :1], ["hip"], 50.0)
    stop = threading.Event()
    sender = threading.Thread(target=lambda: (fleet.connect(60), fleet.run(stop)))
    sender.start()
    watch = None
    try:
        wait_until(lambda: (tmp_path / "status.json").exists() and "slimevr" in json.loads(
            (tmp_path / "status.json").read_text())["parts"], 60, "up's status naming the gateway", on_fail=stack.logs)
        watch = StatsWatch(stack.endpoint)
        wait_until(lambda: (d := watch.poll().get("sv07/hip")) and d["online"] and d["points"] > 2, 60,
                   "the tracker's device in the stats", on_fail=stack.logs)
        parts = json.loads((tmp_path / "status.json").read_text())["parts"]
        assert "emulator" not in parts and {"router", "aggregator", "slimevr"} <= set(parts)
    finally:
        stop.set()
        sender.join()
        fleet.close()
        if watch is not None:
            watch.close()


def test_up_plan_passes_the_gateway_its_flags():
    import argparse
    from limbstream.cli import up as up_cli
    parser = argparse.ArgumentParser()
    up_cli.add_arguments(parser)
    args = parser.parse_args(["--slimevr", "7000", "--no-truth", "--no-sync", "--threshold", "0.002"])
    [argv] = [a for name, a in up_cli.plan(args) if name == "slimevr"]
    assert argv[:6] == ["gateway", "slimevr", "--udp", "7000", "--subject", "sv01"]
    assert {"--no-truth", "--no-sync"} <= set(argv) and argv[argv.index("--threshold") + 1] == "0.002"
    assert argv[argv.index("--live-bound-deg") + 1] == str(wire.LIVE_MODE["live_bound_deg"])
    assert "--assignments-file" not in argv
    args = parser.parse_args(["--slimevr", "7000", "--status-file", "/var/lib/ls/status.json"])
    [argv] = [a for name, a in up_cli.plan(args) if name == "slimevr"]
    assert argv[argv.index("--assignments-file") + 1] == "/var/lib/ls/slimevr-assignments.json"
    assert up_cli.run(parser.parse_args(["--slimevr", "x:99999"])) == 2


def test_a_taken_port_is_a_clear_error():
    import subprocess
    import sys
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        result = subprocess.run([sys.executable, "-m", "limbstream.cli", "gateway", "slimevr", "--udp",
                                 f"127.0.0.1:{port}", "--connect", "tcp/127.0.0.1:1"],
                                capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert f"cannot listen on 127.0.0.1:{port}" in result.stderr


def test_a_bad_assignments_file_is_a_clear_error(tmp_path):
    import subprocess
    import sys
    bad = tmp_path / "assignments.json"
    bad.write_text('[{"tracker": "02:00:00:00:01:05", "sensor": 0, "segment": "tail"}]')
    router = f"tcp/127.0.0.1:{free_port()}"
    with zconfig.open_session(zconfig.ZenohSettings(mode="router", listen=(router,), connect=())):
        result = subprocess.run([sys.executable, "-m", "limbstream.cli", "gateway", "slimevr", "--udp", "127.0.0.1:0",
                                 "--assignments-file", str(bad), "--no-sync", "--connect", router],
                                capture_output=True, text=True, timeout=60)
    assert result.returncode == 1, result.stderr
    assert f"error: assignments file {bad}: segment must be one of" in result.stderr
