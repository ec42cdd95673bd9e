"""Exact Cortex-M4 instruction counts per call under QEMU (firmware_c/tools/icount.py).

The ceiling below is the maximum the kernel reached (docs/kernel.md, "Cortex-M4 and
instruction counts"); a change that makes fastsw_update's slowest branch longer fails.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from support.firmware import FIRMWARE, load_tool, make_m4, require_tools

pytestmark = pytest.mark.qemu

TOOLS = ("arm-none-eabi-gcc", "arm-none-eabi-nm", "arm-none-eabi-objdump", "qemu-system-arm", "make")

FASTSW_MAX_INSTRUCTIONS = 130
"""Reached maximum of fastsw_update per sample, live rule off (paper, Table 2: 210)."""

FASTSW_LIVE_MAX_INSTRUCTIONS = 176
"""Reached maximum with the live rule on, a live close (the bound: the paper's 210)."""
DEVICE_MAX_INSTRUCTIONS = 7704
"""Reached maximum of the device firmware per SAMPLE frame, live mode (link decode, fastSW,
the point's encoding with its float64 body rate, framing)."""
VQF_MAX_INSTRUCTIONS = 2838
"""Reached maximum of VQF 6D per raw sample (updateGyr + updateAcc) in the firmware's default
precision (fastsw_config.h), single: float filter states, the accelerometer low-pass filter's in
float-float (the aim: 3,000)."""
IMU_MAX_INSTRUCTIONS = 12416
"""Reached maximum of the raw-sample pipeline per device sample (200 Hz raw, 50 Hz device: the four
VQF updates since the last device sample, the checks, fastSW live)."""
LIVE_BRANCHES = ("live_first", "live_normal", "live_close", "live_ssr_break", "live_max_len_break",
                 "live_reject_nan", "live_reject_time")


@pytest.fixture(scope="module")
def build_dir(tmp_path_factory) -> Path:
    require_tools(*TOOLS)
    return make_m4(tmp_path_factory, "icount")


@pytest.fixture(scope="module")
def counts(build_dir) -> dict:
    return load_tool("icount").measure(build_dir / "icount.elf")


def test_counting_is_exact(counts):
    """A naked function of known length (3 + 3k instructions) is counted exactly."""
    assert len(counts["probe"]) == 3
    for k, measured, expected in counts["probe"]:
        assert measured == expected, f"icount_probe({k}): counted {measured}, it has {expected}"


def test_fastsw_max_within_ceiling(counts):
    fastsw = counts["fastsw"]
    for branch in ("first", "normal", "ssr_break", "max_len_break", "reject_nan", "reject_time"):
        assert fastsw.get(branch), f"branch {branch} never taken"
    assert counts["fastsw_max"] <= FASTSW_MAX_INSTRUCTIONS, (
        f"fastsw_update takes up to {counts['fastsw_max']} instructions ({counts['fastsw_max_branch']}), "
        f"ceiling {FASTSW_MAX_INSTRUCTIONS}"
    )
    # constant time: every call of one branch costs the same, whatever the segment length
    for branch in ("normal", "ssr_break", "max_len_break"):
        assert len(set(fastsw[branch])) == 1, f"{branch}: counts vary {sorted(set(fastsw[branch]))}"


def test_fastsw_live_max_within_ceiling(counts):
    fastsw = counts["fastsw"]
    for branch in LIVE_BRANCHES:
        assert fastsw.get(branch), f"branch {branch} never taken"
    assert counts["live_max"] <= FASTSW_LIVE_MAX_INSTRUCTIONS <= 210, (
        f"fastsw_update with the live rule takes up to {counts['live_max']} instructions "
        f"({counts['live_max_branch']}), ceiling {FASTSW_LIVE_MAX_INSTRUCTIONS}"
    )
    for branch in ("live_normal", "live_close", "live_ssr_break", "live_max_len_break"):
        assert len(set(fastsw[branch])) == 1, f"{branch}: counts vary {sorted(set(fastsw[branch]))}"
    # the live rule is not free, and the plain rules do not pay for it
    assert counts["live_max"] > counts["fastsw_max"]


def test_sw_cost_is_linear_in_segment_length(counts):
    a, b = counts["sw_a"], counts["sw_b"]
    assert counts["sw_n"][0] == 0 and counts["sw_n"][-1] == 200, counts["sw_n"][:3]
    assert 15 <= b <= 60, f"SW slope {b:.2f} instructions per buffered sample (paper: 35)"
    assert 20 <= a <= 300, f"SW intercept {a:.1f} (paper: 161)"
    assert counts["sw_residual_max"] <= 2.0, f"SW count not linear: residual {counts['sw_residual_max']}"
    # at n = 200 SW costs far more than fastSW's worst case
    assert counts["sw_count"][-1] > 20 * counts["fastsw_max"]


@pytest.mark.slow
def test_make_icount_prints_table(build_dir):
    """All three harnesses (the raw-sample pipeline's traces about 25 million instructions)."""
    done = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "icount", f"BUILD={build_dir}", f"PYTHON={sys.executable}"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = re.findall(r"^fastsw max instructions per sample: (\d+)$", done.stdout, re.MULTILINE)
    assert len(lines) == 1, done.stdout
    assert int(lines[0]) <= FASTSW_MAX_INSTRUCTIONS, done.stdout
    live = re.findall(r"^fastsw live max instructions per sample: (\d+)$", done.stdout, re.MULTILINE)
    assert len(live) == 1 and int(live[0]) <= FASTSW_LIVE_MAX_INSTRUCTIONS, done.stdout
    assert "ssr_break" in done.stdout and "least-squares fit" in done.stdout, done.stdout
    device = re.findall(r"^device max instructions per sample: (\d+)$", done.stdout, re.MULTILINE)
    assert len(device) == 1 and int(device[0]) <= DEVICE_MAX_INSTRUCTIONS, done.stdout
    vqf = re.findall(r"^vqf 6d max instructions per raw sample: (\d+)$", done.stdout, re.MULTILINE)
    assert len(vqf) == 1 and int(vqf[0]) <= VQF_MAX_INSTRUCTIONS, done.stdout
    imu = re.findall(r"^imu max instructions per device sample: (\d+)$", done.stdout, re.MULTILINE)
    assert len(imu) == 1 and int(imu[0]) <= IMU_MAX_INSTRUCTIONS, done.stdout
    assert "rest detected in the still phase: yes" in done.stdout, done.stdout


def test_device_firmware_cost_per_sample(build_dir):
    """The whole work of the device firmware for one sample, traced: a sample that makes a
    point costs more (its encoding, body rate and framing) than one that does not."""
    device = load_tool("icount").measure_device(build_dir / "icount_device.elf")
    assert device["point"] and device["none"], device
    assert min(device["point"]) > max(device["none"]) > 0
    assert device["max"] <= DEVICE_MAX_INSTRUCTIONS, (
        f"the device firmware takes up to {device['max']} instructions per sample, ceiling {DEVICE_MAX_INSTRUCTIONS}")
