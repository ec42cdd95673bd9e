"""Joint angles: anatomical segment frames, angles in OpenSim's conventions, a functional
calibration of the facing from the hinges, and scoring against true angles.

==================  ===========================================================
module              what it holds
==================  ===========================================================
:mod:`.convention`  the angle names, the joints, anatomical frames, the angles
:mod:`.functional`  the facing from the knees' and elbows' motion (offline, live)
:mod:`.scoring`     true angles of a motion, per-angle error figures
==================  ===========================================================
"""
from limbstream.joints.convention import (ANGLES, GIMBAL, GIMBAL_DEG, JOINT_TABLE, MISSING, TO_OPENSIM, UNCALIBRATED,
                                          Joint, anatomical, angle_names, euler_zxy, from_tpose, joint_angles, standing)
from limbstream.joints.functional import HINGES, Facing, HingeStats, face, functional_calibration, rotation_vector
from limbstream.joints.scoring import FIGURES, angle_errors, in_layout, pooled_errors, true_angles

__all__ = ["ANGLES", "FIGURES", "GIMBAL", "GIMBAL_DEG", "HINGES", "JOINT_TABLE", "MISSING", "TO_OPENSIM", "UNCALIBRATED",
           "Facing", "HingeStats", "Joint", "anatomical", "angle_errors", "angle_names", "from_tpose", "euler_zxy", "face",
           "functional_calibration", "in_layout", "joint_angles", "pooled_errors", "rotation_vector", "standing",
           "true_angles"]
