"""``python -m limbstream.wire``: the stats field, compact stats column, device tunable,
joint-angle and drop reason tables of docs/protocol.md, printed as Markdown from the contract
(tests/test_wire.py checks the docs hold exactly these)."""
from __future__ import annotations

from . import ANGLE_BASES, FIELDS, FULL_JOINT_TABLE, JOINT_TABLE, POINT_DROPS, RAW_DROPS, STATS_NUMBERS, STATUS_DROPS, STATS_TEXTS, TUNABLES, UNCHARGED


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


def angles_table(table=JOINT_TABLE) -> str:
    """Markdown table of the joint angles of a joint-angle message of a layout (its joint table),
    in order: their joint and the axis of its Z-X-Y split each turns about, with its sign
    (OpenSim's axes; a joint whose model frame is turned says so)."""
    rows = ["| index | angle | joint | parent -> child | about |", "|---:|---|---|---|---|"]
    named = [(joint, axis, sign, angle) for joint in table
             for axis, sign, angle in zip("ZXY", joint.signs, joint.angles) if angle is not None]

    def about(joint, axis: str, sign: float) -> str:
        turned = "" if joint.frame == (1.0, 0.0, 0.0, 0.0) else \
            f" of the forearm frame (turned {'+' if joint.frame[2] > 0 else '-'}90 deg about Y)"
        return f"{'+' if sign > 0 else '-'}{axis}{turned}"
    rows += [f"| {k} | `{angle}` | `{joint.name}` | {joint.parent} -> {joint.child} | {about(joint, axis, sign)} |"
             for k, (joint, axis, sign, angle) in enumerate(named)]
    return "\n".join(rows)


def bases_table() -> str:
    """Markdown table of the calibrations a joint-angle message's angles can rest on."""
    rows = ["| code | calibration | angles | meaning |", "|---:|---|---|---|"]
    rows += [f"| {code} | `{b.name}` | {'yes' if b.valid else 'none (UNCALIBRATED)'} | {b.meaning} |"
             for code, b in enumerate(ANGLE_BASES)]
    return "\n".join(rows)


def reasons_table(reasons: dict[str, str], what: str = "check") -> str:
    """Markdown table of drop reasons (reason -> what it stands for)."""
    return "\n".join(["| reason | " + what + " |", "|---|---|"] + [f"| `{r}` | {text} |" for r, text in reasons.items()])


def tables() -> dict[str, str]:
    """Every generated table, by what it lists (its section of docs/protocol.md)."""
    return {"Per device": fields_table("device"), "Per subject": fields_table("subject"),
            "Per aggregator": fields_table("aggregator"), "Compact form": compact_table(), "Tunables": tunables_table(),
            "Joint angles": angles_table(), "Joint angles of the full layout": angles_table(FULL_JOINT_TABLE),
            "Calibration of the angles": bases_table(),
            "Segment points dropped": reasons_table(POINT_DROPS), "Truth-tap batches dropped": reasons_table(RAW_DROPS),
            "Body dimensions dropped": reasons_table(STATUS_DROPS),
            "Messages no device can be charged with": reasons_table(UNCHARGED, "message")}


if __name__ == "__main__":
    for heading, table in tables().items():
        print(f"### {heading}\n\n{table}\n")
