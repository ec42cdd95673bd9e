"""``python -m limbstream.wire``: the stats field, compact stats column and device tunable
tables of docs/protocol.md, printed as Markdown from the contract (tests/test_wire.py checks the docs hold
exactly these)."""
from __future__ import annotations

from . import FIELDS, STATS_NUMBERS, STATS_TEXTS, TUNABLES


def fields_table(scope: str) -> str:
    """Markdown table of the stats fields of one scope."""
    rows = ["| field | type | unit | meaning | Prometheus |", "|---|---|---|---|---|"]
    for f in FIELDS:
        if f.scope == scope:
            metric = f"`{f.metric}{'_total' if f.counter else ''}`" if f.metric else ""
            chart = " (charted)" if f.chart else ""
            rows.append(f"| `{f.name}` | {f.type.__name__} | {f.unit} | {f.help}{chart} | {metric} |")
    return "\n".join(rows)


def compact_table() -> str:
    """Markdown table of a compact stats message's device columns: the numbers' table columns in
    order, then the fields in the head's ``texts``."""
    types = {f.name: f.type.__name__ for f in FIELDS if f.scope == "device"}
    rows = ["| column | field | type | sent as |", "|---:|---|---|---|"]
    rows += [f"| {i} | `{name}` | {types[name]} | f64{' (0 or 1)' if types[name] == 'bool' else ''} |"
             for i, name in enumerate(STATS_NUMBERS)]
    rows += [f"| – | `{name}` | {types[name]} | `texts` |" for name in STATS_TEXTS]
    return "\n".join(rows)


def tunables_table() -> str:
    """Markdown table of the device tunables."""
    rows = ["| tunable | flag | type | default | bounds | unit | meaning |", "|---|---|---|---|---|---|---|"]
    for t in TUNABLES.values():
        rows.append(f"| `{t.name}` | `{t.flag}` | {t.type.__name__} | {t.default:g} | {t.low:g}..{t.high:g} | "
                    f"{t.unit} | {t.help} |")
    return "\n".join(rows)


def tables() -> dict[str, str]:
    """Every generated table, by the heading it stands under in docs/protocol.md."""
    return {"Per device": fields_table("device"), "Per subject": fields_table("subject"),
            "Per aggregator": fields_table("aggregator"), "Compact form": compact_table(), "Tunables": tunables_table()}


if __name__ == "__main__":
    for heading, table in tables().items():
        print(f"### {heading}\n\n{table}\n")
