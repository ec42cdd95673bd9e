"""The Makefile's installs, read from ``make -n`` (what make would run, nothing run): `make run`
installs what running needs, the test targets add the test extras, and each reinstalls only when
the sources changed since its install (or the other install did not cover it)."""
from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RUN_INSTALL = "python -m pip install -e .\n"
TEST_INSTALL = "python -m pip install -e '.[test]'"

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="needs make")


@pytest.fixture
def checkout(tmp_path: Path) -> Path:
    """The Makefile and the files its installs depend on (one C source among them), a second old."""
    for name in ("Makefile", "pyproject.toml", "setup.py"):
        shutil.copy2(ROOT / name, tmp_path / name)
    (tmp_path / "firmware_c" / "src").mkdir(parents=True)
    (tmp_path / "firmware_c" / "src" / "kernel.c").write_text("int x;\n")
    old = time.time() - 100
    for path in (tmp_path / "Makefile", tmp_path / "pyproject.toml", tmp_path / "setup.py",
                 tmp_path / "firmware_c" / "src" / "kernel.c"):
        os.utime(path, (old, old))
    return tmp_path


def planned(checkout: Path, target: str) -> str:
    """The commands ``make <target>`` would run (in a virtual environment: no .venv to make)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MAKE")} | {"VIRTUAL_ENV": str(checkout)}
    res = subprocess.run(["make", "-n", target, "PYTHON=python"], cwd=checkout, env=env, check=True,
                         capture_output=True, text=True, timeout=60)
    return res.stdout


def installed(checkout: Path, target: str) -> None:
    """What ``target``'s install leaves: its stamps, as its recipe touches them (read from make -n)."""
    for line in planned(checkout, target).splitlines():
        if line.startswith(("mkdir -p build && touch", "touch")):
            (checkout / "build").mkdir(exist_ok=True)
            for stamp in line.split("touch", 1)[1].split():
                (checkout / stamp).touch()


def test_run_installs_what_running_needs_and_the_tests_add_their_extras(checkout):
    run = planned(checkout, "run")
    assert RUN_INSTALL in run and TEST_INSTALL not in run, run
    for target in ("test", "test-fast", "lint", "install"):
        plan = planned(checkout, target)
        assert TEST_INSTALL in plan, (target, plan)


def test_run_after_test_installs_nothing_and_test_after_run_adds_the_extras(checkout):
    installed(checkout, "test")
    for target in ("run", "test", "lint", "test-fast"):
        assert "pip install" not in planned(checkout, target), target
    for stamp in (checkout / "build").iterdir():
        stamp.unlink()
    installed(checkout, "run")
    assert "pip install" not in planned(checkout, "run")
    assert TEST_INSTALL in planned(checkout, "test")


@pytest.mark.parametrize("changed", ["setup.py", "pyproject.toml", "firmware_c/src/kernel.c"])
def test_a_changed_source_reinstalls_each_install_once(checkout, changed):
    installed(checkout, "test")
    later = time.time() + 5
    os.utime(checkout / changed, (later, later))
    assert RUN_INSTALL in planned(checkout, "run")
    assert TEST_INSTALL in planned(checkout, "test")
    newer = later + 5
    for stamp in (checkout / "build").iterdir():
        os.utime(stamp, (newer, newer))
    assert "pip install" not in planned(checkout, "run") + planned(checkout, "test")
