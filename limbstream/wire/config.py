"""Device settings: each tunable with its default and bounds, written once, and the config /
status messages of a device's queryable (``limbstream/<subject>/<segment>/config``).

The command line (:mod:`limbstream.cli.flags`), the queryable (:func:`decode_config`), the dashboard's
REST model and the kernel binding all check a value with :meth:`Tunable.check`, so a bad value
gets the same refusal on every path. (The C kernel keeps its own defined behaviour for values
outside these bounds: firmware_c/include/fastsw.h.)

Query protocol: a ``get`` with no payload reads the device's status; a payload is a JSON object
with some of the tunables (``{"threshold": 0.001}``): the device applies them (the others keep
their value) and answers with its status, or answers with an error reply
``{"error": "<reason>"}`` and changes nothing.
"""
from __future__ import annotations

import json
import math
import numbers
from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING

from .body import DEFAULT_REST_POSE, ORIENTATIONS, check_rest_pose, decode_body, encode_body
from .errors import WireError

if TYPE_CHECKING:
    from limbstream.body import Body

DEVICE_RATE_HZ = 50.0
"""A device's sample rate unless it is told another (every device, gateway grid and aggregator
frame rate defaults to it), Hz."""


@dataclass(frozen=True)
class Tunable:
    """One device setting.

    Attributes
    ----------
    name : JSON key and DeviceConfig attribute (the CLI flag is ``--`` + name with ``-``).
    type : ``float`` or ``int``.
    default : value of a new device.
    low, high : inclusive bounds.
    unit : unit, empty when it has none.
    help : one line for people.
    """

    name: str
    type: type
    default: float | int
    low: float | int
    high: float | int
    unit: str
    help: str

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    def describe(self) -> str:
        """'an integer in 1..100000' / 'a number in 0..1e+06'."""
        kind = "an integer" if self.type is int else "a number"
        return f"{kind} in {self.low:g}..{self.high:g}"

    def check(self, value):
        """``value`` as this tunable's type if it is one within bounds, else ValueError naming
        the tunable. JSON-style: booleans and strings are refused; 25.0 is an integer."""
        try:
            ok = (isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
                  and self.low <= value <= self.high and (self.type is float or float(value).is_integer()))
        except OverflowError:  # an integer beyond float range
            ok = False
        if not ok:
            raise ValueError(f"{self.name} must be {self.describe()}, got {value!r}")
        return self.type(value)

THRESHOLD = Tunable("threshold", float, 1e-2, 0.0, 1e6, "",
                    "fastSW SSR threshold: largest sum of squared residuals of a segment")
MAX_LEN = Tunable("max_len", int, 25, 1, 100_000, "samples",
                  "max segment length (a still limb still sends a point this often)")
LIVE_BOUND_DEG = Tunable("live_bound_deg", float, 0.0, 0.0, 180.0, "deg",
                         "fastSW live rule: largest angle between a sample and the receiver's prediction "
                         "from the points it has (0 or 180: off)")
TUNABLES: dict[str, Tunable] = {t.name: t for t in (THRESHOLD, MAX_LEN, LIVE_BOUND_DEG)}
"""Every device setting, by name (DeviceConfig has one attribute per entry)."""

LIVE_MODE: dict[str, float] = {"live_bound_deg": 5.0, "threshold": 9e-4}
"""The settings ``limbstream up`` and the compose deployment give devices (the other entry points
keep the plain fastSW defaults above): the live rule on at 5 degrees and a tighter SSR threshold.
Chosen from the live frontier (docs/evaluation.md, "Live mode"): on CMU at max_len 25 this is
ICR 0.2085, exact AAD 0.80 deg and every live sample within 5 deg; with the live rule on, the
tighter threshold costs few points (generator motion: ICR 0.123 -> 0.135) and cuts the exact
error by 40 % (1.09 -> 0.67 deg)."""


@dataclass(frozen=True)
class DeviceConfig:
    """Settings a device applies (one attribute per :data:`TUNABLES` entry)."""

    threshold: float = THRESHOLD.default
    max_len: int = int(MAX_LEN.default)
    live_bound_deg: float = LIVE_BOUND_DEG.default

    def validate(self) -> DeviceConfig:
        """Self, with every value checked (ValueError naming the first bad one)."""
        return DeviceConfig(**{f.name: TUNABLES[f.name].check(getattr(self, f.name)) for f in fields(self)})

    def as_dict(self) -> dict:
        """{tunable: value} in :data:`TUNABLES`' order (a status carries it for every device it
        reports: read directly, not through ``dataclasses.asdict``'s deep copy)."""
        return {name: getattr(self, name) for name in TUNABLES}

    def flags(self) -> list[str]:
        """The command-line flags that give this config (``["--threshold", "0.01", ...]``)."""
        return [a for name, t in TUNABLES.items() for a in (t.flag, str(getattr(self, name)))]


def encode_config(update: DeviceConfig | dict) -> bytes:
    """A config query payload: a whole DeviceConfig or a dict with some tunables."""
    values = update.as_dict() if isinstance(update, DeviceConfig) else dict(update)
    return json.dumps(values).encode()


