"""The wire contract, one place (docs/protocol.md): everything the parts say to each other.

==============  ==============================================================
module          what it holds
==============  ==============================================================
:mod:`.keys`    key-expression grammar: builders for every key and selector
:mod:`.body`    body layout: segments, joints, bones; a wearer's dimensions
:mod:`.point`   segment point codec (device -> aggregator)
:mod:`.raw`     truth-tap batch codec (one device's)
:mod:`.truth`   subject truth-tap codec (the batches of a subject's devices in one message)
:mod:`.pose`    pose frame codec (aggregator -> clients)
:mod:`.angles`  joint-angle codec (aggregator -> clients)
:mod:`.fields`  the stats field table; :mod:`.stats` its codec (compact, JSON)
:mod:`.rejects` the reasons a receiver counts a dropped message under
:mod:`.config`  device tunables (defaults, bounds), config and status messages
:mod:`.time`    time exchange codec (device <-> time service)
:mod:`.calibrate` calibration requests (client -> aggregator) and answers
:mod:`.gateway` a gateway's sensor listing and run-time assignments (client -> gateway)
:mod:`.serial_link` the serial link between a device and its gateway (``wire.serial_link``)
==============  ==============================================================

All binary payloads are little-endian and start with a format version byte. Import the
package, not the modules: ``from limbstream import wire; wire.seg_key(...)``.
"""
from .calibrate import (CALIBRATION_ANSWER_TIMEOUT_S, CALIBRATION_HOLD_S, CALIBRATION_POSES, CalibrateAnswer, decode_calibrate_answer,
                        decode_calibrate_request, encode_calibrate_answer, encode_calibrate_request)
from .angles import (ANGLE_BASES, ANGLE_FLAGS, ANGLE_GIMBAL, ANGLE_MISSING, ANGLE_UNCALIBRATED, ANGLES_DTYPE,
                     ANGLES_DTYPE_V1, ANGLES_HEADER_SIZE, ANGLES_SIZE, ANGLES_VERSION, ANGLES_VERSION_V1, BASIS, AngleBasis,
                     AngleFrames, JointAngles, angles_dtype, decode_angles, decode_angles_many, encode_angles)
from .body import (BONES, DEFAULT_REST_POSE, FULL_JOINT_TABLE, JOINT_ANGLES, JOINT_TABLE, JOINT_TABLES, JOINTS,
                   MAX_LAYOUT_BYTES, ORIENTATIONS, REST_POSES, SEGMENTS, Joint, body_layout, builtin_segments, check_rest_pose,
                   decode_body, encode_body, joint_angles, joint_table, joints_among)
from .config import (DEVICE_RATE_HZ, LIVE_BOUND_DEG, LIVE_MODE, MAX_LEN, THRESHOLD, TUNABLES, ClockStatus, DeviceConfig,
                     DeviceStatus, FusionStatus, FUSION_MODES, LinkStatus, Tunable, decode_config, decode_status,
                     encode_config, encode_status)
from .errors import WireError
from .fields import (AGGREGATOR_FIELDS, AGGREGATOR_FIGURES, DEVICE_FIELDS, FIELDS, HISTORY_FIELDS, STATS_FIELDS, SUBJECT_FIELDS,
                     StatsField)
from .gateway import Assignment, decode_assignment, decode_sensors, encode_assignment, encode_sensors
from .keys import (ALIVE, ANGLES, CALIBRATE, CONFIG, POSE, RAW, SEG, STATS, TRUTH, CHUNK_PATTERN, DEVICE_KINDS, GATEWAY_CHUNK, PREFIX, SUBJECT_KINDS, TIME_CHUNK, alive_key, angles_key, calibrate_key, check_chunk, to_chunk, config_key, device_id, device_key,
                   device_selector, gateway_key, gateway_selector, history_selector, parse_device_key, parse_gateway_key, parse_subject_key, pose_key, raw_key, seg_key,
                   split_device_id, stats_key, subject_key, subject_pattern, subject_selector, time_key, truth_key)
from .point import (FLAG_FINAL, POINT_SIZE, POINT_SIZE_RATE, UNIT_TOLERANCE, VERSION, VERSION_RATE, PointColumns,
                    SegmentPoint, decode_point, decode_points, encode_point)
from .pose import (AUTO, AUTO_LIVE_WINDOW_S, CONTACTS, FRAME_KINDS, FRAME_GAP, FRAME_MISSING, FRAME_NO_ROOT, FRAME_OFF_FEET, FRAME_TPOSE,
                   KIND_EXACT, KIND_LIVE,
                   LAYOUT_CODES, OTHER_LAYOUT, POSE_DTYPE, POSE_DTYPE_V1, POSE_VERSION, POSE_VERSION_V1, PoseFrame, PoseFrames,
                   auto_kind, contact_names, decode_pose, encode_pose, frame_rest_pose, kind_name, layout_code, pose_dtype,
                   pose_stream, rest_pose_flag)
from .rejects import POINT_DROPS, RAW_DROPS, STATUS_DROPS, UNCHARGED, device_reason, truth_reason, undecodable
from .raw import (MAX_RAW_BATCH, RAW_SAMPLE_DTYPE, RAW_SAMPLE_DTYPE_V2, RAW_SAMPLE_DTYPE_V3, RAW_VERSION, RawBatch, RawColumns, decode_raw,
                  decode_raws, encode_raw, encode_raws)
from .truth import MAX_TRUTH_ENTRIES, TRUTH_VERSION, decode_truth, encode_truth, truth_batches
from .stats import (STATS_NUMBERS, STATS_TEXTS, STATS_VERSION, decode_stats, encode_stats, encode_stats_json,
                    encode_stats_table, stats_devices, stats_json)
from .time import (MAX_TIME_US, TIME_ANSWER_SIZE, TIME_REQUEST_SIZE, TIME_VERSION, TimeAnswer, TimeRequest,
                   decode_time_answer, decode_time_request, encode_time_answer, encode_time_request, offset_delay)

