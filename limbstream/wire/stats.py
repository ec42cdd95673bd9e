"""Stats messages: one per subject, about once a second, built from the field table (:mod:`.fields`).

A decoded message is ``{"subject": str, "t": float (s, epoch), "seq": int, <subject fields>...,
"devices": [{device fields}, ...], "aggregator": {aggregator fields}}``. ``seq`` counts the
subject's stats messages from 0 (per aggregator), so a receiver can count what it missed.
Non-finite numbers are null.

Two forms on the wire, told apart by their first byte:

- compact (what the aggregator sends, :func:`encode_stats`): a header, a JSON head (the message
  without its device numbers, and the devices' text fields as columns), then the devices' number
  fields as a little-endian float64 table, one row per device (NaN: null);
- JSON (:func:`encode_stats_json`; older aggregators and recordings, and the answer to a query of a
  stats key: :func:`stats_json`), the decoded message itself.

:func:`decode_stats` reads both into the same dict.
"""
from __future__ import annotations

import json
import math
import struct

import numpy as np

from .errors import WireError
from .fields import AGGREGATOR_FIELDS, DEVICE_FIELDS, SUBJECT_FIELDS, StatsField

STATS_VERSION = 2
"""First byte of a compact stats message (a JSON one begins with ``{``)."""
STATS_NUMBERS: tuple[str, ...] = tuple(f.name for f in DEVICE_FIELDS if f.type in (int, float, bool))
"""The device fields sent as numbers in a compact message (its float64 table's columns, in order)."""
STATS_TEXTS: tuple[str, ...] = tuple(f.name for f in DEVICE_FIELDS if f.type not in (int, float, bool))
"""The device fields sent in the JSON head of a compact message (strings and objects)."""
_HEADER = struct.Struct("<BBHHHI")  # version, reserved, devices, numbers per device, reserved, head bytes

_DEVICE = {f.name: f for f in DEVICE_FIELDS}
_SUBJECT = {f.name: f for f in SUBJECT_FIELDS}
_AGGREGATOR = {f.name: f for f in AGGREGATOR_FIELDS}
_ENVELOPE = ("subject", "t", "seq", "devices", "aggregator")
_COMPACT = ("subject", "t", "seq", "aggregator", "numbers", "texts")  # the head's own keys


def _clean(v):
    return None if isinstance(v, float) and not math.isfinite(v) else v


def _entry(values: dict, table: dict[str, StatsField], what: str, complete: bool) -> dict:
    """Values of ``table``'s fields in table order (missing ones null when ``complete``);
    ValueError naming a key the table does not have."""
    unknown = values.keys() - table.keys()
    if unknown:
        raise ValueError(f"{what} has fields not declared in limbstream.wire.fields: {sorted(unknown)}")
    names = table if complete else [n for n in table if n in values]
    return {n: _clean(values.get(n)) for n in names}


def _message(subject: str, t: float, extra: dict | None, seq: int) -> tuple[dict, dict | None]:
    """The message's envelope and subject fields, and its aggregator fields (None: none)."""
    extra = dict(extra or {})
    aggregator = extra.pop("aggregator", None)
    message = {"subject": subject, "t": t, "seq": int(seq)} | _entry(extra, _SUBJECT, "stats message", complete=False)
    return message, None if aggregator is None else _entry(aggregator, _AGGREGATOR, "aggregator entry", complete=False)


def encode_stats_json(subject: str, t: float, devices: list[dict], extra: dict | None = None, seq: int = 0) -> bytes:
    """One stats message in the JSON form (parameters as :func:`encode_stats`)."""
    message, aggregator = _message(subject, t, extra, seq)
    message["devices"] = [_entry(d, _DEVICE, "device entry", complete=True) for d in devices]
    if aggregator is not None:
        message["aggregator"] = aggregator
    return json.dumps(message, separators=(",", ":")).encode()


def encode_stats(subject: str, t: float, devices: list[dict], extra: dict | None = None, seq: int = 0) -> bytes:
    """One stats message in the compact form.

    Parameters
    ----------
    subject : the subject's key chunk.
    t : send time, seconds since the epoch.
    devices : one dict of device-scope fields per device (missing fields are sent as null).
    extra : subject-scope fields, and ``"aggregator"``: a dict of aggregator-scope fields.
    seq : the subject's stats message counter.
    """
    for d in devices:
        unknown = d.keys() - _DEVICE.keys()
        if unknown:
            raise ValueError(f"device entry has fields not declared in limbstream.wire.fields: {sorted(unknown)}")
    numbers = np.array([[d.get(name) for name in STATS_NUMBERS] for d in devices], "<f8").reshape(-1, len(STATS_NUMBERS))
    return encode_stats_table(subject, t, numbers, {name: [d.get(name) for d in devices] for name in STATS_TEXTS},
                              extra, seq)


