"""The scripts in examples/ run against a live system and print what they say they print."""
from __future__ import annotations

import re
import subprocess
import sys

from support.stack import ROOT, stack, wait_until  # noqa: F401  (fixture)

from limbstream import wire


def example(name: str, *args: str) -> list[str]:
    result = subprocess.run([sys.executable, str(ROOT / "examples" / name), *args], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    return result.stdout.splitlines()


def test_examples_run_against_a_live_system(stack):  # noqa: F811
    stack.router()
    stack.aggregator()
    stack.emulator(1, 1.0, *(f"--{k.replace('_', '-')}={v}" for k, v in wire.LIVE_MODE.items()))
    url = stack.dashboard()

    lines = example("live_frames.py", "s01", stack.endpoint)
    assert len(lines) == 5 and all(re.match(r"s01 t=[\d.]+ s  l_wrist x=[-+][\d.]+ y=[-+][\d.]+ z=[-+][\d.]+ m$", x)
                                   for x in lines), lines

    lines = example("device_settings.py", "s01", stack.endpoint)
    assert sorted(x.split(":")[0] for x in lines) == sorted(f"s01/{s}" for s in wire.SEGMENTS), lines
    assert all("threshold 0.0009, max_len 25, live bound 5 deg" in x and "rest pose standing" in x for x in lines), lines

    def metrics_in() -> list[str]:
        out = example("rest_metrics.py", url)
        return out if len(out) == 10 and all(re.search(r"B/s, ICR 0\.\d{3}, angular error [\d.]+ deg", x)
                                             for x in out) else []
    lines = wait_until(metrics_in, 60, "every device's data rate, ICR and error in the REST answer", interval=1.0)
    print("\n" + "\n".join(lines))
