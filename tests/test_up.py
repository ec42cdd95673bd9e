"""``limbstream up`` keeps the live system running: its parts are SIGKILLed one after another and
come back by themselves; a part that keeps failing, or cannot start, stops ``up`` with one line.

Real processes on free loopback ports. The kill test prints one ``UP |`` line per part (time
from the SIGKILL to the part being back) that docs/reliability.md collects:
``pytest tests/test_up.py -s | grep 'UP |'``.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from support.stack import PAPER10, StatsWatch, free_port, http_json, stack, wait_until  # noqa: F401  (fixture)

from limbstream import wire, zconfig
from limbstream.cli import flags
from limbstream.launch import Child, ChildExited, CrashLoop, RestartPolicy, Supervisor, port_open

PERIOD_US = 20_000  # exact frames at 50 Hz


def report(part: str, how: str, back: str) -> None:
    print(f"\nUP | {part} | {how} | {back} |")


def gone(pid: int) -> bool:
    """True if the process no longer runs (a zombie counts as gone)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def taken_port(port: int) -> socket.socket:
    """Another process's listener on 127.0.0.1:port (SO_REUSEADDR: the port may have TIME_WAIT
    connections of the process killed a moment ago)."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("127.0.0.1", port))
    s.listen()
    return s


class Up:
    """A ``limbstream up`` process of the test's stack and its status file; on the generator the
    paper's 10 segments a subject (``--layout paper10``) unless ``extra`` gives a layout."""

    def __init__(self, stack, tmp_path: Path, *extra: str, http: str | None = None):  # noqa: F811
        self.status_file = tmp_path / "up-status.json"
        self.http = http or f"127.0.0.1:{free_port()}"
        self.url = f"http://{self.http}"
        dashboard = () if "--no-dashboard" in extra else ("--http", self.http)  # (--http needs the dashboard)
        layout = () if "--layout" in extra or "--source" in extra else PAPER10
        self.child = stack.start("up", "up", "--router", stack.endpoint, *dashboard,
                                 "--status-file", str(self.status_file), *layout, *extra)
        self.logs = stack.logs

    def status(self) -> dict:
        if not self.child.alive():
            raise ChildExited(self.child)
        return json.loads(self.status_file.read_text())

    def part(self, name: str) -> dict:
        return self.status()["parts"][name]

    def kill(self, name: str) -> tuple[int, float]:
        """SIGKILL a part; (its pid, time of the kill)."""
        pid = json.loads(self.status_file.read_text())["parts"][name]["pid"]
        os.kill(pid, signal.SIGKILL)
        return pid, time.monotonic()

    def restarted(self, name: str, old_pid: int) -> bool:
        part = self.part(name)
        return part["state"] == "running" and part["pid"] != old_pid

    def output(self) -> list[str]:
        return self.child.tail(200)

    def said(self) -> list[str]:
        """What ``up`` itself said, less the steps of its start (``limbstream up: starting ...``)."""
        return [line for line in self.output() if line.startswith("limbstream up:")
                and not line.startswith(("limbstream up: starting ", "limbstream up: loading "))]

    def wait_exit(self, timeout: float) -> int:
        wait_until(lambda: not self.child.alive(), timeout, "limbstream up to stop", on_fail=self.logs)
        return self.child.returncode


class Frames:
    """Exact pose frames of some subjects as they arrive."""

    def __init__(self, session: zenoh.Session, subjects: list[str]):
        self.subs = {s: session.declare_subscriber(wire.pose_key(s), zenoh.handlers.FifoChannel(1 << 16))
                     for s in subjects}
        self.t = {s: [] for s in subjects}
        self.arrival = {s: [] for s in subjects}

    def poll(self) -> dict[str, list[int]]:
        for subject, sub in self.subs.items():
            while (sample := sub.try_recv()) is not None:
                frame = wire.decode_pose(sample.payload.to_bytes())
                if frame.kind == wire.KIND_EXACT:
                    self.t[subject].append(frame.t_us)
                    self.arrival[subject].append(time.monotonic())
        return self.t

    def first_after(self, subject: str, since: float) -> float | None:
        """Arrival of the first frame received after ``since`` (monotonic), or None."""
        self.poll()
        return next((a for a in self.arrival[subject] if a > since), None)

    def largest_hole_us(self, subject: str, since_t_us: int) -> int:
        t = np.array(sorted({x for x in self.t[subject] if x >= since_t_us}))
        return int(np.diff(t).max()) if len(t) > 1 else 0