def decode_config(payload: bytes, current: DeviceConfig | None = None) -> DeviceConfig:
    """JSON object of tunables -> validated DeviceConfig; WireError('config') naming the problem.

    Fields left out keep their value in ``current`` (the device's settings); without
    ``current`` every tunable must be given."""
    try:
        data = json.loads(bytes(payload))
    except (ValueError, RecursionError) as exc:  # RecursionError: absurdly deep nesting
        raise WireError("config", f"device config is not JSON: {exc}") from None
    if not isinstance(data, dict) or not data:
        raise WireError("config", f"device config must be a JSON object with some of {sorted(TUNABLES)}")
    unknown = set(data) - set(TUNABLES)
    if unknown:
        raise WireError("config", f"unknown device config fields {sorted(unknown)}")
    if current is None and set(data) != set(TUNABLES):
        raise WireError("config", f"device config needs {sorted(TUNABLES)}")
    try:
        values = {name: TUNABLES[name].check(value) for name, value in data.items()}
    except ValueError as exc:
        raise WireError("config", str(exc)) from None
    return replace(current or DeviceConfig(), **values)


@dataclass(frozen=True)
class DeviceStatus:
    """A device's answer to a config query: its settings and its own counters.

    Attributes
    ----------
    device : ``<subject>/<segment>``.
    config : the settings it runs.
    stream : its stream id.
    samples : samples taken in this stream.
    points : segment points sent in this stream.
    clock : its clock synchronisation (:class:`ClockStatus`), None if it does not report one.
    rest_pose : what identity orientations of its data mean (wire.REST_POSES).
    link : the link of a device bridged in by a gateway (:class:`LinkStatus`), None for others.
    fusion : the fusion filter of a device that fuses raw IMU samples (:class:`FusionStatus`),
        None for others.
    orientations : what its orientations are (wire.ORIENTATIONS: its segment's own, rest-calibrated
        or its sensor's reading); None: it does not say (a reader takes them as a sensor's).
    body : its wearer's dimensions (:class:`limbstream.body.Body`), None: not said (the default adult).
    body_error : why the ``"body"`` a status carried was refused (:func:`decode_status` reads the
        rest of such a status; None: none refused).
    """

    device: str
    config: DeviceConfig
    stream: int
    samples: int
    points: int
    clock: ClockStatus | None = None
    rest_pose: str = DEFAULT_REST_POSE
    link: LinkStatus | None = None
    fusion: FusionStatus | None = None
    orientations: str | None = None
    body: Body | None = None
    body_error: str | None = None

    def as_dict(self) -> dict:
        clock = {} if self.clock is None else self.clock.as_dict()
        link = {} if self.link is None else self.link.as_dict()
        fusion = {} if self.fusion is None else self.fusion.as_dict()
        said = {} if self.orientations is None else {"orientations": self.orientations}
        body = {} if self.body is None else {"body": encode_body(self.body)}
        return {"device": self.device, **self.config.as_dict(), "stream": self.stream,
                "samples": self.samples, "points": self.points, **clock, "rest_pose": self.rest_pose, **link,
                **fusion, **said, **body}


FUSION_MODES: tuple[str, ...] = ("6D", "9D")
"""A device's fusion: 6D (gyroscope and accelerometer) or 9D (and magnetometer)."""


@dataclass(frozen=True)
class FusionStatus:
    """The fusion filter of a device fed raw IMU samples (part of its status; optional: a status
    without ``fusion`` has none). docs/kernel.md, "Raw samples: VQF on the device".

    Attributes
    ----------
    fusion : ``"6D"`` or ``"9D"`` (:data:`FUSION_MODES`).
    gyro_bias_dps : (3,) the filter's current gyroscope bias estimate, deg/s, sensor frame.
    at_rest : the filter detects rest.
    raw_faults : bad raw samples counted since the filter started, by kind (invalid, time_back,
        gap, saturated, gyr_stuck).
    """

    fusion: str
    gyro_bias_dps: tuple[float, float, float]
    at_rest: bool
    raw_faults: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"fusion": self.fusion, "gyro_bias_dps": list(self.gyro_bias_dps), "at_rest": self.at_rest,
                "raw_faults": dict(self.raw_faults)}


@dataclass(frozen=True)
class LinkStatus:
    """The link between a gateway and the real device it bridges in (part of the device's status;
    optional: a status without ``tracker`` has none).

    Attributes
    ----------
    tracker : the device behind the gateway (SlimeVR: ``<MAC or ip:port>/<sensor id>``).
    battery_pct : its battery level, % (None: not reported).
    signal_dbm : its radio signal strength, dBm (None: not reported).
    link_loss : fraction of its packets lost on the way to the gateway (from their numbers).
    link_pps : packets per second the gateway receives from it.
    """

    tracker: str
    battery_pct: float | None = None
    signal_dbm: float | None = None
    link_loss: float | None = None
    link_pps: float | None = None

    def as_dict(self) -> dict:
        return {"tracker": self.tracker, "battery_pct": self.battery_pct, "signal_dbm": self.signal_dbm,
                "link_loss": self.link_loss, "link_pps": self.link_pps}


