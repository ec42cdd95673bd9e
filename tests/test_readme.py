"""The README's first screen works as printed: every command of its Quick start block, then every
client command ``limbstream up`` prints in its banner under ``make run``, run exactly as written
from the repository's folder, with the repository's ``.venv`` (``make run`` makes it, when needed).

A command that runs until Ctrl-C is started, waited for on the line that shows it works (the
banner, a frame, the recording's start, pytest starting its workers) and stopped with SIGINT
to its process group, as Ctrl-C in a terminal does. ``make run`` listens on its fixed ports
(7447, 8000): everything runs in a network namespace of its own, whose loopback nothing else uses.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import uuid

import pytest
from support import ROOT, require
from support.command import Command

pytestmark = [pytest.mark.e2e, pytest.mark.root, pytest.mark.slow]

GUARD = "LIMBSTREAM_README_TEST"
"""Set for the ``make test`` this test starts: the test does not start itself again there."""
READY = {
    "make run": "Ctrl-C stops everything.",
    "make test": "created: ",  # pytest-xdist has started its workers
    " watch ": " live #",
    " record ": "recording subjects",
}
"""Commands that run until Ctrl-C (by a part of the line) -> the line that shows each works."""
ONCE = {
    " calibrate ": ("devices calibrated (rest)", "refused: "),
}
"""Commands that end by themselves -> the lines of an answer (the aggregator's: done or refused)."""


def quick_start() -> list[str]:
    """The commands of the README's Quick start block, comments left out."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Quick start\s+```sh\n(.*?)```", text, re.S)
    assert block, "README.md has a Quick start block"
    return [line.split("#", 1)[0].strip() for line in block.group(1).splitlines() if line.split("#", 1)[0].strip()]


def banner_commands(lines: list[str]) -> list[str]:
    """The client commands of up's banner: the ``try`` line and the lines under it."""
    start = next(k for k, line in enumerate(lines) if line.startswith("  try "))
    commands = [lines[start][len("  try "):].strip()]
    for line in lines[start + 1:]:
        if not line.startswith("    ") or not line.strip():
            break
        commands.append(line.strip())
    return commands


@pytest.fixture
def netns():
    """A network namespace with its loopback up; removed afterwards."""
    require(os.geteuid() == 0 and shutil.which("ip") is not None, "network namespaces need root and iproute2")
    name = f"lsreadme{uuid.uuid4().hex[:8]}"
    subprocess.run(["ip", "netns", "add", name], check=True)
    try:
        subprocess.run(["ip", "netns", "exec", name, "ip", "link", "set", "lo", "up"], check=True)
        yield ["ip", "netns", "exec", name]
    finally:
        subprocess.run(["ip", "netns", "del", name], check=False)


def run_as_printed(line: str, prefix: list[str], env: dict[str, str], keep: list[Command]) -> None:
    """Run ``line`` in the repository's folder and check it works: until its ready line, then
    Ctrl-C (``make run`` is kept running in ``keep``), or to its end and its answer."""
    cmd = Command(line, cwd=ROOT, env=env, shell=True, prefix=prefix)
    ready = next((text for part, text in READY.items() if part in f" {line} "), None)
    if line == "make run":
        cmd.wait_line(READY[line], timeout=600)  # (it installs first when the sources changed)
        keep.append(cmd)
        return
    if ready is not None:
        cmd.wait_line(ready, timeout=300)
        cmd.interrupt(group=True)
        code, _ = cmd.exit_code(60.0)
        out = "\n".join(cmd.rest())
        assert "ERROR collecting" not in out, out
        if line != "make test":  # (pytest interrupted prints its KeyboardInterrupt; make says so)
            assert code in (0, 130) and "Traceback" not in out, (line, code, out)
        return
    answers = next((texts for part, texts in ONCE.items() if part in f" {line} "), None)
    assert answers is not None, f"README/banner command {line!r}: this test does not know how to check it"
    code, _ = cmd.exit_code(120.0)
    out = "\n".join(cmd.rest())
    assert any(text in out for text in answers) and "Traceback" not in out, (line, code, out)


def test_the_readme_first_screen_runs_as_printed(netns):
    if os.environ.get(GUARD):
        pytest.skip("inside the make test this test started")
    recording = ROOT / "session.mcap"
    require(not recording.exists(), f"{recording} exists: the banner's record command would replace it")
    env = {k: v for k, v in os.environ.items() if k not in ("LIMBSTREAM_ROUTER", "VIRTUAL_ENV")}
    env[GUARD] = "1"
    venv_bin = str(ROOT / ".venv" / "bin")  # a new user's shell: the venv not activated
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep) if p.rstrip("/") != venv_bin)
    keep: list[Command] = []
    try:
        commands = quick_start()
        assert commands[0] == "make run", commands
        for line in commands:
            run_as_printed(line, netns, env, keep)
        printed = banner_commands(keep[0].rest())
        assert printed[0] == ".venv/bin/limbstream watch s01", printed  # PATH has no .venv/bin here
        for line in printed:
            run_as_printed(line, netns, env, keep)
        keep[0].interrupt(group=True)
        keep[0].exit_code(60.0)
        out = keep[0].rest()
        assert "limbstream up: stopped" in out and "Traceback" not in "\n".join(out), out[-40:]
    finally:
        for cmd in keep:
            if cmd.proc.poll() is None:
                cmd.kill()
        recording.unlink(missing_ok=True)
