"""The body layout every message shares: the 10 measured segments, the joints of a pose
frame and the bones a client draws between them, the joint angles of a joint-angle message, and
what a device's orientations are."""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass

SEGMENTS: tuple[str, ...] = (
    "l_shank", "r_shank", "l_thigh", "r_thigh", "l_lowerarm",
    "r_lowerarm", "l_upperarm", "r_upperarm", "neck", "hip",
)
"""The 10-IMU layout: one device per segment, in this order in pose frames and motion arrays."""

JOINTS: tuple[str, ...] = (
    "pelvis", "neck_base", "head",
    "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle",
    "l_shoulder", "l_elbow", "l_wrist", "r_shoulder", "r_elbow", "r_wrist",
)
"""Joint positions of a pose frame, in this order (see limbstream.skeleton)."""

BONES: tuple[tuple[str, str], ...] = (
    ("pelvis", "neck_base"), ("neck_base", "head"),
    ("pelvis", "l_hip"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"),
    ("pelvis", "r_hip"), ("r_hip", "r_knee"), ("r_knee", "r_ankle"),
    ("neck_base", "l_shoulder"), ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"),
    ("neck_base", "r_shoulder"), ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"),
)
"""Lines a client draws between joints."""

def builtin_segments() -> tuple[str, ...]:
    """Every segment name of the built-in layouts (``paper10``'s in its order, then ``full``'s
    others): what a segment named before its subject's layout is known may be."""
    from limbstream.body import LAYOUTS  # (the body package is built on this module)
    return tuple(dict.fromkeys(name for layout in LAYOUTS.values() for name in layout.segment_names))


REST_POSES: tuple[str, ...] = ("standing", "tpose")
"""What identity segment orientations mean, the body's **rest pose**: ``standing`` (arms hanging
along -Y: the built-in generator, IMU recordings, BVH files whose zero pose hangs the arms) or
``tpose`` (arms out along +-X: most BVH files, and files converted from them). Every motion source knows its own; devices announce it in their
status, pose frames in their flags (docs/protocol.md, "Rest pose")."""
DEFAULT_REST_POSE = "standing"
"""The rest pose of data that does not say (a device status without the field)."""


def check_rest_pose(name: str) -> str:
    """``name`` if it is one of REST_POSES, else ValueError with the choices."""
    if name not in REST_POSES:
        raise ValueError(f"rest pose must be one of {', '.join(REST_POSES)}, got {name!r}")
    return name


ORIENTATIONS: tuple[str, ...] = ("segments", "rest", "sensors")
"""What a stream of orientations is (a motion's, ``sources.Motion.orientations``; a device's, its
status):

- ``segments``: the segments' own orientations in the skeleton's world (Y up): BVH clips, npz
  files, the generator, devices emulated without a sensor model; joint angles can be taken from
  them as they are.
- ``rest``: real sensors, each calibrated from the still rest pose its recording starts with in a
  world turned Y up: the segments up to the subject's facing, the one turn about the vertical a
  rest pose cannot tell (found from the hinges' motion, :mod:`limbstream.joints.functional`).
- ``sensors``: sensors' own readings, not calibrated (a sensor model, a real tracker, a recording
  that does not start still): nothing about the body can be taken from them before a calibration.
"""


@dataclass(frozen=True)
class Joint:
    """One joint: the segments it joins and the names and signs of its three Z-X-Y angles
    (None: not reported, e.g. a hinge's ad/abduction); the convention is
    :mod:`limbstream.joints.convention`'s."""

    name: str
    parent: str
    child: str
    angles: tuple[str | None, str | None, str | None]
    signs: tuple[float, float, float] = (1.0, 1.0, 1.0)
    frame: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    """The model's joint frame in both segments' anatomical frames, a scalar-first unit
    quaternion in OpenSim's axes (identity: the model's frames are the rest pose's; the wrists'
    are turned about the forearm, :mod:`limbstream.joints.convention`)."""


JOINT_TABLE: tuple[Joint, ...] = (
    Joint("hip_r", "hip", "r_thigh", ("hip_flexion_r", "hip_adduction_r", "hip_rotation_r")),
    Joint("knee_r", "r_thigh", "r_shank", ("knee_angle_r", None, None), (-1.0, 1.0, 1.0)),
    Joint("hip_l", "hip", "l_thigh", ("hip_flexion_l", "hip_adduction_l", "hip_rotation_l"), (1.0, -1.0, -1.0)),
    Joint("knee_l", "l_thigh", "l_shank", ("knee_angle_l", None, None), (-1.0, 1.0, 1.0)),
    Joint("shoulder_r", "hip", "r_upperarm", ("arm_flex_r", "arm_add_r", "arm_rot_r")),
    Joint("elbow_r", "r_upperarm", "r_lowerarm", ("elbow_flex_r", None, None)),
    Joint("shoulder_l", "hip", "l_upperarm", ("arm_flex_l", "arm_add_l", "arm_rot_l"), (1.0, -1.0, -1.0)),
    Joint("elbow_l", "l_upperarm", "l_lowerarm", ("elbow_flex_l", None, None)),
    Joint("neck", "hip", "neck", ("neck_extension", "neck_bending", "neck_rotation")),
)
"""The joints of the 10-segment body, in the order of their angles in :data:`JOINT_ANGLES`."""

JOINT_ANGLES: tuple[str, ...] = tuple(a for j in JOINT_TABLE for a in j.angles if a is not None)
"""The joint angles of the 10-segment body (OpenSim's Rajagopal model's names), in this order in
its angle vectors: joint-angle messages, ``limbstream.joints.ANGLES``, ``.mot`` files (degrees).
Other layouts: :func:`joint_angles`."""

_H = 0.5 ** 0.5
FULL_JOINT_TABLE: tuple[Joint, ...] = (
    JOINT_TABLE[0], JOINT_TABLE[1],
    Joint("ankle_r", "r_shank", "r_foot", ("ankle_angle_r", "subtalar_angle_r", None)),
    JOINT_TABLE[2], JOINT_TABLE[3],
    Joint("ankle_l", "l_shank", "l_foot", ("ankle_angle_l", "subtalar_angle_l", None), (1.0, -1.0, 1.0)),
    Joint("lumbar", "hip", "chest", ("lumbar_extension", "lumbar_bending", "lumbar_rotation")),
    Joint("shoulder_r", "chest", "r_upperarm", ("arm_flex_r", "arm_add_r", "arm_rot_r")),
    JOINT_TABLE[5],
    Joint("wrist_r", "r_lowerarm", "r_hand", ("wrist_flex_r", "wrist_dev_r", None), frame=(_H, 0.0, _H, 0.0)),
    Joint("shoulder_l", "chest", "l_upperarm", ("arm_flex_l", "arm_add_l", "arm_rot_l"), (1.0, -1.0, -1.0)),
    JOINT_TABLE[7],
    Joint("wrist_l", "l_lowerarm", "l_hand", ("wrist_flex_l", "wrist_dev_l", None), (1.0, -1.0, 1.0),
          frame=(_H, 0.0, -_H, 0.0)),
    Joint("neck", "chest", "head", ("neck_extension", "neck_bending", "neck_rotation")),
)
"""The joints of the ``full`` layout (15 segments), in the order of its angles: the Rajagopal
model's order (right leg, left leg, back, right arm, left arm), the neck last; hips, knees and
elbows as the 10-segment body's, the shoulders and the neck measured from the chest."""

JOINT_TABLES: dict[str, tuple[Joint, ...]] = {"paper10": JOINT_TABLE, "full": FULL_JOINT_TABLE}
"""The joints of each built-in layout (``limbstream.body.LAYOUTS``) by its name."""


def joints_among(segments, parent_of: dict[str, str | None] | None = None) -> tuple[Joint, ...]:
    """The joints among ``segments`` (names), by the rule every layout follows: in
    :data:`FULL_JOINT_TABLE` order, each joint of the built-in tables whose parent and child
    segments are both there, the first that is (``full``'s before the 10-segment body's: a
    shoulder is measured from the ``chest`` where there is one, else from the ``hip``); with
    ``parent_of`` (segment -> its parent, a layout's tree) a joint's parent must also be an
    ancestor of its child. ``full`` and ``paper10`` give their own tables back."""
    have = set(segments)

    def ancestor(parent: str, child: str) -> bool:
        if parent_of is None:
            return True
        at = parent_of.get(child)
        while at is not None and at != parent:
            at = parent_of.get(at)
        return at == parent

    out = []
    for joint in FULL_JOINT_TABLE:
        variants = [joint] + [j for j in JOINT_TABLE if j.name == joint.name and j != joint]
        out += [j for j in variants if j.parent in have and j.child in have and ancestor(j.parent, j.child)][:1]
    return tuple(out)


def joint_table(layout) -> tuple[Joint, ...]:
    """The joints of a layout, in the order of its angles: a built-in layout's name (its table,
    :data:`JOINT_TABLES`), a layout file's path, or a :class:`limbstream.body.Layout` (its
    segments' joints by :func:`joints_among`, their parents from its tree). ValueError for an
    unknown name (``limbstream.body.layout``'s)."""
    if isinstance(layout, str) and layout in JOINT_TABLES:
        return JOINT_TABLES[layout]
    if not hasattr(layout, "segments"):
        from limbstream.body import layout as load  # (the body package is built on this module)
        layout = load(layout)
    return joints_among([s.name for s in layout.segments], {s.name: s.parent for s in layout.segments})


def joint_angles(layout) -> tuple[str, ...]:
    """The joint angles of a layout (:func:`joint_table`'s joints), in this order in its angle
    vectors (degrees): ``paper10``'s are :data:`JOINT_ANGLES`."""
    return tuple(a for j in joint_table(layout) for a in j.angles if a is not None)


MAX_LAYOUT_BYTES = 16_384
"""The most a layout file's table may take in a status's ``"body"`` (its compact JSON, bytes): a
layout of 64 joints (the C chain's limit) takes about 11 kB, ``examples/layouts/suit17.toml`` 2.8 kB."""


def encode_body(body) -> dict:
    """A wearer's dimensions as a device status carries them (``"body"``, docs/protocol.md "Body
    dimensions"): ``{"layout": name or table, "height_m": m or null, "bones": {bone: m, or [x, y, z]
    m in the standing frame where it lies off its rest direction}}``. ``body``: a
    :class:`limbstream.body.Body`; a built-in layout travels as its name, another (a layout file's)
    as its table (``Layout.to_dict``, the form a layout file holds)."""
    from limbstream.body import LAYOUTS  # (the body package is built on this module)
    table = body.to_dict()
    table.pop("layout")
    lay = body.layout
    named = LAYOUTS.get(lay.name) == lay
    return {"layout": lay.name if named else lay.to_dict(), "height_m": body.height_m, "bones": table}


@functools.lru_cache(maxsize=64)
def _layout_of_table(text: str):
    """The layout of a status's layout table (its compact JSON text: each device says it again every
    poll, so it is checked once)."""
    from limbstream.body import LAYOUTS, layout_from_dict  # (the body package is built on this module)
    lay = layout_from_dict(json.loads(text), "body layout")
    if lay.name in LAYOUTS:
        raise ValueError(f"body layout: a table named {lay.name!r}, a built-in layout's name (which travels alone)")
    return lay


def body_layout(value):
    """The :class:`limbstream.body.Layout` of a status body's ``"layout"``: a built-in's name, or a
    layout file's table (at most :data:`MAX_LAYOUT_BYTES`, checked as a layout file is: a cycle, a
    missing parent, a duplicate segment, ... refused by name); ValueError naming the problem."""
    from limbstream.body import builtin_layout  # (the body package is built on this module)
    if isinstance(value, str):
        return builtin_layout(value)
    if not isinstance(value, dict):
        raise ValueError(f"body layout must be a built-in's name or a layout table, got {str(value)[:80]!r}")
    text = json.dumps(value, separators=(",", ":"), sort_keys=True)
    if len(text) > MAX_LAYOUT_BYTES:
        raise ValueError(f"body layout table of {len(text)} bytes, at most {MAX_LAYOUT_BYTES}")
    return _layout_of_table(text)


def decode_body(data):
    """The :class:`limbstream.body.Body` of a status's ``"body"`` entry (:func:`encode_body`);
    ValueError naming the problem (not an object, an unknown key or layout, a bad layout table, a
    bone missing, unknown or out of bounds, a height out of bounds). The bounds and the checks are
    the body's own (:mod:`limbstream.body.dimensions`) and a layout file's
    (:func:`limbstream.body.layout_from_dict`)."""
    from limbstream.body import Body  # (the body package is built on this module)
    if not isinstance(data, dict) or set(data) - {"layout", "height_m", "bones"} or "bones" not in data:
        raise ValueError(f"body must be an object of layout, height_m and bones, got {str(data)[:80]!r}")
    bones = data["bones"]
    if not isinstance(bones, dict):
        raise ValueError(f"body bones must be an object of bone -> metres, got {str(bones)[:80]!r}")
    return Body(body_layout(data.get("layout", "paper10")), bones, height_m=data.get("height_m"))
