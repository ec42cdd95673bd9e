"""The README's figure: a CMU walk's root path as the contact rule tracks it from the estimated feet,
beside the file's own, seen from above (docs/body.md and docs/evaluation.md, "Root translation").

    python bench/root_path_plot.py                    # 131_01, make run's raw sensors -> docs/img/root_path_131_01.png
    python bench/root_path_plot.py 02_01 --out /tmp/walk.png --no-contacts
    python bench/root_path_plot.py 131_01 --perfect   # perfect sensors (eval's default)

It runs ``limbstream eval`` on the clips (``../shared/data/cmu``, together as docs/benchmarks.md
does: the sensors are drawn per motion in turn) with the sensors of
:data:`RAW` (raw ICM-42688-P readings fused on the device, calibrated, headings held by the joints;
fastSW at 9e-4, ``max_len`` 25, ``--layout full``: the figures of docs/benchmarks.md), takes the
dump's ``root``, ``true_root``, ``feet`` and ``contacts``, aligns the estimate's start as eval does
(:func:`limbstream.evaluation.translation.aligned`) and draws x and z (m): the true path, the
estimated one, and (unless ``--no-contacts``) where each estimated foot point was put down. The
title carries eval's end error for the clip. It prints that row.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from limbstream.evaluation.translation import aligned

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data" / "cmu"
RAW = ("--imu", "raw", "--imu-model", "icm42688p", "--mounting-deg", "90", "--heading-deg", "180",
       "--calibration", "rest,mounting", "--heading-correction", "joints")
"""make run's sensors in eval's terms (docs/benchmarks.md, "Root translation")."""
ROW = ("--algorithms", "fastsw", "--thresholds", "9e-4", "--max-len", "25", "--layout", "full")


def evaluate(data: Path, clip: str, perfect: bool, folder: Path) -> tuple[dict, dict]:
    """Run ``limbstream eval`` on the folder ``data`` dumping into ``folder``: (clip ``clip``'s
    translation row, its dump). The whole folder, as docs/benchmarks.md runs it: each motion's
    sensors are drawn in turn, so a clip evaluated alone has other sensors (other figures)."""
    rows = folder / "rows.json"
    command = [sys.executable, "-m", "limbstream.cli", "eval", str(data), *(() if perfect else RAW), *ROW,
               "--dump", str(folder), "--json", str(rows)]
    print("running:", " ".join(["limbstream", *command[3:]]), file=sys.stderr)
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    [row] = json.loads(rows.read_text())
    [figures] = [m for m in row["translation"] if m["motion"] == clip]
    with np.load(folder / f"{clip}.npz") as dump:
        return figures, {k: dump[k] for k in ("t", "root", "true_root", "feet", "foot_points", "contacts",
                                              "root_heading_rad")}


def touch_downs(contacts: np.ndarray, names: np.ndarray) -> np.ndarray:
    """(F, C) bool: frames where foot point c starts touching (its ``wire.CONTACTS`` bit newly set)."""
    from limbstream.wire import CONTACTS

    bits = np.stack([(contacts >> CONTACTS.index(str(n))) & 1 for n in names], axis=1).astype(bool)
    return bits & ~np.vstack([np.zeros((1, len(names)), bool), bits[:-1]])


def draw(clip: str, figures: dict, dump: dict, sensors: str, out: Path, contacts: bool) -> None:
    """The top view (x, z in metres) into ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = np.isfinite(dump["root"]).all(axis=1)
    t, true_root = dump["t"][ok], dump["true_root"][ok]
    root, feet = aligned(t, dump["root"][ok], dump["feet"][ok], true_root, float(dump["root_heading_rad"]))
    fig, ax = plt.subplots(figsize=(6.4, 4.0), constrained_layout=True)
    ax.plot(true_root[:, 0], true_root[:, 2], color="k", lw=1.6, label="true root (the file's)")
    ax.plot(root[:, 0], root[:, 2], color="C3", lw=1.4, label="estimated root (from the feet)")
    if contacts:
        down = touch_downs(dump["contacts"][ok], dump["foot_points"])
        for side, color in (("l", "C0"), ("r", "C2")):
            mine = np.array([str(n).startswith(side) for n in dump["foot_points"]])
            at = feet[:, mine][down[:, mine]]
            ax.plot(at[:, 0], at[:, 2], ".", ms=4, color=color, alpha=0.7,
                    label=f"{'left' if side == 'l' else 'right'} foot put down (estimate)")
    ax.plot(*true_root[0, [0, 2]], "ko", ms=5)
    ax.annotate("start", true_root[0, [0, 2]], textcoords="offset points", xytext=(6, 6), fontsize=8)
    ax.set(aspect="equal", xlabel="x (m)", ylabel="z (m)",
           title=f"CMU {clip}, {sensors}: end error {figures['end_cm']:.1f} cm "
                 f"({figures['end_pct']:.1f} % of {figures['path_m']:.1f} m)")
    ax.title.set_fontsize(9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.savefig(out, dpi=90)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip", nargs="?", default="131_01", help="CMU clip name (default 131_01)")
    ap.add_argument("--data", type=Path, default=DATA, help="folder of CMU .bvh clips (evaluated together)")
    ap.add_argument("--out", type=Path, help="PNG to write (default docs/img/root_path_<clip>.png)")
    ap.add_argument("--perfect", action="store_true", help="perfect sensors (default: make run's raw ones)")
    ap.add_argument("--no-contacts", action="store_true", help="do not mark where the feet were put down")
    args = ap.parse_args()
    out = args.out or ROOT / "docs" / "img" / f"root_path_{args.clip}.png"
    with tempfile.TemporaryDirectory() as tmp:
        figures, dump = evaluate(args.data, args.clip, args.perfect, Path(tmp))
    sensors = "perfect sensors" if args.perfect else "raw ICM-42688-P sensors"
    draw(args.clip, figures, dump, sensors, out, not args.no_contacts)
    print(f"{args.clip} ({sensors}): path {figures['path_m']:.2f} m, end error {figures['end_cm']:.1f} cm "
          f"({figures['end_pct']:.1f} % of the path), root height error {figures['height_cm']:.1f} cm -> {out} "
          f"({out.stat().st_size // 1024} kB)")


if __name__ == "__main__":
    main()