def nothing_lost(watch: StatsWatch, devices: list[str], what: str, on_fail) -> None:
    """Every device's own count of published points reaches the aggregator (asked now, then waited
    for), with no sequence gap and no Zenoh miss."""
    own = {d: watch.device_status(d)["points"] for d in devices}
    wait_until(lambda: all(watch.poll()[d]["points"] >= own[d] for d in devices), 30,
               f"the aggregator to receive every point the devices published ({what})", on_fail=on_fail)
    gaps = {d: watch.devices[d]["gaps"] for d in devices if watch.devices[d]["gaps"]}
    missed = sum((s.get("aggregator") or {}).get("missed", 0) for s in watch.subjects.values())
    assert not gaps and missed == 0, f"{what}: gaps {gaps}, missed {missed}"


# ----------------------------------------------------------------------------- plan


def test_up_runs_live_mode_unless_told_otherwise():
    """``up``'s emulators get wire.LIVE_MODE; any tunable flag given to ``up`` wins."""
    from limbstream.cli import up as up_cli

    def emulator_config(*argv: str) -> wire.DeviceConfig:
        parser = argparse.ArgumentParser()
        up_cli.add_arguments(parser)
        args = parser.parse_args(["--no-sync", *argv])
        [emulate] = [a for name, a in up_cli.plan(args) if name == "emulator"]
        sub = argparse.ArgumentParser()
        flags.add_device_config(sub)
        known, _ = sub.parse_known_args(emulate)
        return flags.device_config(known)

    assert emulator_config() == wire.DeviceConfig(**wire.LIVE_MODE)
    off = emulator_config("--live-bound-deg", "0", "--threshold", "0.01")
    assert (off.live_bound_deg, off.threshold) == (0.0, 0.01)


def test_up_passes_raw_sensors_on_and_calibrates_them():
    """``up --imu raw``: the emulators get the raw sensors' flags, the aggregator calibrates."""
    from limbstream.cli import up as up_cli
    parser = argparse.ArgumentParser()
    up_cli.add_arguments(parser)
    parts = dict(up_cli.plan(parser.parse_args(["--no-sync", "--imu", "raw", "--imu-model", "icm42688p",
                                                "--mounting-deg", "90", "--heading-deg", "180"])))
    emulate = " ".join(parts["emulator"])
    assert "--imu raw --imu-model icm42688p --imu-rate 200" in emulate and "--mounting-deg 90" in emulate, emulate
    assert "--calibrate-on-start" in parts["aggregator"]
    parts = dict(up_cli.plan(parser.parse_args(["--no-sync", "--imu", "raw", "--vqf-precision", "single"])))
    assert "--vqf-precision single" in " ".join(parts["emulator"])


