"""The REST forms of the dashboard's live state: devices, their history, subjects, aggregators,
and the latest pose of a subject by kind."""
from __future__ import annotations

import math
import time

from limbstream import wire

from .entries import HISTORY_FIELDS, KINDS, PoseEntry


class Views:
    """Reads of a :class:`~.state.LiveState` (mixed into it)."""

    def auto_kind(self, subject: str) -> int:
        """The kind ``kind=auto`` shows now: the contract's one rule (``wire.auto_kind``)."""
        live = self.poses.get(subject, {}).get(wire.KIND_LIVE)
        return wire.auto_kind(math.inf if live is None else time.time() - live.rx)

    def latest_pose(self, subject: str, kind: str = "auto") -> PoseEntry | None:
        slots = self.poses.get(subject, {})
        if kind == "auto":
            return slots.get(self.auto_kind(subject)) or next(iter(slots.values()), None)
        return slots.get(KINDS[kind])

    def device_view(self, did: str, now: float | None = None) -> dict | None:
        """The REST form of one device: every stats field, plus subject, alive, age_s, stale."""
        entry = self.devices.get(did)
        if entry is None:
            return None
        now = time.time() if now is None else now
        stats = entry.stats or {}
        view = {k: stats.get(k) for k in wire.STATS_FIELDS}
        view |= {k: v for k, v in stats.items() if k not in view}
        age = now - entry.updated if entry.stats is not None else None
        stale = age is None or age > self.stale_after_s
        alive = did in self.alive
        view.update(device=did, segment=entry.segment, subject=entry.subject, alive=alive,
                    age_s=None if age is None else round(age, 3), stale=stale,
                    online=bool(stats.get("online")) if not stale else alive)
        return view

    def device_views(self, subject: str | None = None) -> list[dict]:
        """Every device's view, by id; ``subject``: only that subject's."""
        now = time.time()
        return [self.device_view(did, now) for did, e in sorted(self.devices.items())
                if subject is None or e.subject == subject]

    def history(self, did: str, seconds: float) -> dict | None:
        """Column form ``{"t": [...], <field>: [...]}`` of the last ``seconds`` of a device."""
        entry = self.devices.get(did)
        if entry is None:
            return None
        rows = list(entry.history)
        if rows:
            cutoff = rows[-1][0] - seconds
            rows = [r for r in rows if r[0] >= cutoff]
        columns = {"t": [r[0] for r in rows]}
        for i, name in enumerate(HISTORY_FIELDS, start=1):
            columns[name] = [r[i] for r in rows]
        return columns

    def subject_names(self) -> list[str]:
        """Every subject with a device or a pose frame, sorted."""
        return sorted({e.subject for e in self.devices.values()} | set(self.poses))

    def subject_views(self) -> list[dict]:
        return [self.subject_view(name) for name in self.subject_names()]

    def subject_view(self, name: str, with_devices: bool = False) -> dict:
        """The REST form of one subject; ``with_devices``: also each device's view
        (``device_list``) and the body's segments it has no device for (``missing_segments``)."""
        now = time.time()
        views = self.device_views(name)
        pose = self.latest_pose(name)
        view = {
            "subject": name,
            "devices": len(views),
            "online": sum(1 for v in views if v["online"]),
            "msgs_per_s": round(sum(v["msgs_per_s"] or 0.0 for v in views), 3),
            "bytes_per_s": round(sum(v["bytes_per_s"] or 0.0 for v in views), 3),
            "stats_age_s": round(now - self.stats_times[name], 3) if name in self.stats_times else None,
            "pose": None if pose is None else {
                "seq": pose.frame.seq, "t": pose.frame.t_us / 1e6,
                "kind": "live" if pose.frame.kind == wire.KIND_LIVE else "exact",
                "age_s": round(now - pose.rx, 3)},
            **self.exact_latency_view(name),
            **self.subject_stats.get(name, {}),
        }
        if with_devices:
            have = {v["segment"] for v in views}
            view |= {"device_list": views, "missing_segments": [s for s in wire.SEGMENTS if s not in have]}
        return view

    def exact_latency_view(self, subject: str) -> dict:
        """``exact_latency_p50_ms``, ``exact_latency_p99_ms``: frame time -> received here, over
        the subject's last :data:`LATENCY_FRAMES` exact frames (None before the first)."""
        lat = self.exact_latency.get(subject)
        if not lat:
            return {"exact_latency_p50_ms": None, "exact_latency_p99_ms": None}
        xs = sorted(lat)
        pick = lambda q: round(xs[min(len(xs) - 1, int(q * len(xs)))], 1)  # noqa: E731 - nearest rank
        return {"exact_latency_p50_ms": pick(0.5), "exact_latency_p99_ms": pick(0.99)}

    def aggregator_views(self) -> list[dict]:
        """The REST form of every aggregator: its figures, late ticks in %, age and staleness."""
        now = time.time()
        out = []
        for aid, agg in sorted(self.aggregators.items()):
            f = agg.figures
            late_pct = 100.0 * f["late"] / f["ticks"] if f["ticks"] and f["late"] is not None else None
            age = now - agg.updated
            out.append({"id": aid, **f, "late_pct": None if late_pct is None else round(late_pct, 4),
                        "bad_keys": agg.bad_keys, "serving": sorted(agg.subjects),
                        "age_s": round(age, 3), "stale": age > self.stale_after_s})
        return out