def encode_stats_table(subject: str, t: float, numbers: np.ndarray, texts: dict[str, list], extra: dict | None = None,
                       seq: int = 0) -> bytes:
    """One stats message in the compact form from its device columns: ``numbers`` (N, K) float64,
    the :data:`STATS_NUMBERS` of each of N devices (NaN: null), and ``texts``: {field: N values}
    of the :data:`STATS_TEXTS` (missing ones: null); the rest as :func:`encode_stats`.

    Layout (little-endian): u8 version (:data:`STATS_VERSION`), u8 0, u16 devices N, u16 numbers
    per device K, u16 0, u32 head length H; H bytes of UTF-8 JSON: the envelope and subject fields,
    ``"aggregator"``, ``"numbers"``: the K names of the number columns, ``"texts"``: {field: N
    values} of the other device fields; then N x K float64, device by device (NaN: null; bools 0/1).
    """
    n = len(numbers)
    if numbers.shape != (n, len(STATS_NUMBERS)) or texts.keys() - set(STATS_TEXTS) or any(
            len(v) != n for v in texts.values()):
        raise ValueError(f"stats table: numbers must be (N, {len(STATS_NUMBERS)}) and texts N values of "
                         f"{STATS_TEXTS}, got {numbers.shape} and {sorted(texts)}")
    message, aggregator = _message(subject, t, extra, seq)
    if aggregator is not None:
        message["aggregator"] = aggregator
    message["numbers"] = STATS_NUMBERS
    message["texts"] = {name: texts.get(name, [None] * n) for name in STATS_TEXTS}
    head = json.dumps(message, separators=(",", ":")).encode()
    body = np.ascontiguousarray(numbers, "<f8").tobytes()
    return _HEADER.pack(STATS_VERSION, 0, n, len(STATS_NUMBERS), 0, len(head)) + head + body


def stats_devices(names: list[str], rows: list[list[float]], texts: dict[str, list]) -> list[dict]:
    """Device entries (dicts, fields in table order) from columns: number rows (N lists of the
    values of columns ``names``; NaN: null) and ``texts`` {field: N values}; numbers take their
    field's type (TypeError: an int field that is not one)."""
    types = [_DEVICE.get(name) for name in names]
    devices = []
    for i, row in enumerate(rows):
        entry = {name: _number(v, f) for name, v, f in zip(names, row, types)}
        entry.update((name, values[i]) for name, values in texts.items())
        devices.append({name: entry[name] for name in _DEVICE if name in entry}
                       | {name: v for name, v in entry.items() if name not in _DEVICE})
    return devices


def stats_json(payload: bytes) -> bytes:
    """The JSON form of a stats message in either form (WireError as :func:`decode_stats`)."""
    if bytes(payload[:1]) != bytes([STATS_VERSION]):
        decode_stats(payload)
        return bytes(payload)
    return json.dumps(decode_stats(payload), separators=(",", ":")).encode()


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


def _number(value: float, f: StatsField | None):
    """A number column's value as its field's type (null: NaN; TypeError: not of the type)."""
    if not math.isfinite(value):
        return None
    if f is None or f.type is float:
        return value
    if f.type is bool:
        return value != 0.0
    if value != int(value):
        raise TypeError(f"device field {f.name} must be an integer, got {value!r}")
    return int(value)


def _compact(payload: bytes) -> dict:
    """A compact stats message -> the dict of its JSON form (before the checks of :func:`decode_stats`)."""
    if len(payload) < _HEADER.size:
        raise ValueError(f"compact stats message of {len(payload)} bytes")
    _, _, n, k, _, h = _HEADER.unpack_from(payload)
    if len(payload) != _HEADER.size + h + 8 * n * k:
        raise ValueError(f"compact stats message of {len(payload)} bytes, {n} devices x {k} numbers, head {h}")
    data = json.loads(bytes(payload[_HEADER.size:_HEADER.size + h]))
    if not isinstance(data, dict):
        raise TypeError("a stats message must be an object")
    names, texts = data.pop("numbers"), data.pop("texts")
    if not isinstance(names, list) or len(names) != k or not isinstance(texts, dict) or not all(
            isinstance(v, list) and len(v) == n for v in texts.values()):
        raise TypeError(f"numbers must name the {k} columns and texts hold {n} values each")
    rows = np.frombuffer(payload, "<f8", n * k, _HEADER.size + h).reshape(n, k).tolist()
    devices = stats_devices(names, rows, texts)
    return {key: data[key] for key in data if key not in _COMPACT[3:]} | {"devices": devices} | (
        {"aggregator": data["aggregator"]} if "aggregator" in data else {})


def decode_stats(payload: bytes) -> dict:
    """Stats message (either form) -> dict; WireError('json') if it is malformed, lacks a device
    field, or has a value of the wrong type. Fields not in the table are left in (a newer sender)."""
    try:
        if bytes(payload[:1]) == bytes([STATS_VERSION]):
            data = _compact(payload)
        else:
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
    except (ValueError, KeyError, TypeError, RecursionError, struct.error) as exc:
        raise WireError("json", f"bad stats message: {exc}") from None
    return data