@pytest.mark.parametrize("argv, message", [
    (["--source", "{tmp}/missing.npz"], "{tmp}/missing.npz: no such file or folder"),
    (["--speed", "0"], "--speed must be > 0, got 0"),
    (["--subjects", "-2"], "--subjects must be >= 1, got -2"),
    (["--subjects", "-2", "--slimevr", "6969"], "--subjects must be >= 0 (0: the SlimeVR trackers alone), got -2"),
    (["--emulators", "0"], "--emulators must be >= 1, got 0"),
    (["--clock-drift-ppm", "5000"], "--clock-drift-ppm must be in 0..1000, got 5000.0"),
    (["--source", "{xsens}"], "no sensor maps to a body segment (sensors found: 00B421E6,"),
    (["--names", "opensense"], "--names maps the sensors of an IMU recording; the generator has none"),
    (["--imu", "raw", "--yaw-drift-dps", "0.1"], "--yaw-drift-dps is the modelled sensors' drift formula"),
    (["--imu", "raw", "--clock-drift-ppm", "50"], "--imu raw samples on the feed's own clock"),
    (["--router", "127.0.0.1:7447"], "--router 127.0.0.1:7447: expected a Zenoh endpoint PROTOCOL/ADDRESS, e.g. "
                                     "tcp/127.0.0.1:7447"),
    (["--router", "tcp/127.0.0.1:74470"], "--router tcp/127.0.0.1:74470: the port must be a number in 0..65535"),
    (["--router", "tcp/127.0.0.1:0"], "--router tcp/127.0.0.1:0: the parts need the router's port"),
    (["--router", "tcp/127.0.0.1:7447,tcp/127.0.0.1:7448"], "expected one endpoint PROTOCOL/HOST:PORT"),
    (["--http", "127.0.0.1:99999"], "--http 127.0.0.1:99999: the port must be a number in 1..65535, got '99999'"),
    (["--http", "127.0.0.1"], "--http 127.0.0.1: expected HOST:PORT"),
    (["--imu-model", "icm42688p"], "--imu-model applies to raw sensors only: add --imu raw"),
    (["--imu-rate", "400"], "--imu-rate applies to raw sensors only: add --imu raw"),
    (["--imu", "raw", "--imu-model", "bmi270"], "--imu-model must be one of ideal, icm42688p, got 'bmi270'"),
    (["--slimevr-subject", "sv02"], "--slimevr-subject applies only with --slimevr"),
    (["--no-dashboard", "--http", "127.0.0.1:8001"], "--http applies only with the dashboard"),
    (["--layout", "fullest"], "--layout: layout must be one of paper10, full or a .toml/.json file, got 'fullest'"),
    (["--layout", "full", "--height-m", "3"], "--height-m: height must be within [0.5, 2.5] m, got 3.0"),
])
def test_up_checks_its_flags_and_source_before_starting_anything(argv, message, tmp_path, xsens_dir, capsys):
    """A bad flag or source is one error line naming it alone, exit 2, before any part starts."""
    from limbstream.cli import up as up_cli
    parser = argparse.ArgumentParser()
    up_cli.add_arguments(parser)
    args = parser.parse_args([a.format(tmp=tmp_path, xsens=xsens_dir) for a in argv]
                             + ["--status-file", str(tmp_path / "status.json")])
    assert up_cli.run(args) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("limbstream up: error: ") and \
        message.format(tmp=tmp_path, xsens=xsens_dir) in err[0], err
    assert not (tmp_path / "status.json").exists(), "nothing started"


def test_up_banner_counts_the_devices_that_run_and_prints_client_commands(xio_dir, monkeypatch):
    from limbstream.cli import up as up_cli
    monkeypatch.delenv(zconfig.ROUTER_ENV, raising=False)
    parser = argparse.ArgumentParser()
    up_cli.add_arguments(parser)
    args = parser.parse_args(["--source", str(xio_dir), "--subjects", "2", "--router", "tcp/127.0.0.1:7448"])
    devices = up_cli.check(args)
    assert up_cli.running(devices, args) == (f"2 subjects x 7 devices (l_foot, l_shank, l_thigh, r_foot, r_shank, "
                                             f"r_thigh, hip), source {xio_dir}")
    command = up_cli.typed_command()  # this interpreter's limbstream, as the shell finds it
    assert up_cli.client_commands(args)[0] == f"{command} watch s01 --connect tcp/127.0.0.1:7448"
    monkeypatch.setenv(zconfig.ROUTER_ENV, "tcp/127.0.0.1:7448")  # up's --router and every --connect default to it
    parser = argparse.ArgumentParser()
    up_cli.add_arguments(parser)
    default = parser.parse_args([])
    assert default.router == "tcp/127.0.0.1:7448" and up_cli.client_commands(default)[0] == f"{command} watch s01"
    assert up_cli.running(up_cli.check(default), default) == "2 subjects x 15 devices (layout full), source generator"


