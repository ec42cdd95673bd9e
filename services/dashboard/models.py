"""Typed request and response bodies of the dashboard API."""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, create_model, model_validator

from limbstream import wire

PoseKind = Literal["auto", "live", "exact"]
AngleName = Literal[tuple(dict.fromkeys(a for name in wire.JOINT_TABLES for a in wire.joint_angles(name)))]  # type: ignore[valid-type]


def _described(f: wire.StatsField):
    unit = f" ({f.unit})" if f.unit else ""
    return Field(None, description=f"{f.help}{unit}")


def _from_fields(name: str, doc: str, fields: tuple[wire.StatsField, ...], wrap=lambda t: t, **extra) -> type:
    """A response model with one optional attribute per stats field (``wrap``: of its type)."""
    attributes = {f.name: (wrap(f.type if f.type is not dict else dict[str, float]) | None, _described(f))
                  for f in fields}
    return create_model(name, __doc__=doc, **extra, **attributes)


DeviceStats = _from_fields(
    "DeviceStats", "One device: the device fields of the stats contract (limbstream.wire.fields; null "
    "until the aggregator reports), plus ``alive`` (liveliness token present), ``age_s`` and ``stale``.",
    wire.DEVICE_FIELDS,
    alive=(bool, Field(description="liveliness token present")),
    stale=(bool, Field(description="no stats for longer than the stale limit")),
    age_s=(float | None, Field(None, description="seconds since the last stats message")),
)

DeviceHistory = _from_fields(
    "DeviceHistory", "Column-wise time series of one device (one row per stats message, ~1 Hz).",
    tuple(f for f in wire.DEVICE_FIELDS if f.chart), wrap=lambda t: list[t | None],
    device=(str, ...), t=(list[float], Field(description="stats time, seconds since the epoch")),
)


class PoseSummary(BaseModel):
    seq: int
    t: float
    kind: Literal["live", "exact"]
    age_s: float


class _SubjectSummary(BaseModel):
    subject: str
    devices: int
    online: int
    msgs_per_s: float
    bytes_per_s: float
    stats_age_s: float | None
    pose: PoseSummary | None
    pose_refused: str | None = Field(None, description="why the subject's latest refused pose frame could not be "
                                     "read (a layout file's frames before its devices said their layout, or of "
                                     "devices that say none)")
    exact_latency_p50_ms: float | None = Field(
        None, description="median exact-frame latency: the time this service received each of the subject's last "
        "500 exact frames minus the frame's time (device time; same clock and --speed 1 assumed), ms")
    exact_latency_p99_ms: float | None = Field(None, description="99th percentile of that latency, ms")


Subject = _from_fields(
    "Subject", "One subject: its devices and latest pose, plus the subject fields of the stats contract "
    "(limbstream.wire.fields; null until the aggregator reports).", wire.SUBJECT_FIELDS, __base__=_SubjectSummary)

SubjectDetail = create_model(
    "SubjectDetail", __base__=Subject, __doc__="One subject, as in the list, with its devices.",
    device_list=(list[DeviceStats], Field(description="the subject's devices, by id (as GET /api/devices)")),
    missing_segments=(list[str], Field(description="the layout's segments the subject has no device for "
                                                   "(their orientations follow their parent's)")),
    segments=(list[str], Field(description="the layout's segments, in the order of a frame's orientations")),
    joints=(list[str], Field(description="the layout's joints, in the order of a frame's positions")),
    bones=(list[Annotated[list[str], Field(min_length=2, max_length=2)]],
           Field(description="the layout's bones: pairs of joints (proximal, distal) to draw a line between")),
)


class Pose(BaseModel):
    """A pose frame (:meth:`limbstream.wire.PoseFrame.to_json`) plus ``rx``, the time the
    service received it (s, epoch)."""

    subject: str
    seq: int
    t: float
    kind: Literal["live", "exact"]
    gap: bool
    missing: bool
    rest_pose: Literal[tuple(wire.REST_POSES)] = Field(  # type: ignore[valid-type]
        description="what identity segment orientations mean (the frame's TPOSE flag; docs/protocol.md 'Rest pose')")
    layout: str = Field(description="the subject's body layout (docs/body.md): the names of segments and joints")
    segments: dict[str, list[float]] = Field(description="segment orientations (w, x, y, z) by name, device order")
    joints: dict[str, list[float]] = Field(description="joint positions, m, Y up, by name")
    root: list[float] = Field(description="the root (pelvis) position, m, world frame (zeros: not tracked)")
    contacts: list[str] = Field(description="the foot points planted on the floor")
    rx: float


class JointAngles(BaseModel):
    """One joint-angle message (:meth:`limbstream.wire.JointAngles.to_json`) plus ``rx``, the time
    the service received it (s, epoch)."""

    subject: str
    seq: int = Field(description="the pose frame's sequence number (per subject and kind)")
    t: float = Field(description="the pose frame's time, s since the epoch (device time)")
    kind: Literal["live", "exact"]
    calibration: Literal[tuple(b.name for b in wire.ANGLE_BASES)] = Field(  # type: ignore[valid-type]
        description="the calibration the angles rest on (docs/protocol.md, 'Joint angles')")
    valid: bool = Field(description="whether that calibration gives anatomical angles")
    why: str | None = Field(description="why there are no angles (null: there are)")
    facing_deg: float | None = Field(description="the subject's facing the knees and elbows told (functional), deg")
    angles: dict[str, float | None] = Field(description="degrees by angle name; null: none (see flags)")
    flags: dict[str, list[Literal[tuple(wire.ANGLE_FLAGS)]]] = Field(  # type: ignore[valid-type]
        description="the flags of each flagged angle: missing (a segment has no data), gimbal (near gimbal lock), "
                    "uncalibrated")
    rx: float


