"""Shared fixtures: the shared motion data (skipped where absent, required in CI)."""
from __future__ import annotations

import pytest

from support import profiles, require_data  # noqa: F401  (profiles: registers the Hypothesis profiles)

pytest_plugins = ("support.stack", "support.dashboard")  # fixtures: `stack` and `watch` (real processes), `router`


def _data(relative: str):
    """A session fixture: the path of ``relative`` in the shared data (skip, or fail in CI)."""
    return pytest.fixture(scope="session")(lambda: require_data(relative))


cmu_npz = _data("cmu_10seg_50hz.npz")
xio_dir = _data("xio_lower_body")
cmu_bvh_dir = _data("cmu")
xsens_dir = _data("xsens_opensense")


LANES = {"stack": "e2e", "watch": "e2e", "netns": "root"}
"""Test lanes by the fixtures a test uses: real processes and a router (``stack``) are ``e2e``;
network namespaces are ``root``. Other lanes (qemu, browser, slow) are marked where the test is."""


def pytest_collection_modifyitems(items):
    for item in items:
        for fixture, lane in LANES.items():
            if fixture in getattr(item, "fixturenames", ()):
                item.add_marker(lane)
