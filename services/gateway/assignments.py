"""A gateway's run-time sensor assignments kept in a file, so that a restarted gateway feeds the
devices it fed: a JSON list of assignments as sent to its queryable
(:class:`limbstream.wire.Assignment`: ``{tracker, sensor, subject, segment}``, ``segment`` null:
the sensor feeds none), rewritten whole after each change (a temporary file, then renamed)."""
from __future__ import annotations

import json
import os
from pathlib import Path

from limbstream import wire

Assigned = dict[tuple[str, int], "tuple[str, str] | None"]
"""{(tracker, sensor): (subject, segment), or None: it feeds none}."""


def load(path: str | Path) -> Assigned:
    """The assignments kept in ``path``; {} when there is no such file yet. ValueError with one
    sentence naming the file and the problem when it is not a list of assignments."""
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        return {}
    except OSError as exc:
        raise ValueError(f"cannot read assignments file {path}: {exc.strerror or exc}") from None
    try:
        entries = json.loads(text)
        if not isinstance(entries, list):
            raise ValueError("expected a JSON list of {tracker, sensor, subject, segment}")
        found = [wire.decode_assignment(json.dumps(e).encode()) for e in entries]
    except wire.WireError as exc:
        raise ValueError(f"assignments file {path}: {str(exc).partition(': ')[2]}") from None
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"assignments file {path}: {exc}") from None
    return {(a.tracker, a.sensor): (a.subject, a.segment) if a.segment else None for a in found}


def save(path: str | Path, assigned: Assigned) -> None:
    """Write ``assigned`` to ``path`` (subjects resolved: every entry names its subject)."""
    entries = [{"tracker": tracker, "sensor": sensor, "subject": target[0] if target else None,
                "segment": target[1] if target else None}
               for (tracker, sensor), target in sorted(assigned.items())]
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(entries, indent=1) + "\n")
    os.replace(tmp, path)
