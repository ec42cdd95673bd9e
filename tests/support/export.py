"""The export tests' pieces: the recorded time base and ``limbstream export`` as a subprocess."""
from __future__ import annotations

import subprocess
import sys

from support import ROOT

T0_US = 1_700_000_000_000_000
"""Device time of the first recorded frame, us since the epoch."""


def cli(*args: str) -> subprocess.CompletedProcess:
    """``limbstream export ARGS`` from the repository's root: its exit status and output."""
    return subprocess.run([sys.executable, "-m", "limbstream.cli", "export", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
