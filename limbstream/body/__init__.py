"""Bodies as data: a layout (its segments, each segment's parent, the joint where its bone starts
and the bone's direction at rest) and the wearer's dimensions (the bones' lengths), with their
forward kinematics (docs/body.md).

Built-in layouts: ``paper10`` (wire.SEGMENTS and wire.JOINTS, the skeleton of the paper's
evaluation) and ``full`` (15 segments); a ``.toml`` or ``.json`` layout file adds others
(:func:`load_layout`). Bodies: :class:`Body` (``from_height``, ``from_file``, ``from_vectors``,
``default``). A subject's body travels in its devices' status (``wire.encode_body``) and the
aggregator draws its frames, of that body's layout, with it; a ``paper10`` subject without one is
drawn with :mod:`limbstream.skeleton`, which ``paper10``'s default body reproduces bit for bit.
"""
from __future__ import annotations

from pathlib import Path

from limbstream.body.builtin import (DEFAULT_HEIGHT_M, FULL, LAYOUTS, PAPER10, PAPER10_BONES, WINTER_HEIGHTS,
                                     WINTER_LENGTHS, builtin_layout)
from limbstream.body.dimensions import (HEIGHT_BOUNDS_M, MAX_BONE_M, Body, check_height, check_length, lengths_of,
                                        rest_heights)
from limbstream.body.files import layout_from_dict, load_layout, read_table
from limbstream.body.layout import Bend, Bone, Layout, Offset, Segment, bend, offset, segment


def layout(name_or_path: str | Path) -> Layout:
    """A built-in layout by name, or the layout of a ``.toml``/``.json`` file."""
    if isinstance(name_or_path, str) and name_or_path in LAYOUTS:
        return LAYOUTS[name_or_path]
    if Path(name_or_path).suffix.lower() in (".toml", ".json"):
        return load_layout(name_or_path)
    return builtin_layout(str(name_or_path))


def layout_for(segments) -> Layout:
    """The smallest built-in layout holding every segment name of ``segments`` (``paper10`` before
    ``full``); ValueError naming the segments no built-in layout has."""
    names = set(segments)
    for candidate in LAYOUTS.values():
        if names <= set(candidate.segment_names):
            return candidate
    known = set().union(*(set(lay.segment_names) for lay in LAYOUTS.values()))
    unknown = sorted(names - known)
    what = f"segments {', '.join(unknown)}" if unknown else f"all of the segments {', '.join(sorted(names))}"
    raise ValueError(f"no built-in layout ({', '.join(LAYOUTS)}) has {what}; give a layout file (--layout FILE)")


__all__ = ["DEFAULT_HEIGHT_M", "FULL", "HEIGHT_BOUNDS_M", "LAYOUTS", "MAX_BONE_M", "PAPER10", "PAPER10_BONES",
           "WINTER_HEIGHTS", "WINTER_LENGTHS", "Bend", "Body", "Bone", "Layout", "Offset", "Segment", "builtin_layout",
           "bend", "check_height", "check_length", "layout", "layout_for", "lengths_of", "layout_from_dict", "load_layout", "offset", "read_table",
           "rest_heights", "segment"]
