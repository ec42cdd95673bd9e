"""``limbstream up`` as a user starts it: from any folder (one holding a clone named
``limbstream`` too), with flags checked before anything starts, and stopped by Ctrl-C at any step
of its start with ``limbstream up: stopped``, no traceback and no part left running.

Real processes on free loopback ports; each step is waited for on the line ``up`` prints for it."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from support.command import Command
from support.stack import PAPER10, free_port

from limbstream import cli

pytestmark = pytest.mark.e2e

SCRIPT = Path(sys.executable).parent / "limbstream"
"""The installed entry point, as a user runs it."""


def gone(pid: int) -> bool:
    """True if the process no longer runs (a zombie counts as gone)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def up(cwd: Path, *extra: str) -> tuple[Command, Path]:
    """``limbstream up`` (the entry point) on free ports in ``cwd`` (the generator on paper10's
    10 segments unless ``extra`` gives a source); its status file."""
    status = cwd / "up-status.json"
    layout = () if "--source" in extra else PAPER10
    argv = [str(SCRIPT), "up", "--subjects", "1", "--router", f"tcp/127.0.0.1:{free_port()}",
            "--http", f"127.0.0.1:{free_port()}", "--status-file", str(status), *layout, *extra]
    return Command(" ".join(argv), cwd=cwd, shell=True), status


def stopped_cleanly(cmd: Command, status: Path, codes: tuple[int, ...]) -> None:
    code, _ = cmd.exit_code(60.0)
    lines = cmd.rest()
    assert code in codes and "Traceback" not in "\n".join(lines), (code, lines)
    assert lines[-1] == "limbstream up: stopped", lines
    if status.exists():
        pids = [part["pid"] for part in json.loads(status.read_text())["parts"].values() if part["pid"]]
        assert all(gone(pid) for pid in pids), [pid for pid in pids if not gone(pid)]


def test_up_runs_from_the_folder_that_holds_a_clone(tmp_path):
    """``cd ~; limbstream up`` with the clone at ``~/limbstream``: the parts start from the
    installed package, not from the folder in the working directory."""
    clone = tmp_path / "limbstream"
    (clone / "limbstream").mkdir(parents=True)
    (clone / "README.md").write_text("a clone of the repository\n")
    cmd, status = up(tmp_path)
    cmd.wait_line("Ctrl-C stops everything.", timeout=120)
    cmd.interrupt()
    stopped_cleanly(cmd, status, (0,))
    assert not any("failed to start" in line or "No module named" in line for line in cmd.rest()), cmd.rest()


@pytest.mark.parametrize("step", [
    "limbstream up: loading",
    "limbstream up: starting the router on",
    "limbstream up: starting clock, emulator, aggregator",
    "limbstream up: starting the dashboard on",
    "Ctrl-C stops everything.",
])
def test_ctrl_c_at_any_step_of_the_start_stops_up_cleanly(step, tmp_path, xio_dir):
    """SIGINT once ``up`` says it is at ``step`` (loading a recording, starting each kind of part,
    running): ``limbstream up: stopped``, no traceback, no part left, exit 0 once running (130
    while starting)."""
    cmd, status = up(tmp_path, "--source", str(xio_dir))
    cmd.wait_line(step, timeout=120)
    cmd.interrupt()
    stopped_cleanly(cmd, status, (0,) if step.startswith("Ctrl-C") else (0, 130))


@pytest.mark.parametrize("argv, message", [
    (["watch", "s01", "--connect", "127.0.0.1:7447"],
     "limbstream watch: error: --connect 127.0.0.1:7447: expected a Zenoh endpoint PROTOCOL/ADDRESS"),
    (["record", "x.mcap", "--connect", "tcp/127.0.0.1:70000"],
     "limbstream record: error: --connect tcp/127.0.0.1:70000: the port must be a number in 1..65535"),
    (["aggregate", "--listen", "tcp/127.0.0.1"], "limbstream aggregate: error: --listen tcp/127.0.0.1: expected HOST:PORT"),
    (["router", "--listen", "udp/[::1]:x"], "limbstream router: error: --listen udp/[::1]:x: the port must be a number"),
    (["calibrate", "s01", "--pose", "rest", "--connect-timeout", "-1"],
     "limbstream calibrate: error: --connect-timeout must be >= 0, got -1"),
    (["emulate", "--imu-model", "icm42688p"], "limbstream emulate: error: --imu-model applies to raw sensors only"),
    (["eval", "x.npz", "--imu-rate", "400"], "limbstream eval: error: --imu-rate applies to raw sensors only"),
    (["dashboard", "--http", "127.0.0.1:99999"], "--http 127.0.0.1:99999: the port must be a number in 0..65535"),
])
def test_the_shared_flags_are_checked_before_a_command_starts(argv, message, tmp_path, capsys, monkeypatch):
    """The flags of limbstream/cli/flags.py: one line naming the flag, exit status 2, nothing
    written or connected."""
    monkeypatch.chdir(tmp_path)
    try:
        code = cli.main(argv)
    except SystemExit as exc:  # argparse's own error: the dashboard's --http is an argparse type
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and message in err[-1] and "Json5Err" not in "\n".join(err), (code, err)
    assert argv[0] == "dashboard" or len(err) == 1, err
    assert not list(tmp_path.iterdir())
