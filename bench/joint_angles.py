"""Joint angles of a real recording, as `limbstream export -o X.mot` writes them (docs/evaluation.md,
"Joint angles"): the knees' and hips' ranges, and optionally a plot of their flexion.

The recording starts standing still: loading it calibrates each sensor from the first second
(rest pose; limbstream.sources.imu_files.to_body), the export finds the subject's facing from the
knees' motion (limbstream.joints.functional), and the angles are the Rajagopal model's
coordinates (degrees), time 0 at the first common sample.

    python bench/joint_angles.py ../shared/data/xsens_opensense --names opensense --plot docs/joint_angles_xsens_walk.png
    python bench/joint_angles.py ../shared/data/xio_lower_body
    python bench/joint_angles.py --speed   # the cost of the angles of 200 subjects per frame

``--names``: the Xsens MTw files name their sensors by serial number only; they are mapped as
every command maps them (limbstream.sources.names; ``opensense``: OpenSim's own example code's).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from limbstream import joints, wire
from limbstream.cli.flags import add_names
from limbstream.services.outputs.export import from_motion, take_angles
from limbstream.sources import load

SHOWN = ("knee_angle_l", "knee_angle_r", "hip_flexion_l", "hip_flexion_r", "hip_adduction_l", "hip_adduction_r",
         "hip_rotation_l", "hip_rotation_r")


def table(path: str, names: dict[str, str] | None) -> tuple[str, np.ndarray, np.ndarray]:
    """(markdown table, (F,) seconds, (F, A) angles) of one recording (``names``: its sensors'
    segments, limbstream.sources.names)."""
    take = from_motion(load(path, names), None, Path(path), None)
    angles, _ = take_angles(take)
    t = (take.t_us - take.t_us[0]) / 1e6
    lines = [f"{take.name}: {len(t)} frames at {1e6 / take.period_us:g} Hz ({t[-1]:.1f} s); calibration: {take.basis}",
             "", "| angle | p2 / p50 / p98 (deg) | min / max (deg) | range p2-p98 (deg) |", "|---|---|---|---|"]
    for name in SHOWN:
        v = angles[:, joints.ANGLES.index(name)]
        v = v[np.isfinite(v)]
        p = np.percentile(v, [2, 50, 98])
        lines.append(f"| {name} | {p[0]:.1f} / {p[1]:.1f} / {p[2]:.1f} | {v.min():.1f} / {v.max():.1f} | "
                     f"{p[2] - p[0]:.1f} |")
    return "\n".join(lines), t, angles


def plot(t: np.ndarray, angles: np.ndarray, path: Path, title: str) -> None:
    """Knee and hip flexion over time, both sides, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True, constrained_layout=True)
    for ax, joint in zip(axes, ("knee_angle", "hip_flexion")):
        for side, color in (("l", "C0"), ("r", "C3")):
            ax.plot(t, angles[:, joints.ANGLES.index(f"{joint}_{side}")], color=color, lw=1.1,
                    label=f"{joint}_{side}")
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylabel("degrees")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[1].set_xlabel("time (s)")
    fig.suptitle(title)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def speed(subjects: int = 200, rate_hz: float = wire.DEVICE_RATE_HZ, repeats: int = 300) -> str:
    """The cost of :func:`limbstream.joints.joint_angles` for ``subjects`` subjects at once (one
    frame each, as an aggregator's frame tick; float64, and float32 as the aggregator calls it;
    the ``full`` layout's too), of
    the aggregator's whole joint stage on such a tick (angles, flags, encoding, the messages), and
    of the functional calibration's running sums (one second of frames per call), as a table. CPU
    time of this process (less sensitive to other work on the machine than wall time)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    q = Rotation.random(subjects * 10, random_state=rng).as_quat()[:, [3, 0, 1, 2]].reshape(subjects, 10, 4)

    def cost(work, n: int = repeats) -> float:
        work()
        start = time.process_time()
        for _ in range(n):
            work()
        return (time.process_time() - start) / n

    full = Rotation.random(subjects * 15, random_state=rng).as_quat()[:, [3, 0, 1, 2]].reshape(subjects, 15, 4)
    stage, batch = _joint_stage(q)
    stats = joints.HingeStats.empty((subjects,))
    second = np.broadcast_to(q[:, None], (subjects, round(rate_hz), 10, 4))
    rows = [("joint angles, one frame tick (float64)", cost(lambda: joints.joint_angles(q)), rate_hz),
            ("joint angles, one frame tick (float32, the aggregator's)",
             cost(lambda: joints.joint_angles(q.astype(np.float32))), rate_hz),
            ("joint angles, one frame tick of the full layout (15 segments, 30 angles; float32)",
             cost(lambda: joints.joint_angles(full.astype(np.float32), layout="full")), rate_hz),
            (f"the aggregator's joint stage, one frame tick (angles, flags, {subjects} messages encoded)",
             cost(lambda: list(stage(batch))), rate_hz),
            ("functional sums + facing, one second of frames", cost(lambda: (stats.add(second), stats.facing()), 10),
             1.0)]
    lines = [f"| work ({subjects} subjects, {rate_hz:g} Hz) | per call (CPU) | share of one core |", "|---|---:|---:|"]
    return "\n".join(lines + [f"| {what} | {t * 1e6:,.0f} us | {100 * t * per_s:.2f} % |" for what, t, per_s in rows])


def _joint_stage(q: np.ndarray):
    """An aggregator's joint stage whose subjects' devices send their segments' own orientations,
    and a tick's live frames of ``q`` (S, 10, 4)."""
    from limbstream.services.aggregator.aggregator import Aggregator, AggregatorSettings
    from limbstream.services.aggregator.frames import FrameBatch

    agg = Aggregator(None, AggregatorSettings())
    for s in range(len(q)):
        for segment in wire.SEGMENTS:
            track = agg.track(f"s{s + 1:03d}", segment)
            agg.fusion.set_online(track, True)
            track.orientations = "segments"
    n = len(q)
    live = wire.PoseFrames(np.arange(n), np.full(n, 1_800_000_000_000_000), wire.KIND_LIVE, np.zeros(n, np.int64), q,
                           np.zeros((n, len(wire.JOINTS), 3)))
    none = np.zeros((0, len(wire.SEGMENTS)), bool)
    return agg.frame_stages[0], FrameBatch(np.zeros(0, np.int64), wire.PoseFrames.empty(wire.KIND_EXACT), np.arange(n),
                                           live, none, np.zeros((n, len(wire.SEGMENTS)), bool))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", nargs="?", help="a recording of real sensors that starts standing still (x-IMU3, "
                                                "Xsens folder)")
    parser.add_argument("--speed", action="store_true", help="time the angles of 200 subjects instead")
    add_names(parser)
    parser.add_argument("--plot", type=Path, metavar="OUT.png", help="draw knee and hip flexion into this PNG")
    args = parser.parse_args(argv)
    if args.speed:
        print(speed())
        return 0
    if args.path is None:
        parser.error("give a recording (or --speed)")
    text, t, angles = table(args.path, args.names)
    print(text)
    if args.plot is not None:
        plot(t, angles, args.plot, f"{Path(args.path).name}: knee and hip flexion (Rajagopal conventions)")
        print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
