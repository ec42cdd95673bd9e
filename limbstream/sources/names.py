"""Which body segment each sensor of an IMU recording measures.

x-IMU3 files carry the segment in their names (``Left_Upper.csv``, :data:`XIO_PREFIXES`); Xsens
MTw exports are named by the sensor's serial number only, so their segments come from a mapping:
a named one (:data:`NAMED`), a file, or a list, as ``--names`` takes it (:func:`parse`):

- ``opensense``: a mapping of :data:`NAMED`;
- ``SENSOR=SEGMENT,SENSOR=SEGMENT,...``: a list;
- a file holding such entries, separated by commas or new lines (``#`` starts a comment).

The same flag maps a BVH file's joints (``JOINT=SEGMENT``, :mod:`.bvh_names`) where no naming
scheme fits them.

``SENSOR`` is a file's name without its extension; a name that ends in ``_SENSOR`` matches too
(Xsens' ``MT_012005D6_009-001_00B4227C``). With a mapping, the sensors it does not name are
left out; without one, a file is named by :data:`XIO_PREFIXES` or keeps its own name.

:func:`parse` checks the syntax only: a ``SEGMENT`` is any segment of the layout in effect (a
layout file's own too), which the command knows once its ``--layout`` is read
(:func:`check_segments`; without one, a built-in layout's, :data:`BODY_SEGMENTS`).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from limbstream.body import LAYOUTS, Layout
from limbstream.wire.body import SEGMENTS

EXTRA_SEGMENTS: tuple[str, ...] = ("l_foot", "r_foot")
"""Segments some recordings measure that the 10-IMU body does not draw (their devices run, and
count in the statistics, but no pose-frame orientation is theirs)."""

BODY_SEGMENTS: tuple[str, ...] = tuple(dict.fromkeys(SEGMENTS + tuple(s for lay in LAYOUTS.values()
                                                                      for s in lay.segment_names)))
"""The built-in layouts' segments (``paper10``'s, then ``full``'s further ones: chest, head, hands,
feet): those a sensor or joint may be mapped to where no layout is given."""

XIO_PREFIXES: dict[str, str] = {
    "left_upper": "l_thigh",
    "right_upper": "r_thigh",
    "left_lower": "l_shank",
    "right_lower": "r_shank",
    "left_foot": "l_foot",
    "right_foot": "r_foot",
    "pelvis": "hip",
}
"""File-name prefix (case-insensitive) -> segment of the x-IMU3 lower-body recording."""

NAMED: dict[str, dict[str, str]] = {
    # OpenSim's OpenSense example (its example and test code: 00B42268 back, 00B42279 pelvis,
    # 00B4227D/C right tibia/femur, 00B421ED/EE left tibia/femur, 00B421EF/E6 right/left foot)
    "opensense": {"00B42279": "hip", "00B4227C": "r_thigh", "00B4227D": "r_shank", "00B421EE": "l_thigh",
                  "00B421ED": "l_shank", "00B421EF": "r_foot", "00B421E6": "l_foot"},
}
"""Named mappings (sensor -> segment) of recordings whose files carry no segment names."""

FLAG = "--names NAME|FILE|SENSOR=SEGMENT,..."
"""How a user gives a mapping (in error messages)."""


def _entries(text: str, where: str) -> dict[str, str]:
    mapping: dict[str, str] = {}
    lines = (line.split("#", 1)[0] for line in text.splitlines())
    for entry in (e.strip() for line in lines for e in line.split(",")):
        if not entry:
            continue
        sensor, sep, segment = (part.strip() for part in entry.partition("="))
        if not sep or not sensor or not segment:
            raise ValueError(f"{where}: {entry!r} is not SENSOR=SEGMENT")
        if sensor in mapping:
            raise ValueError(f"{where}: sensor {sensor!r} is mapped twice")
        mapping[sensor] = segment
    if not mapping:
        raise ValueError(f"{where}: no SENSOR=SEGMENT entry")
    return mapping


def parse(text: str) -> dict[str, str]:
    """The mapping ``text`` gives (a name of :data:`NAMED`, a list, or a file, see the module);
    ValueError naming the problem. Its segments are checked against a layout by
    :func:`check_segments`."""
    text = text.strip()
    if "=" in text:
        return _entries(text, "--names")
    if text in NAMED:
        return dict(NAMED[text])
    path = Path(text)
    if not path.is_file():
        raise ValueError(f"--names {text!r} is neither a named mapping ({', '.join(NAMED)}), a file, "
                         "nor a SENSOR=SEGMENT list")
    try:
        return _entries(path.read_text(), str(path))
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"--names {path}: cannot read ({exc})") from None


def check_segments(mapping: Mapping[str, str] | None, layout: Layout | None) -> None:
    """ValueError (one line: the first segment of ``mapping`` that ``layout`` lacks and the layout's
    segments) unless every segment ``mapping`` maps to is one of ``layout`` (None: of a built-in
    layout, :data:`BODY_SEGMENTS`)."""
    allowed = BODY_SEGMENTS if layout is None else layout.segment_names
    bad = next((segment for segment in (mapping or {}).values() if segment not in allowed), None)
    if bad is not None:
        whose = ("of a built-in layout (a layout file's with --layout FILE); theirs" if layout is None
                 else f"of layout {layout.name}; its segments")
        raise ValueError(f"--names: {bad!r} is not a segment {whose}: {', '.join(allowed)}")


def _matches(sensor: str, stem: str) -> bool:
    sensor, stem = sensor.lower(), stem.lower()
    return stem == sensor or stem.endswith("_" + sensor)


def default_name(stem: str) -> str:
    """A file's segment without a mapping: by :data:`XIO_PREFIXES`, else the stem itself."""
    low = stem.lower()
    return next((segment for prefix, segment in XIO_PREFIXES.items() if low.startswith(prefix)), stem)


def name_sensors(stems: Sequence[str], names: Mapping[str, str] | None) -> list[str | None]:
    """Each sensor's segment (``stems``: the files' names without extension): from ``names`` if
    given (None where it names none), else :func:`default_name`."""
    if names is None:
        return [default_name(stem) for stem in stems]
    return [next((seg for sensor, seg in names.items() if _matches(sensor, stem)), None) for stem in stems]


def check_body(where: str, segments: Sequence[str], sensors: Sequence[str] | None = None,
               known: Sequence[str] = BODY_SEGMENTS) -> None:
    """ValueError unless some of ``segments`` is one of ``known`` (default :data:`BODY_SEGMENTS`; a
    mapping's own segments where one is given); the sentence names the sensors found (``sensors``,
    default ``segments``) and how to map them."""
    if any(s in known for s in segments):
        return
    found = ", ".join(sensors if sensors is not None else segments) or "none"
    raise ValueError(f"{where}: no sensor maps to a body segment (sensors found: {found}); map them with "
                     f"{FLAG} (named: {', '.join(NAMED)}; segments: {', '.join(SEGMENTS)})")
