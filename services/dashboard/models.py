"""Typed request and response bodies of the dashboard API."""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator

PoseKind = Literal["auto", "live", "exact"]


class DeviceStats(BaseModel):
    """One device: the stats fields of the wire contract (null until the aggregator reports),
    plus ``subject``, ``alive`` (liveliness token present), ``age_s`` and ``stale``.
    Extra fields the aggregator sends (e.g. ``max_len``) pass through."""

    model_config = ConfigDict(extra="allow")

    device: str = Field(examples=["s0/l_thigh"])
    segment: str
    subject: str
    online: bool
    alive: bool
    stale: bool
    age_s: float | None = Field(None, description="seconds since the last stats message")
    samples: int | None = None
    points: int | None = None
    icr: float | None = Field(None, description="segment points / samples (0..1)")
    msgs_per_s: float | None = None
    bytes_per_s: float | None = None
    aad_deg: float | None = None
    p99_deg: float | None = None
    max_deg: float | None = None
    live_err_deg: float | None = None
    watermark_lag_s: float | None = None
    gaps: int | None = None
    dropped: int | None = None
    threshold: float | None = None


class DeviceHistory(BaseModel):
    """Column-wise time series of one device (one row per stats message, ~1 Hz)."""

    device: str
    t: list[float] = Field(description="stats time, seconds since the epoch")
    msgs_per_s: list[float | None]
    bytes_per_s: list[float | None]
    icr: list[float | None]
    aad_deg: list[float | None]
    p99_deg: list[float | None]
    max_deg: list[float | None]
    live_err_deg: list[float | None]
    watermark_lag_s: list[float | None]


class PoseSummary(BaseModel):
    seq: int
    t: float
    kind: Literal["live", "exact"]
    age_s: float


class Subject(BaseModel):
    subject: str
    devices: int
    online: int
    msgs_per_s: float
    bytes_per_s: float
    stats_age_s: float | None
    pose: PoseSummary | None


class Pose(BaseModel):
    """A pose frame (:meth:`limbstream.wire.PoseFrame.to_json`) plus ``rx``, the time the
    service received it (s, epoch)."""

    subject: str
    seq: int
    t: float
    kind: Literal["live", "exact"]
    gap: bool
    missing: bool
    segments: dict[str, list[float]]
    joints: dict[str, list[float]]
    rx: float


class Skeleton(BaseModel):
    joints: list[str] = Field(description="joint names, in the order of pose frames")
    bones: list[Annotated[list[str], Field(min_length=2, max_length=2)]] = Field(
        description="pairs of joints to draw a line between")


def _whole(value):
    """JSON integers may be written 25.0; booleans and fractions are not integers."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


class ConfigUpdate(BaseModel):
    """New device settings; a field left out keeps the device's current value."""

    model_config = ConfigDict(extra="forbid", strict=True, json_schema_extra={"minProperties": 1})

    threshold: float = Field(None, ge=0, le=1e6, allow_inf_nan=False,
                             description="SSR threshold of the fastSW kernel (>= 0)")
    max_len: Annotated[int, BeforeValidator(_whole)] = Field(None, ge=1, le=100_000,
                                                               description="max segment length, samples")

    @model_validator(mode="after")
    def _something(self) -> ConfigUpdate:
        if self.threshold is None and self.max_len is None:
            raise ValueError("give threshold and/or max_len")
        return self


class DeviceConfig(BaseModel):
    """The config a device confirmed (status fields the device adds pass through)."""

    model_config = ConfigDict(extra="allow")

    device: str
    threshold: float
    max_len: int


class Aggregator(BaseModel):
    """One aggregator's own loop, as it reported it with its last stats message (~1 Hz).
    Figures are null if the aggregator did not send them."""

    id: str = Field(description="host:pid of the aggregator process", examples=["lab-pc:4242"])
    serving: list[str] = Field(description="subjects whose stats it sent")
    subjects: float | None = Field(None, description="subjects it tracks")
    ticks: float | None = Field(None, description="loop ticks (one per 20 ms)")
    late: float | None = Field(None, description="ticks that started more than one period late")
    late_pct: float | None = Field(None, description="late / ticks, %")
    load: float | None = Field(None, description="share of the last second spent working (>= 1: falling behind)")
    max_tick_ms: float | None = Field(None, description="longest tick since start, ms")
    recent_max_tick_ms: float | None = Field(None, description="longest tick in the last second, ms")
    recent_backlog: float | None = Field(None, description="most messages waiting at one tick, last second")
    max_backlog: float | None = None
    missed: float | None = Field(None, description="segment points Zenoh reported lost for good")
    points: float | None = None
    frames: float | None = None
    bad_keys: dict[str, float] = Field(description="messages no device could be charged with, by reason")
    age_s: float
    stale: bool


class Health(BaseModel):
    status: Literal["ok", "starting"]
    zenoh: bool
    subjects: int
    devices: int
    uptime_s: float
    control: bool = Field(description="whether device control is enabled (an API token is set)")
