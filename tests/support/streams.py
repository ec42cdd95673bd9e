"""Quaternion streams the kernel's tests segment: seeded random walks (uniform and jittered
times), the CMU clips and the x-IMU3 recording as (name, t s, (m, 4) q) triples; and the
tolerance of the kernel's float32 rates."""
from __future__ import annotations

import numpy as np


def random_walk_quaternions(m: int, seed: int, step: float = 0.05) -> np.ndarray:
    """(m, 4) float64 unit quaternions of a seeded smooth random rotation walk."""
    rng = np.random.default_rng(seed)
    velocity = np.cumsum(rng.normal(0, step, (m, 4)), axis=0) * 0.1
    q = np.array([1.0, 0, 0, 0]) + np.cumsum(velocity, axis=0) * 0.05
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def synthetic_streams() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Seeded streams with uniform and jittered (non-uniform) timestamps."""
    streams = []
    for seed in range(6):
        rng = np.random.default_rng(100 + seed)
        m = 600
        dt = np.full(m, 0.02) if seed % 2 == 0 else rng.uniform(0.005, 0.04, m)
        streams.append((f"synthetic{seed}", np.cumsum(dt), random_walk_quaternions(m, seed)))
    return streams


def cmu_streams(path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    data = np.load(path)
    fs = float(data["fs"])
    streams = []
    for key in (k for k in data.files if k.startswith("clip_")):
        clip = data[key]
        for s in range(clip.shape[1]):
            streams.append((f"{key}/{s}", np.arange(len(clip)) / fs, clip[:, s, :]))
    return streams


def xio_streams(folder) -> list[tuple[str, np.ndarray, np.ndarray]]:
    streams = []
    for csv in sorted(folder.glob("*.csv")):
        raw = np.loadtxt(csv, delimiter=",", skiprows=1)
        streams.append((csv.name, raw[:, 0] * 1e-6, raw[:, 1:5]))
    return streams


def rates_match(got: np.ndarray, want: np.ndarray) -> bool:
    """float32 rates against float64 ones: a rate is a difference quotient of neighbouring
    samples, resolved to about 1e-5 of itself (plus 1e-4 rad/s) in float32."""
    scale = np.linalg.norm(want, axis=1, keepdims=True)
    return bool(np.all(np.abs(got - want) <= 1e-3 * scale + 1e-4))
