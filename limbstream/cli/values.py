"""Flag values the commands share: one list syntax (``A,B,C``) for every flag that takes several
values, and the sensor-to-segment mapping of ``--names``."""
from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TypeVar

from limbstream.sources import names

T = TypeVar("T")


def comma_list(item: Callable[[str], T]) -> Callable[[str], list[T]]:
    """An argparse ``type`` that reads ``A,B,C`` (spaces around the commas allowed) with ``item``
    for each value; ``item`` raises ValueError or ArgumentTypeError with its own sentence."""

    def parse(text: str) -> list[T]:
        values = []
        for part in (p.strip() for p in text.split(",")):
            if not part:
                continue
            try:
                values.append(item(part))
            except ValueError as exc:
                raise argparse.ArgumentTypeError(str(exc)) from None
        if not values:
            raise argparse.ArgumentTypeError(f"no value in {text!r}")
        return values

    return parse


def sensor_names(text: str) -> dict[str, str]:
    """The ``--names`` mapping (:func:`limbstream.sources.names.parse`), as an argparse type."""
    try:
        return names.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_names_argument(parser: argparse.ArgumentParser) -> None:
    """``--names NAME|FILE|SENSOR=SEGMENT,...``: which segment each sensor of an IMU recording
    measures (the mapping itself: :mod:`limbstream.sources.names`)."""
    parser.add_argument("--names", type=sensor_names, default=None, metavar="NAME|FILE|SENSOR=SEGMENT,...",
                        help="which segment each sensor of an IMU recording measures: a named mapping "
                             f"({', '.join(names.NAMED)}), a file of SENSOR=SEGMENT lines, or a list "
                             "(SENSOR: a file name without extension, e.g. an Xsens serial number; default: "
                             "x-IMU3 file names, e.g. Left_Upper.csv -> l_thigh)")


def names_flags(mapping: dict[str, str] | None) -> list[str]:
    """The flags that give ``mapping`` to a child process (none for None)."""
    return [] if mapping is None else ["--names", ",".join(f"{sensor}={segment}" for sensor, segment in mapping.items())]
