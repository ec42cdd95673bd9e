"""Shared by the Cortex-M4 tests: the toolchain check and the firmware's Python tools."""
from __future__ import annotations

import importlib.util
import shutil
import sys
from types import ModuleType

from support import ROOT, require

FIRMWARE = ROOT / "firmware_c"


def require_tools(*tools: str) -> None:
    """Skip without the cross toolchain and QEMU; fail in CI."""
    missing = [tool for tool in tools if shutil.which(tool) is None]
    require(not missing, f"Cortex-M4 tools not installed: {missing} (apt install gcc-arm-none-eabi qemu-system-arm)")


def load_tool(name: str) -> ModuleType:
    """firmware_c/tools/<name>.py as a module (the tools are scripts, not a package)."""
    spec = importlib.util.spec_from_file_location(f"m4_{name}", FIRMWARE / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module
