"""Joint angles through a router (e2e): an aggregator publishes them for every subject, with the
calibration they rest on; ``limbstream watch --joints`` prints them for a subject whose devices
send their segments' own orientations, and says why there are none for one whose sensors are
strapped on and not calibrated."""
from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest
from support.stack import PAPER10, ROOT, stack, wait_for_subscribers, wait_until  # noqa: F401  (stack is a fixture)

from limbstream import wire, zconfig
from limbstream.services.outputs.subscription import Subscription

pytestmark = pytest.mark.e2e


def watch(endpoint: str, subject: str) -> str:
    """``limbstream watch <subject> --joints`` until 10 frames came (it shows the newest, 10 times a second)."""
    out = subprocess.run([sys.executable, "-m", "limbstream.cli", "watch", subject, "--joints", "--connect", endpoint,
                          "--count", "10", "--timeout", "30", "--refresh", "10"], cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_watch_prints_the_joint_angles_or_why_there_are_none(stack):  # noqa: F811
    stack.router()
    stack.aggregator()
    wait_for_subscribers(stack.endpoint, [wire.seg_key("s01", "hip")], "the aggregator", on_fail=stack.logs)
    stack.emulator(1)
    stack.start("emulate-s02", "emulate", "--connect", stack.endpoint, "--subjects", "1", "--first-subject", "2",
                *PAPER10, "--mounting-deg", "90", "--heading-deg", "180")
    newest: dict[str, wire.JointAngles] = {}
    with Subscription(zconfig.ZenohSettings(connect=(stack.endpoint,)), "*", (wire.ANGLES,)) as sub:
        def told() -> bool:  # each subject's calibration is known once its devices' statuses are in
            newest.update((item.subject, item.value) for item in sub.drain())
            return {s: a.calibration.name for s, a in newest.items()} == {"s01": "segments", "s02": "uncalibrated"}
        wait_until(told, 30, "both subjects' calibrations known", on_fail=stack.logs)
    s01 = newest["s01"]
    assert s01.kind == wire.KIND_LIVE and np.isfinite(s01.angles).all() and not (s01.flags & ~np.uint8(2)).any()
    assert np.isnan(newest["s02"].angles).all()

    text = watch(stack.endpoint, "s01")
    blocks = text.split("s01  live #")[1:]
    assert blocks and all("  joint angles" in b for b in blocks), text
    assert "joint angles (deg; calibration segments" in blocks[-1], text  # (with --joints, --count waits for angles)
    for name in ("hip_flexion_r", "knee_angle_r", "elbow_flex_l", "neck_rotation"):
        assert re.search(rf"{name} +-?\d+\.\d°", blocks[-1]), (name, blocks[-1])
    last = watch(stack.endpoint, "s02").split("s02  live #")[-1]
    assert "joint angles: none, calibration uncalibrated: a device reports its sensor's orientation" in last, last