def test_up_streams_the_generator_in_the_layout_asked_for(xio_dir, tmp_path, monkeypatch):
    """``up --layout full``: its emulators get the layout and the body flags; full is the default,
    ``--layout paper10`` the paper's 10 segments; a recording's segments must be in the layout."""
    from limbstream.body import FULL
    from limbstream.cli import up as up_cli
    parser = argparse.ArgumentParser()
    up_cli.add_arguments(parser)
    args = parser.parse_args(["--layout", "full", "--height-m", "1.8", "--no-sync"])
    assert up_cli.check(args) == [FULL.segment_names] * 2
    assert up_cli.running(up_cli.check(args), args) == "2 subjects x 15 devices (layout full), source generator"
    [emulate] = [argv for name, argv in up_cli.plan(args) if name == "emulator"]
    assert emulate[emulate.index("--layout") + 1] == "full" and emulate[emulate.index("--height-m") + 1] == "1.8"
    default = parser.parse_args(["--no-sync"])
    assert "--layout" not in dict(up_cli.plan(default))["emulator"] and up_cli.check(default) == [FULL.segment_names] * 2
    paper = parser.parse_args(["--layout", "paper10", "--no-sync"])
    assert up_cli.check(paper) == [wire.SEGMENTS] * 2 and "--layout paper10" in " ".join(dict(up_cli.plan(paper))["emulator"])
    assert up_cli.running(up_cli.check(paper), paper) == "2 subjects x 10 devices (layout paper10), source generator"
    with pytest.raises(ValueError, match="--layout paper10: the source .* moves segments l_foot, r_foot, not in"):
        up_cli.check(parser.parse_args(["--source", str(xio_dir), "--layout", "paper10"]))
    assert up_cli.check(parser.parse_args(["--source", str(xio_dir), "--layout", "full"]))[0][0] == "l_foot"
    legs = {"name": "legs", "segments": [  # a layout file of segments the generator moves: passed on by its path
        {"name": "hip", "joint": "pelvis", "end": "spine", "direction": [0, 1, 0], "height_fraction": 0.1},
        {"name": "r_thigh", "parent": "hip", "joint": "pelvis", "end": "r_knee", "direction": [0, -1, 0],
         "height_fraction": 0.245}]}
    (tmp_path / "legs.json").write_text(json.dumps(legs))
    monkeypatch.chdir(tmp_path)
    args = parser.parse_args(["--layout", "legs.json", "--no-sync"])
    assert up_cli.check(args) == [("hip", "r_thigh")] * 2
    emulate = dict(up_cli.plan(args))["emulator"]
    assert emulate[emulate.index("--layout") + 1] == str(tmp_path / "legs.json")


def test_a_recording_is_one_subject_unless_more_are_asked_for(xsens_dir, monkeypatch):
    """``up``/``emulate --source`` a recording: its one person (the generator: 2 subjects);
    ``--subjects N`` asks for copies; the banner counts what runs."""
    from limbstream.cli import emulate as emulate_cli
    from limbstream.cli import up as up_cli
    monkeypatch.delenv("LIMBSTREAM_SUBJECTS", raising=False)

    def up_args(*argv: str) -> argparse.Namespace:
        parser = argparse.ArgumentParser()
        up_cli.add_arguments(parser)
        return parser.parse_args(list(argv))

    args = up_args("--source", str(xsens_dir), "--names", "opensense")
    assert up_cli.running(up_cli.check(args), args).startswith("1 subject x 7 devices (")
    assert [argv[argv.index("--subjects") + 1] for _, argv in up_cli.plan(args) if argv[0] == "emulate"] == ["1"]
    args = up_args("--source", str(xsens_dir), "--names", "opensense", "--subjects", "3")
    assert up_cli.running(up_cli.check(args), args).startswith("3 subjects x 7 devices (")
    args = up_args()
    assert up_cli.running(up_cli.check(args), args) == "2 subjects x 15 devices (layout full), source generator"

    def feeds(*argv: str) -> list[str]:
        parser = argparse.ArgumentParser()
        emulate_cli.add_arguments(parser)
        args = parser.parse_args(list(argv))
        emulate_cli.validate(args)
        return sorted(emulate_cli.build_feeds(args))
    assert feeds("--source", str(xsens_dir), "--names", "opensense") == ["s01"]
    assert feeds() == ["s01", "s02"]
    monkeypatch.setenv("LIMBSTREAM_SUBJECTS", "3")
    assert feeds("--source", str(xsens_dir), "--names", "opensense") == ["s01", "s02", "s03"]


