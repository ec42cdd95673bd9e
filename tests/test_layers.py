"""The import layers hold: the core library (limbstream, less limbstream.cli, the launcher and
the parts) imports nothing above it; the parts (device_emulator, services: limbstream.device_emulator
and limbstream.services once installed) import the core only; only limbstream.cli and the process
launcher (limbstream/launch.py) start them (by module name). Read from the source, so a string import cannot hide a cycle."""
from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
UPPER = {"core": ("limbstream.cli", "limbstream.services", "limbstream.device_emulator"), "parts": ("limbstream.cli",)}
SOURCES = ("limbstream", "services", "device_emulator")
"""The folders of the layers (only these are read: globbing the whole checkout walks .venv too)."""


def imported(path: Path) -> set[str]:
    """Modules a file imports, by import statements and by names in strings that look like a
    module path (``importlib.import_module("limbstream.services.x")``)."""
    tree = ast.parse(path.read_text(), str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and re.fullmatch(r"[a-z_]+(\.[a-z_]+)+", node.value):
            names.add(node.value)
    return names


def layer(path: Path) -> str | None:
    rel = path.relative_to(ROOT).as_posix()
    if rel.startswith("limbstream/cli/") or rel == "limbstream/launch.py":
        return None
    if rel.startswith("limbstream/"):
        return "core"
    if rel.startswith(("services/", "device_emulator/")):
        return "parts"
    return None


def test_no_module_imports_a_layer_above_it():
    wrong = []
    for path in sorted(p for folder in SOURCES for p in (ROOT / folder).glob("**/*.py")):
        kind = layer(path)
        if kind is None:
            continue
        for name in imported(path):
            if any(name == up or name.startswith(up + ".") for up in UPPER[kind]):
                wrong.append(f"{path.relative_to(ROOT)} ({kind}) imports {name}")
    assert not wrong, "\n".join(wrong)


LAUNCHED = ("emulate", "aggregate", "router", "clock", "dashboard", "record", "replay", "watch", "up")
"""Commands that ``limbstream up`` or a test starts as processes."""
MOTIONLESS = ("aggregate", "router", "clock", "dashboard", "record", "replay", "watch")
"""Those of them that read no motion file (no rotation conversions, no filters)."""


def loaded(commands: tuple[str, ...], prefixes: tuple[str, ...]) -> list[str]:
    """The modules starting with ``prefixes`` that importing ``commands``' modules loads (in a
    fresh interpreter)."""
    modules = ", ".join(f"limbstream.cli.{c}" for c in commands)
    code = f"import json, sys, {modules}; print(json.dumps(sorted(m for m in sys.modules if m.startswith({prefixes!r}))))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120, check=True)
    return json.loads(out.stdout)


def test_launched_commands_import_scipy_only_where_they_use_it():
    """scipy.signal (which brings scipy.stats and scipy.interpolate) costs about a second of CPU
    per process to import and scipy.spatial about 0.4 s: only the raw-sensor model and the motion
    readers need them, so they are imported where they are used, not at every process's start."""
    assert loaded(LAUNCHED, ("scipy.signal", "scipy.stats")) == []
    assert loaded(MOTIONLESS, ("scipy",)) == []