@dataclass(frozen=True)
class ClockStatus:
    """A device's view of its clock synchronisation (part of its status).

    Attributes
    ----------
    clock_offset_ms : its clock minus the common time base as it estimates it, ms (None: no
        estimate yet, or sync off).
    sync_rtt_ms : round trip of its last valid time exchange, ms (None: none yet).
    synced : it stamps on the common time base (a valid answer within its holdover).
    sync_bad : time answers it discarded, by reason.
    """

    clock_offset_ms: float | None = None
    sync_rtt_ms: float | None = None
    synced: bool = False
    sync_bad: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"clock_offset_ms": self.clock_offset_ms, "sync_rtt_ms": self.sync_rtt_ms, "synced": self.synced,
                "sync_bad": dict(self.sync_bad)}


def encode_status(status: DeviceStatus) -> bytes:
    """``{"device", <tunables>..., "stream", "samples", "points"[, <ClockStatus fields>]}``."""
    return json.dumps(status.as_dict()).encode()


def _clock(data: dict) -> ClockStatus | None:
    """The ClockStatus fields of a status reply (None if it has none); TypeError if one is bad."""
    if "synced" not in data:
        return None
    offset, rtt, synced, bad = (data.get(k) for k in ("clock_offset_ms", "sync_rtt_ms", "synced", "sync_bad"))
    for name, v in (("clock_offset_ms", offset), ("sync_rtt_ms", rtt)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            raise TypeError(f"{name} must be a finite number or null, got {v!r}")
    bad = {} if bad is None else bad
    if not isinstance(synced, bool) or not isinstance(bad, dict) or not all(
            isinstance(k, str) and isinstance(n, int) and not isinstance(n, bool) for k, n in bad.items()):
        raise TypeError("synced must be a boolean and sync_bad an object of counts")
    return ClockStatus(offset, rtt, synced, bad)


def _link(data: dict) -> LinkStatus | None:
    """The LinkStatus fields of a status reply (None if it has none); TypeError if one is bad."""
    if "tracker" not in data:
        return None
    if not isinstance(data["tracker"], str):
        raise TypeError(f"tracker must be a string, got {data['tracker']!r}")
    values = [data.get(k) for k in ("battery_pct", "signal_dbm", "link_loss", "link_pps")]
    for v in values:
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            raise TypeError(f"link figures must be finite numbers or null, got {v!r}")
    return LinkStatus(data["tracker"], *values)


def _fusion(data: dict) -> FusionStatus | None:
    """The FusionStatus fields of a status reply (None if it has none); TypeError if one is bad."""
    if "fusion" not in data:
        return None
    mode, bias, rest, faults = (data.get(k) for k in ("fusion", "gyro_bias_dps", "at_rest", "raw_faults"))
    if mode not in FUSION_MODES or not isinstance(rest, bool):
        raise TypeError(f"fusion must be one of {FUSION_MODES} and at_rest a boolean, got {mode!r}, {rest!r}")
    if not (isinstance(bias, list) and len(bias) == 3 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in bias)):
        raise TypeError(f"gyro_bias_dps must be 3 finite numbers, got {bias!r}")
    faults = {} if faults is None else faults
    if not isinstance(faults, dict) or not all(
            isinstance(k, str) and isinstance(n, int) and not isinstance(n, bool) for k, n in faults.items()):
        raise TypeError("raw_faults must be an object of counts")
    return FusionStatus(mode, (float(bias[0]), float(bias[1]), float(bias[2])), rest, faults)


def _body(data: dict) -> tuple[Body | None, str | None]:
    """(the body of a status reply or None, why its ``"body"`` was refused or None)."""
    if "body" not in data:
        return None, None
    try:
        return decode_body(data["body"]), None
    except ValueError as exc:
        return None, str(exc).splitlines()[0] if str(exc) else "bad body"


def decode_status(payload: bytes) -> DeviceStatus:
    """A config reply -> DeviceStatus; WireError('status') if it is not one. A malformed
    ``"body"`` does not refuse the status: it is read without it, the reason in ``body_error``."""
    try:
        data = json.loads(bytes(payload))
        if not isinstance(data, dict):
            raise TypeError("a device status must be an object")
        config = DeviceConfig(**{name: TUNABLES[name].check(data[name]) for name in TUNABLES})
        stream, samples, points = (data[k] for k in ("stream", "samples", "points"))
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (stream, samples, points)):
            raise TypeError(f"stream, samples and points must be integers, got {[stream, samples, points]}")
        orientations = data.get("orientations")
        body, body_error = _body(data)
        if orientations is not None and orientations not in ORIENTATIONS:
            raise ValueError(f"orientations must be one of {', '.join(ORIENTATIONS)}, got {orientations!r}")
        return DeviceStatus(str(data["device"]), config, stream, samples, points, clock=_clock(data),
                            rest_pose=check_rest_pose(data.get("rest_pose", DEFAULT_REST_POSE)), link=_link(data),
                            fusion=_fusion(data), orientations=orientations, body=body, body_error=body_error)
    except (ValueError, KeyError, TypeError, RecursionError) as exc:
        raise WireError("status", f"bad device status: {exc}") from None