def test_up_prints_client_commands_that_the_shell_finds(monkeypatch, tmp_path):
    """The banner's ``limbstream``: the bare name when PATH finds this interpreter's entry point,
    else its path (relative to the working directory when below it), which runs as printed."""
    from limbstream.cli import up as up_cli
    script = Path(sys.executable).parent / "limbstream"
    monkeypatch.setenv("PATH", f"{script.parent}{os.pathsep}/usr/bin:/bin")
    assert up_cli.typed_command() == "limbstream"
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    monkeypatch.chdir(script.parent.parent.parent)  # (a venv's folder: .venv/bin/limbstream below it)
    assert up_cli.typed_command() == os.path.join(script.parent.parent.name, "bin", "limbstream")
    monkeypatch.chdir(tmp_path)
    assert up_cli.typed_command() == str(script)


def test_subjects_sharing_a_clip_start_apart_unless_told_otherwise():
    """Two subjects on one clip: the second starts 61.8 % into it; --same-start: in step. With two
    clips, the subjects take them in turn, each at its start."""
    from limbstream.cli.emulate import clip_of
    assert [clip_of(k, 1) for k in (1, 2, 3)] == [(0, 0.0), (0, pytest.approx(0.618, abs=1e-3)),
                                                  (0, pytest.approx(0.236, abs=1e-3))]
    assert [clip_of(k, 1, same_start=True) for k in (1, 2)] == [(0, 0.0), (0, 0.0)]
    assert [clip_of(k, 2) for k in (1, 2, 3)] == [(0, 0.0), (1, 0.0), (0, pytest.approx(0.618, abs=1e-3))]


# ----------------------------------------------------------------------------- supervisor


def test_supervisor_backs_off_and_stops_a_crash_loop(tmp_path):
    """Real children that exit at once: restarts wait 0.5, 1, 2, 4 s (times given to poll), the
    back-off starts over after a healthy minute, and the 5th exit within 60 s is a crash loop
    naming the child and its last line of output."""
    child = Child("flaky", [sys.executable, "-c", "print('flaky: cannot open /dev/flux'); raise SystemExit(3)"],
                  log=tmp_path / "flaky.log").start()
    messages: list[str] = []
    sup = Supervisor([child], RestartPolicy(), report=messages.append)
    now = time.monotonic()
    delays = []
    with pytest.raises(CrashLoop) as loop:
        for _ in range(10):
            child.popen.wait()
            assert sup.poll(now)                       # the exit is noted ...
            due = sup.records["flaky"].due
            delays.append(round(due - now, 3))
            assert not sup.poll(due - 0.01) and not child.alive()  # ... nothing starts before its time
            assert sup.poll(due) and sup.status()["flaky"]["state"] in ("running", "exited")
            now = due
    assert delays == [0.5, 1.0, 2.0, 4.0], delays
    assert sup.status()["flaky"]["restarts"] == 4
    assert str(loop.value) == "flaky exited 5 times within 60 s (exit status 3): flaky: cannot open /dev/flux"
    assert messages[0] == "flaky exit status 3; starting it again in 0.5 s", messages
    assert messages[1].startswith("flaky started again (pid ") and messages[1].endswith(", restart 1)"), messages

    # exits a minute apart: never a loop, and each ran a healthy minute, so the back-off starts over
    sup = Supervisor([child.start()], RestartPolicy(), report=messages.append)
    base = time.monotonic()
    for k in range(1, 9):
        child.popen.wait()
        t = base + 61.0 * k
        assert sup.poll(t)
        assert sup.records["flaky"].due == pytest.approx(t + 0.5)
        assert sup.poll(t + 0.5)
    assert sup.status()["flaky"]["restarts"] == 8
    child.popen.wait()


# ----------------------------------------------------------------------------- up


