"""The heading correction's tunables (:class:`.estimator.HeadingCorrection`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Settings:
    """The estimator's tunables (angles in degrees, rates in deg/s, times in s).

    - ``update_s``: a filter step per this much of ticks.
    - Filters (:mod:`.filter`): the start's standard deviations of a joint's offset
      (``delta0_deg``: the calibration's), rate (``rate0_dps`` for ball joints,
      ``hinge_rate0_dps`` for hinges) and a hinge's bias (``hinge_mean0_deg``; a ball joint's
      mean twist: ``twist_deg``); their random walks per sqrt(s) (``delta_walk``, ``rate_walk``
      in deg/s, ``mean_walk``).
    - Hinges (:mod:`.hinge`): the spread of a knee's and an elbow's turns about the bone and
      across it (``knee_spread_deg``, ``elbow_spread_deg``), the time over which the hinge measure's
      errors are alike (``hinge_corr_s``), the axis learner's memory and trust thresholds
      (``axis_*``).
    - Ball joints (hips, shoulders, the neck; where a body has them the lumbar spine, the ankles
      and the wrists, which report two angles and are held by their twist and range): per kind,
      the prior of the mean twist and the twist's spread about it (``twist_deg``: (kind, mean
      sd, spread)), the time over which it stays alike
      (``twist_corr_s``), the gate in standard deviations beyond which a twist is left out
      (``twist_gate``); the range of motion's (:mod:`.rom`) measure, memory and share out of range
      that asks for a turn (``rom_*``).
    - Stillness (:mod:`.still`): below ``still_dps`` for ``still_s``; the relaxed pose measured at
      ``relaxed_sd_deg`` per second held, up to ``relaxed_pose_deg`` per still spell, within
      ``relaxed_lean_deg`` of the rest pose's lean and ``relaxed_gate_deg`` of the expected twist.
    - ``confidence_deg``: the offset's standard deviation at which a device's confidence is 1/2.
    - Contradicted constraints (:mod:`.contradiction`): a hinge bending about an axis more than
      ``hinge_off_deg`` out of the plane across its bone, a ranged joint out of range at every
      heading; kept over ``contradiction_memory_s``; a subject stops being corrected when a joint
      seen for ``contradiction_min_s`` is contradicted more than ``contradiction_share`` of it.
    """

    update_s: float = 0.2
    delta0_deg: float = 1.0
    rate0_dps: float = 0.05
    hinge_rate0_dps: float = 0.1
    hinge_mean0_deg: float = 3.0
    delta_walk: float = 0.02
    rate_walk: float = 5e-3
    mean_walk: float = 0.05
    knee_spread_deg: tuple[float, float] = (10.0, 3.0)
    elbow_spread_deg: tuple[float, float] = (30.0, 5.0)
    hinge_corr_s: float = 1.0
    axis_memory_s: float = 120.0
    axis_min_amount: float = 3.0
    axis_min_share: float = 0.8
    twist_deg: tuple[tuple[str, float, float], ...] = (("hip", 10.0, 10.0), ("shoulder", 30.0, 30.0),
                                                       ("neck", 10.0, 15.0), ("lumbar", 10.0, 15.0),
                                                       ("ankle", 10.0, 10.0), ("wrist", 20.0, 30.0))
    twist_corr_s: float = 1.0
    twist_gate: float = 4.0
    rom_sd_deg: float = 3.0
    rom_memory_s: float = 10.0
    rom_min_share: float = 0.2
    still_dps: float = 2.0
    still_s: float = 1.0
    relaxed_sd_deg: float = 1.0
    relaxed_pose_deg: float = 2.0
    relaxed_lean_deg: float = 5.0
    relaxed_gate_deg: float = 25.0
    confidence_deg: float = 5.0
    hinge_off_deg: float = 75.0
    contradiction_memory_s: float = 60.0
    contradiction_min_s: float = 30.0
    contradiction_share: float = 0.5

    def heading_sd(self, calibrated_s_ago: float | None) -> float:
        """A joint's heading offset's standard deviation, rad, at a restart: as at a calibration
        made ``calibrated_s_ago`` seconds ago (``delta0_deg`` and the drift since at
        ``rate0_dps``), or half a turn either way (None: not calibrated)."""
        if calibrated_s_ago is None:
            return float(np.pi)
        return float(min(np.pi, np.radians(np.hypot(self.delta0_deg, self.rate0_dps * max(0.0, calibrated_s_ago)))))

    def __post_init__(self):
        for name in ("update_s", "delta0_deg", "rate0_dps", "hinge_rate0_dps", "hinge_mean0_deg", "hinge_corr_s",
                     "axis_memory_s", "twist_corr_s", "twist_gate", "rom_sd_deg", "rom_memory_s", "still_s",
                     "relaxed_sd_deg", "relaxed_pose_deg", "confidence_deg", "hinge_off_deg", "contradiction_memory_s",
                     "contradiction_min_s", "contradiction_share"):
            if not getattr(self, name) > 0:
                raise ValueError(f"Settings.{name} must be > 0, got {getattr(self, name)}")


DEFAULTS = Settings()
"""The default tunables."""
