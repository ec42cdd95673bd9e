"""Shared by the Cortex-M4 tests: the toolchain check and the firmware's Python tools."""
from __future__ import annotations

import dataclasses
import importlib.util
import queue
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

from support import ROOT, require

from limbstream import kernel, wire

FIRMWARE = ROOT / "firmware_c"


def require_tools(*tools: str) -> None:
    """Skip without the cross toolchain and QEMU; fail in CI."""
    missing = [tool for tool in tools if shutil.which(tool) is None]
    require(not missing, f"Cortex-M4 tools not installed: {missing} (apt install gcc-arm-none-eabi qemu-system-arm)")


def make_m4(tmp_path_factory, name: str) -> Path:
    """A fresh ``make m4`` (the Cortex-M4 images) into a temporary build folder ``name``."""
    build = tmp_path_factory.mktemp(name)
    done = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "m4", f"BUILD={build}", f"PYTHON={sys.executable}"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"make m4 failed:\n{done.stdout}\n{done.stderr}"
    return build


def load_tool(name: str) -> ModuleType:
    """firmware_c/tools/<name>.py as a module (the tools are scripts, not a package)."""
    spec = importlib.util.spec_from_file_location(f"m4_{name}", FIRMWARE / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def final_point(bank: kernel.SegmenterBank, slot: int, stream: int, last: bytes) -> bytes:
    """The message a stream's END makes, as the emulator ends a stream: its last sample flushed
    as a held FINAL point, or, when that already was a point, its last message ``last`` repeated
    as FINAL with the next sequence number (the bank's wire ring gives sample and stamp)."""
    flushed = bank.flush(slot)
    if flushed is None:
        point = dataclasses.replace(wire.decode_point(last), seq=int(bank.seq[slot]), flags=wire.FLAG_FINAL)
    else:
        row = flushed[0] % bank.sample.shape[0]
        point = wire.SegmentPoint(stream, int(bank.seq[slot]), int(bank.sample[row, slot] - bank.base[slot]),
                                  int(bank.t_us[row, slot]), tuple(float(v) for v in flushed[2]), wire.FLAG_FINAL,
                                  (0.0, 0.0, 0.0) if bank.live(slot) else None)
    return wire.encode_point(point)


def drain(port) -> list[bytes]:
    """The points a device on the serial link (a SerialLink) has sent so far (heartbeats skipped)."""
    points = []
    while True:
        try:
            kind, message = port.inbox.get_nowait()
        except queue.Empty:
            return points
        if kind == "point":
            points.append(message)