def test_up_brings_back_each_killed_part(stack, tmp_path):  # noqa: F811
    """Under ``up`` (2 emulator processes, 1 subject each), SIGKILL the router, one emulator, the
    aggregator and the dashboard, one after another: each comes back by itself — points flow
    again with none lost (router, aggregator), devices online again (emulator), exact frames on
    the 50 Hz grid resume, the dashboard answers and shows the restart counts (/health,
    /metrics). Finally the dashboard's port is taken while it restarts: ``up`` stops with one
    line naming it and the cause, and no child outlives it."""
    up = Up(stack, tmp_path, "--subjects", "2", "--emulators", "2", "--max-exits", "3")
    wait_until(lambda: up.status()["state"] == "running", 60, "up to start every part", on_fail=up.logs)
    watch = StatsWatch(stack.endpoint)
    frames = Frames(watch.session, ["s01", "s02"])
    try:
        def online(subjects=("s01", "s02")) -> bool:
            mine = [d for d in watch.poll().values() if d["subject"] in subjects]
            return len(mine) == 10 * len(subjects) and all(d["online"] for d in mine)
        wait_until(lambda: online() and all(len(v) > 50 for v in frames.poll().values()), 60,
                   "20 devices online and exact frames of both subjects", on_fail=up.logs)
        assert http_json(up.url + "/health")[0] == 200
        devices = sorted(watch.devices)
        live = wire.DeviceConfig(**wire.LIVE_MODE)  # up's devices run live mode by default
        wait_until(lambda: all(watch.poll()[d]["threshold"] is not None for d in devices), 30,
                   "the aggregator to learn every device's settings (config poll)", on_fail=up.logs)
        settings = {(watch.devices[d]["live_bound_deg"], watch.devices[d]["threshold"]) for d in devices}
        assert settings == {(live.live_bound_deg, live.threshold)}, settings

        # router: clients reconnect; the devices' caches resend what was published meanwhile
        before = {d: watch.devices[d]["points"] for d in devices}
        pid, killed = up.kill("router")
        wait_until(lambda: up.restarted("router", pid) and port_open("127.0.0.1", stack.port), 30,
                   "the router to be started again", interval=0.01, on_fail=up.logs)
        listening = time.monotonic()
        wait_until(lambda: all(watch.poll()[d]["points"] > before[d] for d in devices), 30,
                   "points of every device after the router restart", interval=0.02, on_fail=up.logs)
        flowing = time.monotonic()
        resumed = wait_until(lambda: all(frames.first_after(s, listening) for s in ("s01", "s02"))
                             and max(frames.first_after(s, listening) for s in ("s01", "s02")), 30,
                             "exact frames after the router restart", interval=0.02, on_fail=up.logs)
        nothing_lost(watch, devices, "router restart", up.logs)
        report("router", "SIGKILL", f"listening again {listening - killed:.2f} s, points of every device "
               f"{flowing - killed:.2f} s, exact frames {resumed - killed:.2f} s; 0 points lost")

        # one emulator (subject s02): a new stream of the same devices
        old = {d: watch.devices[d]["stream"] for d in devices if d.startswith("s02/")}
        last_t = max(frames.poll()["s02"])
        pid, killed = up.kill("emulator2")

        def new_stream_online() -> bool:
            now = watch.poll()
            return all(now[d]["online"] and now[d]["stream"] != old[d] for d in old)
        wait_until(new_stream_online, 30, "s02's devices online with a new stream", interval=0.02,
                   on_fail=up.logs)
        back_online = time.monotonic()

        def s02_frames_after_restart():
            frames.poll()
            return next((a for t, a in zip(frames.t["s02"], frames.arrival["s02"]) if t > last_t and a > killed),
                        None)
        resumed = wait_until(s02_frames_after_restart, 30, "exact frames of s02's new stream", interval=0.02,
                             on_fail=up.logs)
        assert online(["s01"]), "s01 (the other emulator) stays online"
        report("emulator (10 devices)", "SIGKILL", f"devices online (new stream) {back_online - killed:.2f} s, "
               f"exact frames {resumed - killed:.2f} s")

        # aggregator: the new one asks the devices for their history
        last = {s: max(frames.poll()[s]) for s in ("s01", "s02")}
        n_before = {s: len(frames.t[s]) for s in ("s01", "s02")}
        pid, killed = up.kill("aggregator")
        wait_until(lambda: up.restarted("aggregator", pid), 30, "the aggregator to be started again",
                   interval=0.01, on_fail=up.logs)
        started = time.monotonic()
        resumed = wait_until(lambda: all(frames.first_after(s, started) for s in ("s01", "s02"))
                             and max(frames.first_after(s, started) for s in ("s01", "s02")), 30,
                             "exact frames from the new aggregator", interval=0.02, on_fail=up.logs)
        wait_until(lambda: all(max(frames.poll()[s]) > last[s] + 2_000_000 for s in last), 30,
                   "2 s of frames after the aggregator restart", on_fail=up.logs)
        nothing_lost(watch, devices, "aggregator restart", up.logs)
        # frame time as this consumer saw it: the new aggregator starts a subject's frames once every
        # device of it settled (its history in), seconds before the old one's last frame, and publishes
        # them with congestion control BLOCK (zconfig.QOS): no hole (docs/reliability.md)
        start = min(min(frames.t[s][n_before[s]:]) - last[s] for s in last) / 1e3
        holes = {s: frames.largest_hole_us(s, last[s] - 1_000_000) / 1e3 for s in last}
        report("aggregator", "SIGKILL", f"exact frames {resumed - killed:.2f} s (the new process started "
               f"{started - killed:.2f} s after the kill); the first frame after the restart is {start:+.0f} ms "
               f"from the last one before (history), largest hole in frame time {holes['s01']:.0f} ms "
               f"(s02: {holes['s02']:.0f} ms); 0 points lost")
        assert start < 0 and max(holes.values()) <= PERIOD_US / 1e3, (start, holes)
        for s, t in frames.poll().items():
            assert all(x % PERIOD_US == 0 for x in t), f"{s}: exact frames off the 50 Hz grid"

        # dashboard
        pid, killed = up.kill("dashboard")
        wait_until(lambda: up.restarted("dashboard", pid) and http_json(up.url + "/health", timeout=1.0)[0] == 200,
                   30, "the dashboard to answer again", interval=0.01, on_fail=up.logs)
        report("dashboard", "SIGKILL", f"/health answers 200 {time.monotonic() - killed:.2f} s")
        restarts = {name: p["restarts"] for name, p in up.status()["parts"].items()}
        assert restarts == {"router": 1, "clock": 0, "emulator1": 0, "emulator2": 1, "aggregator": 1, "dashboard": 1}, restarts
        health = http_json(up.url + "/health")[1]
        assert {name: p["restarts"] for name, p in health["parts"].items()} == restarts, health
        assert health["parts"]["router"] == {"state": "running", "restarts": 1, "last_exit": "killed by SIGKILL"}
        metrics = http_json(up.url + "/metrics")[1]
        for name, n in restarts.items():
            assert f'limbstream_up_restarts_total{{part="{name}"}} {n:.1f}' in metrics, metrics
        out = "\n".join(up.output())
        for name in ("router", "emulator2", "aggregator", "dashboard"):
            assert f"limbstream up: {name} killed by SIGKILL; starting it again in 0.5 s" in out, out
            assert f"limbstream up: {name} started again (pid " in out, out

        # the dashboard's port taken while it restarts: exits 2 and 3 within 60 s stop everything
        pids = [p["pid"] for p in up.status()["parts"].values()]
        port = int(up.http.rsplit(":", 1)[1])
        os.kill(up.child.pid, signal.SIGSTOP)  # up is paused: it cannot start the dashboard before the port is taken
        try:
            up.kill("dashboard")
            taker = wait_until(lambda: taken_port(port), 10, "the dashboard's port to be free")
        finally:
            os.kill(up.child.pid, signal.SIGCONT)
        with taker:
            assert up.wait_exit(60) == 1
    finally:
        watch.close()
    lines = up.said()
    assert any(line.startswith("limbstream up: dashboard exited 3 times within 60 s (")
               and "address already in use" in line and line.endswith("; stopping") for line in lines), \
        "\n".join(up.output())
    assert lines[-1] == "limbstream up: stopped"
    assert all(gone(pid) for pid in pids), [pid for pid in pids if not gone(pid)]
    assert json.loads(up.status_file.read_text())["state"] == "stopped"


