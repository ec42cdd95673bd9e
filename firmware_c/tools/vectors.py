"""Test vectors for the Cortex-M4 harness (firmware_c/m4/main.c), in one binary layout.

Layout (little-endian, every field 4 bytes)::

    "LSV2"  u32 n_cases
    per case: f32 threshold, u32 max_len, f32 live_bound_deg, u32 m, u32 ticks[m], f32 y[m][4]

The same bytes are either compiled into the firmware as a C header (the default vectors:
seeded synthetic quaternion streams, so the build does not need the motion data) or read
by the firmware from a host file through semihosting (e.g. real CMU clips).

Usage::

    python3 vectors.py header OUT.h          # synthetic default vectors as a C header
    python3 vectors.py blob OUT.bin [--npz cmu_10seg_50hz.npz]
"""
from __future__ import annotations

import argparse
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MAGIC = b"LSV2"
HEADER = struct.Struct("<fIfI")
"""Per-case header: threshold, max_len, live_bound_deg, m."""
DIM = 4
TICK_US = 20_000
"""Nominal sample period, microsecond ticks (50 Hz)."""


@dataclass(frozen=True)
class Case:
    """One stream with its settings.

    Attributes
    ----------
    threshold : float, SSR threshold (float32 in the kernel).
    max_len : int, samples per segment after its anchor.
    ticks : (m,) uint32, microseconds.
    y : (m, 4) float32, scalar-first quaternions (may hold NaN to test rejection).
    live_bound_deg : float, the live rule's bound in degrees (0: off).
    """

    threshold: float
    max_len: int
    ticks: np.ndarray
    y: np.ndarray
    live_bound_deg: float = 0.0


