"""Stats messages: JSON built from the field table (:mod:`.fields`).

``{"subject": str, "t": float (s, epoch), "seq": int, "devices": [{device fields}, ...],
<subject fields>..., "aggregator": {aggregator fields}}``. ``seq`` counts the subject's stats
messages from 0 (per aggregator), so a receiver can count what it missed. Non-finite numbers
are sent as null.
"""
from __future__ import annotations

import json
import math

from .errors import WireError
from .fields import AGGREGATOR_FIELDS, DEVICE_FIELDS, SUBJECT_FIELDS, StatsField

_DEVICE = {f.name: f for f in DEVICE_FIELDS}
_SUBJECT = {f.name: f for f in SUBJECT_FIELDS}
_AGGREGATOR = {f.name: f for f in AGGREGATOR_FIELDS}
_ENVELOPE = ("subject", "t", "seq", "devices", "aggregator")


def _clean(v):
    return None if isinstance(v, float) and not math.isfinite(v) else v


def _entry(values: dict, table: dict[str, StatsField], what: str, complete: bool) -> dict:
    """Values of ``table``'s fields in table order (missing ones null when ``complete``);
    ValueError naming a key the table does not have."""
    unknown = set(values) - set(table)
    if unknown:
        raise ValueError(f"{what} has fields not declared in limbstream.wire.fields: {sorted(unknown)}")
    names = table if complete else [n for n in table if n in values]
    return {n: _clean(values.get(n)) for n in names}


def encode_stats(subject: str, t: float, devices: list[dict], extra: dict | None = None, seq: int = 0) -> bytes:
    """One stats message.

    Parameters
    ----------
    subject : the subject's key chunk.
    t : send time, seconds since the epoch.
    devices : one dict of device-scope fields per device (missing fields are sent as null).
    extra : subject-scope fields, and ``"aggregator"``: a dict of aggregator-scope fields.
    seq : the subject's stats message counter.
    """
    extra = dict(extra or {})
    aggregator = extra.pop("aggregator", None)
    message = {"subject": subject, "t": t, "seq": int(seq)}
    message |= _entry(extra, _SUBJECT, "stats message", complete=False)
    message["devices"] = [_entry(d, _DEVICE, "device entry", complete=True) for d in devices]
    if aggregator is not None:
        message["aggregator"] = _entry(aggregator, _AGGREGATOR, "aggregator entry", complete=False)
    return json.dumps(message, separators=(",", ":")).encode()


def _typed(value, f: StatsField) -> bool:
    """``value`` is null or of the field's type (an int counts as a float; a bool as nothing else)."""
    if value is None:
        return True
    if f.type is dict:
        return isinstance(value, dict) and all(
            isinstance(k, str) and isinstance(v, (int, float)) and not isinstance(v, bool) for k, v in value.items())
    if f.type is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if f.type is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, f.type)


def _check(entry, table: dict[str, StatsField], what: str, complete: bool) -> None:
    if not isinstance(entry, dict):
        raise TypeError(f"{what} must be an object")
    if complete:
        missing = [k for k in table if k not in entry]
        if missing:
            raise KeyError(f"{what} lacks {missing}")
    for name, f in table.items():
        if name in entry and not _typed(entry[name], f):
            raise TypeError(f"{what} field {name} must be {f.type.__name__} or null, got {entry[name]!r}")


def decode_stats(payload: bytes) -> dict:
    """Stats JSON -> dict; WireError('json') if it is malformed, lacks a device field, or has a
    value of the wrong type. Fields not in the table are left in (a newer sender)."""
    try:
        data = json.loads(bytes(payload))  # RecursionError: nesting deeper than the parser allows
        if not isinstance(data, dict):
            raise TypeError("a stats message must be an object")
        devices = data["devices"]
        if not isinstance(data["subject"], str) or not isinstance(devices, list):
            raise TypeError("subject must be a string and devices a list")
        if not isinstance(data.get("seq", 0), int) or isinstance(data.get("seq"), bool):
            raise TypeError("seq must be an integer")
        _check({k: v for k, v in data.items() if k not in _ENVELOPE}, _SUBJECT, "stats message", False)
        for d in devices:
            _check(d, _DEVICE, "device entry", True)
        if data.get("aggregator") is not None:
            _check(data["aggregator"], _AGGREGATOR, "aggregator entry", False)
    except (ValueError, KeyError, TypeError, RecursionError) as exc:
        raise WireError("json", f"bad stats message: {exc}") from None
    return data
