"""Gateway sensor assignment (docs/protocol.md, "SlimeVR gateway"): a client lists a gateway's
sensors and moves them between devices at run time. JSON both ways, on the gateway's queryable
(:func:`~.keys.gateway_key`): a query without payload lists; one with an :class:`Assignment`
assigns, and the reply lists the sensors after the change (or is an error reply
``{"error": sentence}``)."""
from __future__ import annotations

import json
from dataclasses import dataclass

from .body import builtin_segments
from .errors import WireError
from .keys import check_chunk


@dataclass(frozen=True)
class Assignment:
    """Sensor ``sensor`` (0..255) of ``tracker`` (its MAC, or ``ip:port``) feeds device
    ``subject/segment``; ``segment`` None: it feeds none; ``subject`` None: the gateway's subject."""

    tracker: str
    sensor: int
    subject: str | None
    segment: str | None


def encode_assignment(a: Assignment) -> bytes:
    return json.dumps({"tracker": a.tracker, "sensor": a.sensor, "subject": a.subject, "segment": a.segment}).encode()


def decode_assignment(payload: bytes) -> Assignment:
    """The assignment asked for; WireError('assign') with one sentence naming the problem."""
    try:
        data = json.loads(bytes(payload))
    except (ValueError, RecursionError) as exc:
        raise WireError("assign", f"an assignment must be a JSON object: {exc}") from None
    if not isinstance(data, dict):
        raise WireError("assign", "an assignment must be a JSON object {tracker, sensor, subject, segment}")
    unknown = set(data) - {"tracker", "sensor", "subject", "segment"}
    if unknown:
        raise WireError("assign", f"unknown assignment field(s): {', '.join(sorted(map(str, unknown)))}")
    tracker, sensor = data.get("tracker"), data.get("sensor")
    subject, segment = data.get("subject"), data.get("segment")
    if not isinstance(tracker, str) or not tracker:
        raise WireError("assign", f"tracker must be the tracker's name (its MAC or ip:port), got {tracker!r}")
    if isinstance(sensor, bool) or not isinstance(sensor, int) or not 0 <= sensor <= 255:
        raise WireError("assign", f"sensor must be an integer in 0..255, got {sensor!r}")
    if segment is not None and segment not in builtin_segments():
        raise WireError("assign", f"segment must be one of {', '.join(builtin_segments())} or null (unassign), "
                                  f"got {segment!r}")
    if subject is not None:
        try:
            check_chunk(subject, "subject")
        except ValueError as exc:
            raise WireError("assign", str(exc)) from None
    return Assignment(tracker, sensor, subject, segment)


def encode_sensors(gateway: str, subject: str, sensors: list[dict]) -> bytes:
    """The gateway's listing: its name, its subject (of sensors placed by body position) and
    each sensor as ``{tracker, sensor, online, position, device, why}`` (``device``: the device id
    it feeds, or null and ``why`` not)."""
    return json.dumps({"gateway": gateway, "subject": subject, "sensors": sensors}).encode()


def decode_sensors(payload: bytes) -> dict:
    """A gateway's listing as a dict (see :func:`encode_sensors`); WireError('gateway') otherwise."""
    try:
        data = json.loads(bytes(payload))
        if not isinstance(data, dict) or not isinstance(data.get("gateway"), str) \
                or not isinstance(data.get("subject"), str) or not isinstance(data.get("sensors"), list):
            raise ValueError("needs 'gateway' and 'subject' strings and a 'sensors' list")
        for s in data["sensors"]:
            if not (isinstance(s, dict) and isinstance(s.get("tracker"), str) and isinstance(s.get("sensor"), int)
                    and isinstance(s.get("online"), bool) and (s.get("device") is None or isinstance(s["device"], str))
                    and (s.get("why") is None or isinstance(s["why"], str))
                    and (s.get("position") is None or isinstance(s["position"], int))):
                raise ValueError(f"bad sensor entry {s!r}")
        return data
    except (ValueError, RecursionError) as exc:
        raise WireError("gateway", f"bad gateway listing: {exc}") from None