class SubjectJoints(BaseModel):
    """A subject's newest joint angles and the last seconds of them, column-wise."""

    subject: str
    kind: Literal["live", "exact"] = Field(description="the pose frames they come from")
    names: list[str] = Field(description="the angles of ``angles``, in the contract's order")
    latest: JointAngles
    t: list[float] = Field(description="each message's frame time, s since the epoch (device time)")
    seq: list[int]
    angles: dict[str, list[float | None]] = Field(description="each angle's values, deg (null: none)")


class Skeleton(BaseModel):
    """How to draw a layout's frames (:func:`~.views.layout_view`)."""

    layout: str = Field(description="the layout's name")
    segments: list[str] = Field(description="segment names, in the order of a frame's orientations")
    joints: list[str] = Field(description="joint names, in the order of pose frames")
    bones: list[Annotated[list[str], Field(min_length=2, max_length=2)]] = Field(
        description="pairs of joints to draw a line between")


def _tunable(t: wire.Tunable):
    """An optional body field checked by the tunable itself (the same refusal as the CLI and the
    device's queryable give)."""
    unit = f", {t.unit}" if t.unit else ""
    return (Annotated[t.type, BeforeValidator(t.check)],
            Field(None, ge=t.low, le=t.high, description=f"{t.help}{unit} ({t.describe()})"))


class _Update(BaseModel):
    model_config = ConfigDict(extra="forbid", json_schema_extra={"minProperties": 1})

    @model_validator(mode="after")
    def _something(self):
        if not self.model_fields_set:
            raise ValueError(f"give some of {', '.join(wire.TUNABLES)}")
        return self

    def update(self) -> dict:
        """The fields the client gave (a partial config for the device)."""
        return {name: getattr(self, name) for name in self.model_fields_set}


ConfigUpdate = create_model(
    "ConfigUpdate", __base__=_Update, __doc__="New device settings; a field left out keeps the device's value.",
    **{name: _tunable(t) for name, t in wire.TUNABLES.items()},
)

class Tunable(BaseModel):
    """A device setting as the contract declares it (limbstream.wire.TUNABLES)."""

    name: str = Field(examples=["threshold"])
    type: Literal["float", "int"]
    default: float
    low: float = Field(description="smallest value accepted")
    high: float = Field(description="largest value accepted")
    unit: str
    help: str


DeviceConfig = create_model(
    "DeviceConfig", __doc__="The settings and counters a device confirmed (its status).",
    device=(str, ...), stream=(int, ...), samples=(int, ...), points=(int, ...),
    **{name: (t.type, Field(description=t.help)) for name, t in wire.TUNABLES.items()},
)


Aggregator = _from_fields(
    "Aggregator", "One aggregator's own loop, as it reported it with its last stats message (~1 Hz). "
    "Figures are null if the aggregator did not send them.",
    wire.AGGREGATOR_FIGURES, wrap=lambda t: float,
    id=(str, Field(description="host:pid of the aggregator process", examples=["lab-pc:4242"])),
    serving=(list[str], Field(description="subjects whose stats it sent")),
    late_pct=(float | None, Field(None, description="late / ticks, %")),
    bad_keys=(dict[str, float], Field(description="messages no device could be charged with, by reason")),
    age_s=(float, ...),
    stale=(bool, ...),
)


class Health(BaseModel):
    status: Literal["ok", "starting"]
    zenoh: bool
    subjects: int
    devices: int
    uptime_s: float
    control: bool = Field(description="whether device control is enabled (an API token is set)")


class CalibrateRequest(BaseModel):
    """A calibration of a subject's devices from the pose it holds now (limbstream.wire.calibrate)."""

    model_config = ConfigDict(extra="forbid")
    pose: Literal[wire.CALIBRATION_POSES] = Field(
        description="rest: full reset in the rest pose; mounting: the mounting pose, after rest; yaw: heading "
                    "only, in the rest pose")


class CalibrateResult(BaseModel):
    """The calibration made: per device id its poses and heading estimate (degrees)."""

    subject: str
    pose: str
    devices: dict[str, dict]
    absent: list[str] = Field(description="the body's segments without a streaming device (not calibrated)")


class GatewaySensor(BaseModel):
    """One sensor a gateway has heard of (limbstream.wire.gateway)."""

    tracker: str = Field(description="its tracker: MAC, or ip:port without one", examples=["AA:BB:CC:DD:EE:01"])
    sensor: int = Field(description="sensor id on the tracker")
    online: bool = Field(description="its tracker is sending")
    position: int | None = Field(description="the body position the tracker reports for it (SlimeVR's ids)")
    device: str | None = Field(description="the device it feeds, <subject>/<segment>; null: none")
    why: str | None = Field(description="why it feeds no device")


class Gateway(BaseModel):
    """A gateway and its sensors."""

    gateway: str = Field(description="its name (limbstream/@gateway/<name>)")
    subject: str = Field(description="subject of the sensors it places by body position")
    sensors: list[GatewaySensor]
    segments: list[str] = Field(description="the segments a sensor can feed")


class AssignRequest(BaseModel):
    """Move a gateway's sensor to a device, or to none (``segment`` null)."""

    model_config = ConfigDict(extra="forbid")
    tracker: str = Field(min_length=1, max_length=64, description="the sensor's tracker (as listed)",
                         examples=["AA:BB:CC:DD:EE:01"])
    sensor: int = Field(ge=0, le=255, description="sensor id on the tracker")
    subject: str | None = Field(None, pattern=wire.CHUNK_PATTERN, max_length=128,
                                description="subject of the device; null: the gateway's subject")
    segment: Literal[wire.SEGMENTS] | None = Field(description="segment of the device; null: feed none")
