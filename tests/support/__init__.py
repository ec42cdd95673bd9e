"""Helpers of the tests (a package: ``from support.stack import ...``; pytest puts ``tests/`` on
the path as the root of its test modules): the repository's root, the shared motion data, the
CI switch; the live system as subprocesses (:mod:`.stack`), the Cortex-M4 tools
(:mod:`.firmware`), the brute-force Sliding Window oracle (:mod:`.sw_oracle`) and Hypothesis
profiles (:mod:`.profiles`)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent.parent
DATA = Path(os.environ.get("LIMBSTREAM_DATA", ROOT.parent / "shared" / "data"))
IN_CI = os.environ.get("CI", "").lower() == "true"


def require_data(relative: str) -> Path:
    """Path of a file under the shared data folder; skip if absent, fail if absent in CI."""
    path = DATA / relative
    if not path.exists():
        message = f"shared motion data not found: {path} (set LIMBSTREAM_DATA)"
        if IN_CI:
            pytest.fail(message)
        pytest.skip(message)
    return path


def require(ok: bool, message: str) -> None:
    """Skip the test when a tool or capability it needs is missing; fail in CI, where it must be."""
    if not ok:
        (pytest.fail if IN_CI else pytest.skip)(message)
