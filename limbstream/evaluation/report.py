"""Results of a sweep as a table, a Pareto frontier and JSON."""
from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from limbstream.evaluation.sweep import ICR_TARGETS, KEYS, at_icr


def format_table(
    rows: Sequence[dict], algorithms: Sequence[str], targets: Sequence[float] = ICR_TARGETS,
    live_bound_deg: Sequence[float] = (0.0,),
) -> str:
    """The comparison table (measures at the target ICRs, per algorithm and live bound) as
    aligned text."""
    head = (f"{'algorithm':<9} {'bound':>5} {'ICR':>5} {'AAD':>7} {'p99':>7} {'max':>7} {'pt_AAD':>8} "
            f"{'pt_max':>8} {'live':>7} {'live99':>7}  {'~TH':>9}")
    lines = [head, "-" * len(head)]
    for a in algorithms:
        for bound in live_bound_deg:
            for r in at_icr(rows, a, targets, live_bound_deg=bound):
                lines.append(
                    f"{a:<9} {bound:>5g} {r['icr']:>5.2f} {r['aad']:>7.2f} {r['p99']:>7.2f} {r['max']:>7.2f} "
                    f"{r['point_aad']:>8.3f} {r['point_max']:>8.3f} {r['live_aad']:>7.2f} {r['live_p99']:>7.2f}  "
                    f"{r['threshold']:>9.2e}"
                )
    lines.append(
        "(angles in degrees; pt_ = segment points vs. the samples at their timestamps; live = live"
        " error, mean and p99; bound = live rule bound, 0 off; ~TH = interpolated threshold)"
    )
    return "\n".join(lines)


def frontier(rows: Sequence[dict], bound: float | None, tolerance: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """The best exact AAD at each ICR among rows whose live error stays within ``bound`` degrees
    at every sample (``live_max <= bound + tolerance``; None: every row): the rows not beaten by
    another with lower or equal ICR and lower AAD.

    Returns
    -------
    icr, aad : (F,) float64, ICR increasing, AAD decreasing.
    """
    ok = [r for r in rows if np.isfinite(r["icr"]) and np.isfinite(r["aad"])
          and (bound is None or r["live_max"] <= bound + tolerance)]
    ok.sort(key=lambda r: (r["icr"], r["aad"]))
    icr: list[float] = []
    aad: list[float] = []
    for r in ok:
        if not aad or r["aad"] < aad[-1]:
            icr.append(r["icr"])
            aad.append(r["aad"])
    return np.array(icr), np.array(aad)


def write_json(rows: Sequence[dict], path: str | Path) -> None:
    """All rows as a JSON list of objects with the :data:`KEYS`; NaN becomes null."""
    clean = [
        {k: (None if isinstance(r[k], float) and not math.isfinite(r[k]) else r[k]) for k in KEYS}
        for r in rows
    ]
    Path(path).write_text(json.dumps(clean, indent=1) + "\n")
