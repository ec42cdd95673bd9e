"""Tables that explain themselves: each column says its name, unit and meaning; a cell whose
value does not apply (None, NaN) shows :data:`DASH`; a legend follows every table. And
:class:`Progress`, the lines a long run prints while it works.

A new measure is one more :class:`Column` in its table's list (``report.EVAL_COLUMNS``).
"""
from __future__ import annotations

import math
import textwrap
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

DASH = "–"
"""What a cell shows when its column does not apply to its row."""


@dataclass(frozen=True)
class Column:
    """One column of a table.

    Attributes
    ----------
    key : the row field it shows.
    name : its header.
    unit : the values' unit ("" for none), under the header and in the legend.
    meaning : one sentence for the legend.
    fmt : format spec of a number (e.g. ".3f"); "" shows the value as text, left-aligned.
    """

    key: str
    name: str
    unit: str = ""
    meaning: str = ""
    fmt: str = ".3f"

    def cell(self, row: dict) -> str:
        """The cell of ``row``: its value formatted, or :data:`DASH` where it does not apply."""
        value = row.get(self.key)
        if value is None or (isinstance(value, float) and not math.isfinite(value)):
            return DASH
        return format(value, self.fmt) if self.fmt else str(value)


def render(columns: Sequence[Column], rows: Sequence[dict]) -> str:
    """The table (a header line, a unit line, a rule, one line per row) and its legend, as text."""
    cells = [[c.cell(r) for c in columns] for r in rows]
    units = [f"({c.unit})" if c.unit else "" for c in columns]
    widths = [max([len(c.name), len(u)] + [len(line[k]) for line in cells]) for k, (c, u) in
              enumerate(zip(columns, units))]

    def line(values: Sequence[str]) -> str:
        return "  ".join(v.ljust(w) if not c.fmt else v.rjust(w) for c, v, w in zip(columns, values, widths)).rstrip()

    out = [line([c.name for c in columns]), line(units), "-" * len(line([c.name for c in columns]))]
    out += [line(values) for values in cells]
    return "\n".join(out + ["", legend(columns)])


def legend(columns: Sequence[Column], width: int = 100) -> str:
    """One entry per column: its name and unit, then its meaning (wrapped to ``width``); then
    what :data:`DASH` means."""
    names = [f"{c.name} ({c.unit})" if c.unit else c.name for c in columns] + [DASH]
    meanings = [c.meaning for c in columns] + ["does not apply to the row"]
    pad = max(len(n) for n in names) + 4
    return "\n".join(textwrap.fill(meaning, width, initial_indent=f"  {name}".ljust(pad),
                                    subsequent_indent=" " * pad) for name, meaning in zip(names, meanings))


class Progress:
    """Lines saying how far a long run is: nothing for the first ``after_s`` seconds, then at most
    one every ``every_s`` (on a terminal: one line rewritten in place).

    Call it with (done, total) as work is done; :meth:`close` ends the line.
    """

    def __init__(self, what: str, write: Callable[[str], None], tty: bool = False, after_s: float = 2.0,
                 every_s: float = 5.0):
        self.what, self.write, self.tty = what, write, tty
        self.start = time.monotonic()
        self.next = self.start + after_s
        self.every_s = 1.0 if tty else every_s
        self.shown = False

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if now < self.next or done >= total:
            return
        self.next = now + self.every_s
        elapsed = now - self.start
        left = elapsed * (total - done) / done if done else math.nan
        text = (f"{self.what} {done}/{total} ({100 * done / total:.0f} %), {elapsed:.0f} s"
                + (f", about {left:.0f} s left" if math.isfinite(left) else ""))
        self.write(f"\r{text}\x1b[K" if self.tty else text + "\n")
        self.shown = True

    def close(self) -> None:
        if self.shown and self.tty:
            self.write("\n")
