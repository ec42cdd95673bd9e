"""Root translation from foot contacts on the CMU clips, fed the files' own feet (docs/benchmarks.md,
"Root translation"): what the contact rule (limbstream.body.translation) makes of feet placed
exactly where the file puts them, against the file's own root path. It bounds what estimated feet
can reach on these clips: the files' feet skate, and the **oracle** column says how much (the root
moved by the truly stillest foot point's motion, frame by frame).

    python bench/root_translation.py            # every clip of ../shared/data/cmu
    python bench/root_translation.py 02_01 131_01

Columns (limbstream.evaluation.translation): the clip's length and horizontal path (m, the
root's path over 0.1 s steps); the horizontal root error at the end (cm, and % of the path) after
aligning the start once (the mean horizontal offset over the first 0.5 s; the feet come in world
axes, so no heading to align); the mean root height error (cm, the floor at the file's lowest
foot point over the clip) and beside it the same over the feet (the file's floor at its lowest
foot point frame by frame); where the file's feet stand: its lowest foot point's height over the
clip's lowest, median and 90th percentile over the frames where it is still (changing slower than
0.1 m/s), cm; the estimated foot points' horizontal speed while the file's are planted, and the
file's own over the same frames (cm/s); the share of frames in flight; the oracle's end error.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from limbstream.body.translation import RootTracker
from limbstream.evaluation.translation import PLANTED_MPS, translation_figures
from limbstream.sources.bvh import global_rotations, joint_positions, parse_bvh
from limbstream.sources.bvh_body import CMU_UNIT_M

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "cmu"
NAMES = ("l_heel", "l_toe", "r_heel", "r_toe")


def _joint(index: dict[str, int], *names: str) -> str:
    return next(n for n in names if n in index)


def file_feet(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame times (F,) s, the root's path (F, 3) m and the feet's heel and toe points (F, 4, 3) m,
    world frame, the floor at the lowest point. A heel lies below its ankle by the foot's drop from
    ankle to toe, turned by the foot; a toe is the toe joint."""
    clip = parse_bvh(path)
    pos, _ = joint_positions(clip)
    at = {n: i for i, n in enumerate(clip.joints)}
    points = []
    for side in ("Left", "Right"):
        foot, toe = _joint(at, f"{side}Foot", f"{side}Ankle"), _joint(at, f"{side}ToeBase", f"{side}Toe")
        drop = np.array([0.0, clip.offsets[at[toe]][1], 0.0])
        heel = pos[:, at[foot]] + global_rotations(clip, [foot])[foot].apply(drop)
        points += [heel, pos[:, at[toe]]]
    feet = np.stack(points, axis=1) * CMU_UNIT_M
    root = pos[:, at["Hips"]] * CMU_UNIT_M
    floor = np.nanmin(feet[:, :, 1])
    feet[:, :, 1] -= floor
    root[:, 1] -= floor
    return np.arange(len(root)) * clip.frame_time, root, feet


def figures(path: Path) -> dict[str, float]:
    """One clip's row (see the module)."""
    t, root, feet = file_feet(path)
    rel = feet - root[:, None]
    est, bits, _ = RootTracker(1, NAMES).track(t, rel)
    f = translation_figures(t, est, est[:, None] + rel, root, feet)
    world_speed = np.linalg.norm(np.diff(feet[:, :, [0, 2]], axis=0), axis=2) / np.diff(t)[:, None]
    stillest = world_speed.argmin(axis=1)
    steps = np.diff(rel, axis=0)[:, :, [0, 2]]
    oracle = -steps[np.arange(len(stillest)), stillest].sum(axis=0)
    lowest = feet[:, :, 1].min(axis=1)  # (the floor at the clip's lowest foot point: 0)
    still = np.r_[True, np.abs(np.diff(lowest)) / np.diff(t) < PLANTED_MPS]
    return {"s": float(t[-1]), "path_m": f.path_m, "end_cm": f.end_cm, "end_pct": f.end_pct,
            "height_cm": f.height_cm, "height_feet_cm": f.height_feet_cm,
            "stand_cm": 100 * float(np.median(lowest[still])), "stand_p90_cm": 100 * float(np.percentile(lowest[still], 90)),
            "skate": f.skate_cmps, "true_skate": f.true_skate_cmps,
            "flight": float(np.mean(bits == 0)),
            "oracle_cm": 100 * float(np.linalg.norm(oracle - (root[-1, [0, 2]] - root[0, [0, 2]])))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clips", nargs="*", help="clip names (default: every clip of the data folder)")
    ap.add_argument("--data", type=Path, default=DATA, help="folder of CMU .bvh clips")
    args = ap.parse_args()
    paths = [args.data / f"{c}.bvh" for c in args.clips] or sorted(args.data.glob("*.bvh"))
    print("| clip | s | path, m | end error, cm | % of path | height error, cm | over the feet, cm | "
          "file's feet stand, cm (p90) | skating, cm/s (truth's) | in flight | "
          "oracle end, cm |")
    print("|---|---:|---:|---:|---:|---:|---:|---|---|---:|---:|")
    for path in paths:
        r = figures(path)
        print(f"| {path.stem} | {r['s']:.1f} | {r['path_m']:.2f} | {r['end_cm']:.1f} | {r['end_pct']:.1f} | "
              f"{r['height_cm']:.1f} | {r['height_feet_cm']:.1f} | {r['stand_cm']:.1f} ({r['stand_p90_cm']:.1f}) | "
              f"{r['skate']:.1f} ({r['true_skate']:.1f}) | {r['flight']:.2f} | "
              f"{r['oracle_cm']:.1f} |")


if __name__ == "__main__":
    main()