def random_walk(rng: np.random.Generator, m: int, start_tick: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random rotation sampled at ~50 Hz with jittered ticks.

    Returns
    -------
    ticks : (m,) uint32, increasing modulo 2**32 from ``start_tick``.
    q : (m, 4) float32, unit quaternions, continuous in sign.
    """
    omega = np.cumsum(rng.normal(0.0, 0.6, (m, 3)), axis=0) * 0.05  # rad/s, drifting
    dt = TICK_US * 1e-6
    q = np.empty((m, 4))
    q[0] = rng.normal(size=4)
    q[0] /= np.linalg.norm(q[0])
    for i in range(1, m):
        angle = np.linalg.norm(omega[i]) * dt
        axis = omega[i] / (np.linalg.norm(omega[i]) or 1.0)
        dq = np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis]
        w0, v0 = q[i - 1, 0], q[i - 1, 1:]
        w1, v1 = dq[0], dq[1:]
        q[i] = np.r_[w0 * w1 - v0 @ v1, w0 * v1 + w1 * v0 + np.cross(v0, v1)]
        q[i] /= np.linalg.norm(q[i])
    steps = TICK_US + rng.integers(-500, 501, m)
    ticks = (start_tick + np.cumsum(steps) - steps[0]) & 0xFFFFFFFF
    return ticks.astype(np.uint32), q.astype(np.float32)


def jumpy(rng: np.random.Generator, m: int, every: int = 8, degrees: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random walk whose orientation steps by ``degrees`` every ``every`` samples
    (like the glitches of recorded motion)."""
    ticks, q = random_walk(rng, m)
    q = q.astype(np.float64)
    step = np.radians(degrees) / 2.0
    offset = np.array([1.0, 0.0, 0.0, 0.0])
    for i in range(m):
        if i and i % every == 0:
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            jump = np.r_[np.cos(step), np.sin(step) * axis]
            w0, v0, w1, v1 = jump[0], jump[1:], offset[0], offset[1:]
            offset = np.r_[w0 * w1 - v0 @ v1, w0 * v1 + w1 * v0 + np.cross(v0, v1)]
        w0, v0, w1, v1 = offset[0], offset[1:], q[i, 0], q[i, 1:]
        q[i] = np.r_[w0 * w1 - v0 @ v1, w0 * v1 + w1 * v0 + np.cross(v0, v1)]
    return ticks, (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)


def synthetic_cases(seed: int = 2021) -> list[Case]:
    """Default vectors: smooth streams at several thresholds plus every special input.

    Cases 0-6 (live rule off) cover SSR breaks, max_len breaks, a NaN and an Inf sample,
    repeated and decreasing timestamps, and a tick counter that wraps around 2**32. Cases
    7-12 run the live rule: at 2 and 5 degrees, near 180, on a stream that steps by 40
    degrees every 8 samples (with SSR and with max_len breaks), on the faults.
    """
    rng = np.random.default_rng(seed)
    cases = []
    ticks, q = random_walk(rng, 300)
    for threshold in (1e-4, 1e-3, 1e-2, 1e-1):
        cases.append(Case(threshold, 1000, ticks, q))
    cases.append(Case(1e-2, 7, ticks, q))  # max_len breaks
    ticks, q = random_walk(rng, 200, start_tick=0xFFFFFFFF - 1_500_000)  # wraps after 75 samples
    bad_ticks, bad_q = ticks.copy(), q.copy()
    bad_q[20, 2] = np.nan
    bad_q[21, 0] = np.inf
    bad_ticks[40] = bad_ticks[39]  # zero time step
    bad_ticks[60] = bad_ticks[59] - 5  # negative time step
    cases.append(Case(1e-3, 1000, bad_ticks, bad_q))
    cases.append(Case(0.0, 1000, ticks[:50], q[:50]))  # every sample a point
    smooth_ticks, smooth_q = cases[0].ticks, cases[0].y
    cases.append(Case(1e-3, 1000, smooth_ticks, smooth_q, 2.0))  # 7
    cases.append(Case(1e-2, 25, smooth_ticks, smooth_q, 5.0))  # 8
    cases.append(Case(1e-2, 25, smooth_ticks, smooth_q, 179.5))  # 9: rule on, hardly ever closes
    jump_ticks, jump_q = jumpy(rng, 200)
    cases.append(Case(1e-3, 1000, jump_ticks, jump_q, 5.0))  # 10: SSR breaks at the steps
    cases.append(Case(1e30, 7, jump_ticks, jump_q, 5.0))  # 11: max_len breaks at the steps
    cases.append(Case(1e-3, 1000, bad_ticks, bad_q, 3.0))  # 12: faults and wrap-around
    return cases


def npz_cases(path: Path, count: int = 400) -> list[Case]:
    """Real vectors: the first ``count`` samples of every segment of every clip in a
    cmu_10seg_50hz.npz file, at thresholds 1e-3 and 1e-2, the second also with the live
    rule at 5 degrees and max_len 25 (50 Hz -> 20 000 us ticks)."""
    data = np.load(path)
    cases = []
    for name in sorted(k for k in data.files if k.startswith("clip_")):
        clip = data[name][:count]
        ticks = (np.arange(len(clip)) * TICK_US).astype(np.uint32)
        for s in range(clip.shape[1]):
            y = np.ascontiguousarray(clip[:, s], np.float32)
            for threshold in (1e-3, 1e-2):
                cases.append(Case(threshold, 1000, ticks, y))
            cases.append(Case(1e-2, 25, ticks, y, 5.0))
    return cases


def pack(cases: list[Case]) -> bytes:
    """Cases -> the binary layout of the module docstring."""
    parts = [MAGIC, struct.pack("<I", len(cases))]
    for case in cases:
        ticks = np.asarray(case.ticks, "<u4")
        y = np.asarray(case.y, "<f4")
        if y.shape != (len(ticks), DIM):
            raise ValueError(f"case y must be ({len(ticks)}, {DIM}), got {y.shape}")
        parts.append(HEADER.pack(case.threshold, case.max_len, case.live_bound_deg, len(ticks)))
        parts.append(ticks.tobytes())
        parts.append(y.tobytes())
    return b"".join(parts)


def c_header(blob: bytes) -> str:
    """The blob as a 4-byte aligned C array ``default_vectors``."""
    rows = [", ".join(f"0x{b:02x}" for b in blob[i:i + 16]) for i in range(0, len(blob), 16)]
    body = ",\n    ".join(rows)
    return (
        "/* Default test vectors for firmware_c/m4/main.c, written by firmware_c/tools/vectors.py. */\n"
        "#include <stdint.h>\n"
        f"static const uint8_t default_vectors[{len(blob)}] __attribute__((aligned(4))) = {{\n"
        f"    {body}\n}};\n"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("kind", choices=["header", "blob"])
    parser.add_argument("out", type=Path)
    parser.add_argument("--npz", type=Path, help="real vectors from a cmu_10seg_50hz.npz (blob only)")
    args = parser.parse_args(argv)
    cases = npz_cases(args.npz) if args.npz else synthetic_cases()
    blob = pack(cases)
    if args.kind == "header":
        args.out.write_text(c_header(blob))
    else:
        args.out.write_bytes(blob)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
