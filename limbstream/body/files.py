"""Layout and body files: TOML (``tomllib``, the standard library's reader) or JSON, told by the
file's suffix; one table each (docs/body.md, "Files"). Every problem is a ValueError naming it."""
from __future__ import annotations

import json
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from limbstream.body.layout import Layout, bend, offset, segment

SEGMENT_KEYS = frozenset({"name", "parent", "joint", "end", "direction", "height_fraction", "offset", "bend"})
OFFSET_KEYS = frozenset({"from", "direction", "height_fraction"})
BEND_KEYS = frozenset({"toward", "share"})


def read_table(path: str | Path) -> dict[str, Any]:
    """The top-level table of a ``.toml`` or ``.json`` file; ValueError (one line, naming the
    file) if it cannot be read or parsed or is not a table."""
    path = Path(path)
    kind = path.suffix.lower()
    if kind not in (".toml", ".json"):
        raise ValueError(f"{path}: a layout or body file is .toml or .json, got {kind or 'no suffix'!r}")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: cannot read: {e}") from None
    try:
        data = tomllib.loads(text) if kind == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: not valid {kind[1:].upper()}: {e}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: must hold a table at the top, got {type(data).__name__}")
    return data


def _unknown(keys: Any, known: frozenset[str], what: str) -> None:
    extra = sorted(set(keys) - known)
    if extra:
        raise ValueError(f"{what}: unknown key {extra[0]!r} (known: {', '.join(sorted(known))})")


def _text(row: Mapping[str, Any], key: str, what: str, required: bool = True) -> Any:
    value = row.get(key)
    if value is None and not required:
        return None
    if not isinstance(value, str) or not value:
        raise ValueError(f"{what}: {key!r} must be a name, got {value!r}")
    return value


def layout_from_dict(data: Mapping[str, Any], where: str = "layout") -> Layout:
    """A :class:`Layout` from a file's table: ``name``, an optional ``joints`` order and
    ``segments``, a list of tables (``name``, ``parent`` (left out: the root), ``joint``, ``end``,
    ``direction``: a 3-vector or ``{standing = [...], tpose = [...]}``, optional
    ``height_fraction``, ``offset = {from, direction, height_fraction}`` and ``bend = {toward,
    share}``)."""
    _unknown(data, frozenset({"name", "joints", "segments"}), where)
    name = _text(data, "name", where)
    rows = data.get("segments")
    if not isinstance(rows, list) or not all(isinstance(r, Mapping) for r in rows):
        raise ValueError(f"layout {name}: 'segments' must be a list of tables")
    segments = []
    for i, row in enumerate(rows):
        what = f"layout {name}: segment {row.get('name', i)!r}"
        _unknown(row, SEGMENT_KEYS, what)
        at = row.get("offset")
        if at is not None:
            if not isinstance(at, Mapping):
                raise ValueError(f"{what}: 'offset' must be a table")
            _unknown(at, OFFSET_KEYS, f"{what} offset")
            at = offset(_text(at, "from", f"{what} offset"), at.get("direction"), at.get("height_fraction"),
                        f"{what} offset")
        bent = row.get("bend")
        if bent is not None:
            if not isinstance(bent, Mapping):
                raise ValueError(f"{what}: 'bend' must be a table")
            _unknown(bent, BEND_KEYS, f"{what} bend")
            bent = bend(bent.get("toward"), bent.get("share"), f"{what} bend")
        segments.append(segment(_text(row, "name", what), _text(row, "parent", what, required=False),
                                _text(row, "joint", what), _text(row, "end", what), row.get("direction"),
                                row.get("height_fraction"), at, bent))
    joints = data.get("joints", ())
    if not isinstance(joints, list | tuple) or not all(isinstance(j, str) for j in joints):
        raise ValueError(f"layout {name}: 'joints' must be a list of names")
    return Layout(name, tuple(segments), tuple(joints))


def load_layout(path: str | Path) -> Layout:
    """The layout of a ``.toml`` or ``.json`` file (:func:`layout_from_dict`); problems raise
    ValueError naming the file and the problem (a cycle, a missing parent, a duplicate segment,
    an unknown joint, a zero or non-finite direction, ...)."""
    try:
        return layout_from_dict(read_table(path))
    except ValueError as e:
        message = str(e)
        raise ValueError(message if message.startswith(str(path)) else f"{path}: {message}") from None