@pytest.mark.parametrize("part", ["router", "dashboard"])
def test_up_stops_with_one_line_when_a_part_cannot_start(stack, tmp_path, part):  # noqa: F811
    """The router's or the dashboard's port is taken by another process: ``up`` does not loop, it
    stops at once with one line naming the part and the cause, and leaves no child behind."""
    port = stack.port if part == "router" else free_port()
    http = f"127.0.0.1:{port}" if part == "dashboard" else None
    with taken_port(port):
        up = Up(stack, tmp_path, "--subjects", "1", "--max-exits", "2", http=http)
        assert up.wait_exit(60) == 1
    lines = [line for line in up.said() if "root translation off" not in line]  # (Up runs paper10: said at start)
    assert lines[-1] == "limbstream up: stopped", lines
    assert len(lines) == 2, lines
    assert lines[0] == f"limbstream up: {part} cannot start: 127.0.0.1:{port} is already in use by another process"
    if up.status_file.exists():
        pids = [p["pid"] for p in json.loads(up.status_file.read_text())["parts"].values()]
        assert pids and all(gone(pid) for pid in pids)


def test_up_draws_the_lower_body_recording_as_a_person(stack, tmp_path, xio_dir):  # noqa: F811
    """``up --source xio_lower_body --subjects 1`` (the x-IMU3 recording, which starts in its rest
    pose): in the exact frames of the first 30 s of the stream, each knee lies below its hip and
    each ankle below its knee in at least 90 % of the frames. At --speed 3: the same frames, in a
    third of the time."""
    up = Up(stack, tmp_path, "--source", str(xio_dir), "--subjects", "1", "--speed", "3", "--no-dashboard")
    # subscribed as soon as up's router listens (the session waits for it), before the emulator and
    # the aggregator have started: every exact frame from the stream's start comes here
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,), connect_timeout_s=60))
    pose = session.declare_subscriber(wire.pose_key("s01"), zenoh.handlers.FifoChannel(1 << 16))
    frames: list[wire.PoseFrame] = []

    def thirty_seconds() -> bool:
        while (sample := pose.try_recv()) is not None:
            frame = wire.decode_pose(sample.payload.to_bytes())
            if frame.kind == wire.KIND_EXACT:
                frames.append(frame)
        return bool(frames) and frames[-1].t_us - frames[0].t_us >= 30_000_000
    try:
        wait_until(lambda: up.status()["state"] == "running", 60, "up to start", on_fail=up.logs)
        wait_until(thirty_seconds, 60, "30 s of exact frames of s01", interval=0.1, on_fail=up.logs)
    finally:
        session.close()
    assert any("1 subject x 7 devices (l_foot, l_shank, l_thigh, r_foot, r_shank, r_thigh, hip)" in line
               for line in up.output()), up.output()
    first = [f for f in frames if f.t_us - frames[0].t_us <= 30_000_000]
    joints = np.array([f.joints for f in first])
    at = first[0].layout.joint_index  # the recording's feet make it a full-layout subject
    assert first[0].layout.name == "full" and all(f.layout == first[0].layout for f in first)
    y = {name: joints[:, j, 1] for name, j in at.items()}
    upright = np.ones(len(first), bool)
    for side in "lr":
        upright &= (y[f"{side}_knee"] < y[f"{side}_hip"]) & (y[f"{side}_ankle"] < y[f"{side}_knee"])
    print(f"\nUP | x-IMU3 lower body | {len(first)} exact frames over 30 s | knees below hips and ankles below "
          f"knees in {100 * upright.mean():.1f} % |")
    assert len(first) > 1000 and upright.mean() >= 0.9, (len(first), upright.mean())
    assert all(f.flags & wire.FRAME_MISSING for f in first), "no arms, no neck: flagged MISSING"


def test_up_removes_its_temporary_folder_with_what_the_parts_kept_there(stack, tmp_path):  # noqa: F811
    """Without --status-file, ``up`` keeps its status in a temporary folder, and with modelled
    sensors the aggregator keeps its calibrations beside it: on Ctrl-C the folder goes, whole."""
    child = stack.start("up", "up", "--router", stack.endpoint, "--subjects", "1", "--no-dashboard", *PAPER10,
                        "--mounting-deg", "90", "--heading-deg", "180", env={"TMPDIR": str(tmp_path)})
    wait_until(lambda: list(tmp_path.glob("limbstream-up-*/calibrations.json")), 90,
               "the aggregator to keep its calibrations in up's folder", on_fail=stack.logs)
    child.signal(signal.SIGINT)
    wait_until(lambda: not child.alive(), 60, "limbstream up to stop", on_fail=stack.logs)
    out = "\n".join(child.tail(200))
    assert child.returncode == 0 and "Traceback" not in out, out
    assert out.splitlines()[-1] == "limbstream up: stopped", out
    assert not list(tmp_path.glob("limbstream-up-*")), list(tmp_path.iterdir())
