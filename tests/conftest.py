"""Shared fixtures: the shared motion data (skipped where absent, required in CI)."""
from __future__ import annotations

from pathlib import Path

import pytest

from support import profiles, require_data  # noqa: F401  (profiles: registers the Hypothesis profiles)

pytest_plugins = ("support.stack", "support.dashboard")  # fixtures: `stack` and `watch` (real processes), `router`


@pytest.fixture(scope="session")
def cmu_npz() -> Path:
    return require_data("cmu_10seg_50hz.npz")


@pytest.fixture(scope="session")
def xio_dir() -> Path:
    return require_data("xio_lower_body")


@pytest.fixture(scope="session")
def cmu_bvh_dir() -> Path:
    return require_data("cmu")


@pytest.fixture(scope="session")
def xsens_dir() -> Path:
    return require_data("xsens_opensense")


LANES = {"stack": "e2e", "watch": "e2e", "netns": "root"}
"""Test lanes by the fixtures a test uses: real processes and a router (``stack``) are ``e2e``;
network namespaces are ``root``. Other lanes (qemu, browser, slow) are marked where the test is."""


def pytest_collection_modifyitems(items):
    for item in items:
        for fixture, lane in LANES.items():
            if fixture in getattr(item, "fixturenames", ()):
                item.add_marker(lane)
