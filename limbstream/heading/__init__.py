"""Heading held by the body: per-joint heading correction of 6D-fused sensors.

Without a magnetometer every sensor's heading drifts on its own. The body's joints hold the
relative headings of adjacent segments (docs/evaluation.md, "Heading without resets"):

- :mod:`.joints`: the joints of a subject's segments, relative orientations, the joint angle error;
- :mod:`.hinge`: knees and elbows, one axis fixed in both segments;
- :mod:`.rom`: the hips' and the neck's range of motion;
- :mod:`.still`: a still joint keeps its heading; a still subject in the rest pose is a known pose;
- :mod:`.filter`: one Kalman filter per joint (offset, rate, mean twist);
- :mod:`.estimator`: :class:`HeadingCorrection`, per tick over (subjects, segments) arrays, and
  its offline form;
- :mod:`.simulate`: headings that drift as a 6D filter's do, to measure it.
"""
from limbstream.heading.estimator import HeadingCorrection, Settings

__all__ = ["HeadingCorrection", "Settings"]
