"""The rest calibration ``limbstream up`` suggests works on its default motion: the built-in
motion stands still in the rest pose for a few seconds about every 30 s, and ``limbstream
calibrate`` asks again while the subject is not still, telling the user, until it is."""
from __future__ import annotations

import re
import subprocess
import sys

import pytest
from support.stack import ROOT, StatsWatch, stack, wait_until  # noqa: F401  (stack is a fixture)
from test_up import Up

pytestmark = pytest.mark.e2e

MAKE_RUN = ("--imu", "raw", "--imu-model", "icm42688p", "--mounting-deg", "90", "--heading-deg", "180")
"""The sensors ``make run`` gives ``up`` (the Makefile's RUN_FLAGS)."""


def test_the_suggested_rest_calibration_succeeds_on_the_default_motion(stack, tmp_path):  # noqa: F811
    up = Up(stack, tmp_path, "--subjects", "1", "--no-dashboard", *MAKE_RUN)
    lines = wait_until(lambda: [line for line in up.output() if "limbstream calibrate s01 --pose rest" in line]
                       and up.output(), 60, "up's banner", on_fail=up.logs)
    command = re.search(r"limbstream calibrate s01 --pose rest.*", next(
        line for line in lines if "limbstream calibrate s01" in line)).group(0).strip()
    assert any("stands still in the rest pose" in line for line in lines), lines
    watch = StatsWatch(stack.endpoint)
    try:
        wait_until(lambda: len(watch.poll()) == 10 and all(d["online"] and d["points"] for d in watch.devices.values()),
                   60, "s01's devices streaming", on_fail=up.logs)
    finally:
        watch.close()
    out = subprocess.run([sys.executable, "-m", "limbstream.cli", *command.split()[1:]], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "s01: 10 devices calibrated (rest)" in out.stdout, out.stdout
