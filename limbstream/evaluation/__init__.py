"""Offline evaluation of the segmentation algorithms: the fastSW paper's protocol (Sect. 6, Fig. 4).

Every segment stream of every motion is segmented at each threshold; the streams are rebuilt by
SLERP between their (normalised) segment points and compared with the original samples:

- ``icr``: segment points / samples over all streams (paper, eq. 1);
- ``aad``, ``std``, ``p99``, ``max``: angular deviation (eq. 2) of the reconstruction at every
  original timestamp, pooled over all streams (AAD, eq. 3; Fig. 4 left);
- ``point_aad``, ``point_max``: deviation of the segment points themselves from the original
  samples at their timestamps (Fig. 4 right): zero for fastSW and SW, whose points are samples;
  not for CPLR and the Swing filter, whose points are extrapolated.
- ``body_aad`` (with a sensor model, ``--mounting-deg`` ...): the calibrated reconstruction
  against the segments' true orientations, over the motion after the calibration script
  (:mod:`limbstream.calibration`); ``aad`` stays the compression error (against what the
  sensors reported), as in the paper.
- ``joint_aad`` and, per joint kind, ``joint_kinds``: the joint error, the angle between the
  estimated and the true relative orientation of each pair of adjacent segments
  (:mod:`.body`), whichever way the body faces; with a sensor model of the calibrated
  reconstruction, its headings held by the joints when asked (``heading``).
- ``pos_cm`` and, per joint kind, ``positions``: the mean per-joint position error, cm, the
  pelvis at the origin (:mod:`.positions`): the estimated orientations' joints on the source's
  body against the source file's own joints (BVH) or the true orientations' on the same body.
- ``live_aad``, ``live_p99``, ``live_max``: the live error at every sample (docs/evaluation.md,
  "Live mode"): the receiver's view of the sample's time, made from the points it has by then
  (the newest one extrapolated at its rate, :func:`limbstream.quat.predict`), against the
  sample. A point is known from the update call that emitted it (``Segmentation.known_from``):
  one closed by the SSR or max_len rule from the sample after it, one closed by fastSW's live
  rule (``live_bound_deg`` > 0) from its own. ``predictor`` names the points' rates: ``rate`` (the
  live rule's own: through the neighbouring sample), ``slope`` (the closed segment's slope,
  through the point before) or ``hold`` (none). fastSW's live rule with ``rate`` is the C
  kernel; with ``slope`` or ``hold`` it is :func:`simulate_live` (float64).

Thresholds mean different things per algorithm (an SSR bound for fastsw, sw and cplr, a
largest absolute deviation per component for swing), so algorithms are compared at equal ICR:
:func:`at_icr` interpolates each measure at given ICRs.

Modules: :mod:`.sweep` (the sweep and the measures), :mod:`.body` (whole bodies: heading
correction, joint error, dumps), :mod:`.positions` (joint positions), :mod:`.live_model` (the live view),
:mod:`.report` (the tables, frontier, JSON), :mod:`.fusion` (a fusion filter's orientation error against
a reference, as the BROAD benchmark scores it). Command line: ``limbstream eval``
(:mod:`limbstream.cli.evaluate`).
"""
from __future__ import annotations

from limbstream.evaluation.live_model import simulate_live
from limbstream.evaluation.report import (format_heading_stopped, format_joint_errors, format_joint_kinds, format_positions, format_table, format_translation, frontier,
                                          write_json)
from limbstream.evaluation.sweep import (ALGORITHMS, CALIBRATIONS, ICR_TARGETS, KEYS, MAX_LEN, MEASURES, PREDICTORS, THRESHOLDS,
                                         Stream, at_icr, evaluate, evaluate_threshold, streams_of)
from limbstream.evaluation.sweep import _Pool  # noqa: F401  (the tests' pooled streams)

__all__ = ["ALGORITHMS", "CALIBRATIONS", "ICR_TARGETS", "KEYS", "MAX_LEN", "MEASURES", "PREDICTORS", "THRESHOLDS", "Stream",
           "at_icr", "evaluate", "evaluate_threshold", "format_heading_stopped", "format_joint_errors", "format_joint_kinds", "format_positions", "format_table", "format_translation", "frontier", "simulate_live", "streams_of",
           "write_json"]
