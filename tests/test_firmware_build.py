"""The firmware's build runs tools in the Python it is given (``PYTHON``: the one that runs
limbstream), not whatever ``python3`` is first on PATH or a ``.venv`` beside the sources; a Python
that cannot import NumPy stops it with one clear sentence. VQF's C++ is in firmware_c/vqf: no
installed package provides source."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from support import ROOT
from support.firmware import FIRMWARE, require_tools

pytestmark = pytest.mark.qemu


@pytest.fixture
def checkout(tmp_path):
    """firmware_c and the wire contract it reads, in a folder with no .venv, and a PATH whose
    python3 has no site-packages (a system Python, or a venv not activated)."""
    require_tools("arm-none-eabi-gcc", "arm-none-eabi-g++", "make")
    shutil.copytree(FIRMWARE, tmp_path / "firmware_c", ignore=shutil.ignore_patterns("build*"))
    (tmp_path / "limbstream" / "wire").mkdir(parents=True)
    shutil.copy(ROOT / "limbstream" / "wire" / "config.py", tmp_path / "limbstream" / "wire" / "config.py")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "python3"
    fake.write_text(f"#!/bin/sh\nexec {sys.executable} -I -S \"$@\"\n")  # no site-packages
    fake.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    return tmp_path / "firmware_c", env


def make_device(folder, env, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-s", "-C", str(folder), "device", *extra], capture_output=True, text=True,
                          env=env, timeout=300)


def test_the_build_uses_the_python_it_is_given(checkout):
    folder, env = checkout
    done = make_device(folder, env, f"PYTHON={sys.executable}")
    assert done.returncode == 0, done.stderr
    assert (folder / "build" / "device.elf").exists()


def test_a_python_without_numpy_is_named(checkout):
    folder, env = checkout
    done = make_device(folder, env)
    assert done.returncode != 0
    assert "python3 cannot import numpy (tools/vectors.py): give PYTHON=the Python that runs limbstream" in done.stderr
    assert "Traceback" not in done.stderr
