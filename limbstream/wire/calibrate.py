"""Calibration requests: a client asks the aggregator serving a subject to calibrate its devices
from the pose the subject holds now (docs/protocol.md, "Calibration"). JSON both ways, on the
subject's ``calibrate`` queryable (:func:`~.keys.calibrate_key`)."""
from __future__ import annotations

import json
from dataclasses import dataclass, field

from .errors import WireError

CALIBRATION_POSES: tuple[str, ...] = ("rest", "mounting", "yaw")
"""rest: full reset (the rest pose); mounting: the mounting pose, after a rest; yaw: heading only,
in the rest pose (limbstream.calibration)."""

CALIBRATION_HOLD_S = 1.0
"""The subject holds the pose this long from the request on (device time): the still window."""

CALIBRATION_ANSWER_TIMEOUT_S = CALIBRATION_HOLD_S + 8.0
"""How long a client waits for the aggregator's answer to a request, s (the hold, the points'
way to the aggregator, and its own wait for them)."""


def encode_calibrate_request(pose: str) -> bytes:
    if pose not in CALIBRATION_POSES:
        raise ValueError(f"pose must be one of {', '.join(CALIBRATION_POSES)}, got {pose!r}")
    return json.dumps({"pose": pose}).encode()


def decode_calibrate_request(payload: bytes) -> str:
    """The pose asked for; WireError('calibrate') naming the problem."""
    try:
        data = json.loads(bytes(payload))
    except (ValueError, RecursionError) as exc:
        raise WireError("calibrate", f"calibration request is not JSON: {exc}") from None
    pose = data.get("pose") if isinstance(data, dict) else None
    if pose not in CALIBRATION_POSES:
        raise WireError("calibrate", f"calibration request needs pose one of {', '.join(CALIBRATION_POSES)}, "
                        f"got {pose!r}")
    return pose


@dataclass(frozen=True)
class CalibrateAnswer:
    """The aggregator's answer: ``ok``, else ``reason`` (one sentence); ``devices``: per device id
    its calibration's poses and heading estimate (degrees); ``absent``: the body's segments the
    subject has no streaming device for (a partial body: they were not calibrated)."""

    ok: bool
    reason: str | None = None
    devices: dict[str, dict] = field(default_factory=dict)
    absent: list[str] = field(default_factory=list)


def encode_calibrate_answer(answer: CalibrateAnswer) -> bytes:
    return json.dumps({"ok": answer.ok, "reason": answer.reason, "devices": answer.devices,
                       "absent": answer.absent}).encode()


def decode_calibrate_answer(payload: bytes) -> CalibrateAnswer:
    try:
        data = json.loads(bytes(payload))
        if not isinstance(data, dict) or not isinstance(data.get("ok"), bool):
            raise ValueError("needs a boolean 'ok'")
        reason, devices, absent = data.get("reason"), data.get("devices") or {}, data.get("absent") or []
        if not (reason is None or isinstance(reason, str)) or not isinstance(devices, dict):
            raise ValueError("'reason' must be a string or null, 'devices' an object")
        if not (isinstance(absent, list) and all(isinstance(s, str) for s in absent)):
            raise ValueError("'absent' must be a list of segment names")
        return CalibrateAnswer(data["ok"], reason, devices, absent)
    except (ValueError, RecursionError) as exc:
        raise WireError("calibrate", f"bad calibration answer: {exc}") from None
