"""An aggregator's settings and its own counters (published in every stats message)."""
from __future__ import annotations

from dataclasses import dataclass, field

from limbstream import wire
from limbstream.pacing import LoopStats
from limbstream.skeleton import Skeleton


@dataclass(frozen=True)
class AggregatorSettings:
    """Tuning of one aggregator.

    Attributes
    ----------
    subjects : key-chunk patterns of the subjects this instance serves (``*`` = all), e.g. ("s0*",).
    rate : exact frame rate, Hz.
    live_rate : live frame rate, Hz (0 = none); the devices' sample rate by default.
    tick_s : loop period, seconds.
    stats_period_s : stats message period, seconds.
    history : segment points per device to ask for when joining late.
    error_window_s : angular-error window, seconds (of samples and frames at ``rate``).
    config_poll_s : how often device configs (threshold) are queried, seconds.
    trim_s : how often freed heap memory is given back to the OS, seconds (limbstream.heap).
    max_devices : most devices tracked; messages of further devices are counted and dropped.
    calibrate_on_start : calibrate each new stream from its calibration script
        (services/aggregator/calibrating.py; devices with a sensor model).
    calibration_file : where calibrations are kept, so that they outlive this process ("": not kept).
    heading_correction : hold each calibrated 6D device's heading by the joints (:mod:`.heading`).
    frame_batch_s : build exact frames at most this often, seconds (0 = every tick). Every build
        covers all subjects in a few vectorised calls, so batching only trades latency for CPU.
    joint_angles : publish every subject's joint angles, one message per live frame (per exact
        frame with ``live_rate`` 0): services/aggregator/angles.py.
    """

    subjects: tuple[str, ...] = ("*",)
    rate: float = wire.DEVICE_RATE_HZ
    live_rate: float = wire.DEVICE_RATE_HZ
    tick_s: float = 0.02
    stats_period_s: float = 1.0
    history: int = 512
    error_window_s: float = 60.0
    config_poll_s: float = 5.0
    trim_s: float = 5.0
    frame_batch_s: float = 0.0
    max_devices: int = 10_000
    skeleton: Skeleton = Skeleton()
    calibrate_on_start: bool = False
    calibration_file: str = ""
    joint_angles: bool = True
    heading_correction: bool = True


@dataclass
class AggregatorCounters:
    """Counters of the aggregator itself; its loop's pacing figures (:class:`limbstream.pacing.LoopStats`) in ``pacing``."""

    points: int = 0
    raw_batches: int = 0
    frames: int = 0
    unheard: int = 0         # pose frames made but not sent: no subscriber matched
    missed: int = 0          # reported by Zenoh's miss detection (not recoverable)
    max_backlog: int = 0     # most messages drained in one tick
    recent_backlog: int = 0  # most messages drained in one tick since the last stats message
    pacing: LoopStats = field(default_factory=LoopStats)

    def end_round(self, now: float) -> None:
        """A stats round is out: the pacing's ``load`` over it, and the ``recent_*`` figures start over."""
        self.pacing.end_round(now)
        self.recent_backlog = 0

    def as_dict(self) -> dict:
        """The counters as published in every stats message (``"aggregator"`` entry)."""
        return self.pacing.as_dict() | {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "pacing"}
