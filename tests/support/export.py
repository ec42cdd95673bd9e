"""The export tests' pieces: the recorded time base, ``limbstream export`` as a subprocess and
OpenSim's own readers of the .mot and .sto files."""
from __future__ import annotations

import subprocess
import sys

import numpy as np

from support import ROOT

T0_US = 1_700_000_000_000_000
"""Device time of the first recorded frame, us since the epoch."""


def cli(*args: str) -> subprocess.CompletedProcess:
    """``limbstream export ARGS`` from the repository's root: its exit status and output."""
    return subprocess.run([sys.executable, "-m", "limbstream.cli", "export", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)


def storage_columns(path):
    """OpenSim's Storage of a motion file and its columns by label (time included):
    (opensim.Storage, dict of (F,) arrays)."""
    import opensim

    storage = opensim.Storage(str(path))
    labels = storage.getColumnLabels()
    columns = {}
    for i in range(labels.getSize()):
        values = opensim.ArrayDouble()
        if labels.get(i) == "time":
            storage.getTimeColumn(values)
        else:
            storage.getDataColumn(labels.get(i), values)
        columns[labels.get(i)] = np.array([values.get(k) for k in range(values.getSize())])
    return storage, columns


def quaternion_table(path):
    """OpenSense's orientation table of a file and its (F, C, 4) quaternions."""
    import opensim

    table = opensim.TimeSeriesTableQuaternion(str(path))
    q = np.array([[[float(v) for v in str(table.getRowAtIndex(k).getElt(0, j)).strip("~[]").split(",")]
                   for j in range(table.getNumColumns())] for k in range(table.getNumRows())])
    return table, q
