"""The REST forms of the dashboard's live state: devices, their history, subjects, their joint
angles, aggregators."""
from __future__ import annotations

import math
import time

import numpy as np

from limbstream import wire
from limbstream.body import LAYOUTS, PAPER10, Layout, lengths_of

from .entries import HISTORY_FIELDS
from .state import LiveState


def layout_view(layout: Layout) -> dict:
    """What a page needs to draw frames of ``layout``: its name, segments (device order), joints
    (the order of a frame's positions) and bones as pairs of joint names (proximal, distal)."""
    return {"layout": layout.name, "segments": list(layout.segment_names), "joints": list(layout.joints),
            "bones": [[b.origin, b.joint] for b in layout.bones]}


class Views:
    """The REST forms of a :class:`~.state.LiveState` (reads only).

    Parameters
    ----------
    live : the state read.
    stale_after_s : age (s) beyond which a device's stats count as stale.
    """

    def __init__(self, live: LiveState, stale_after_s: float = 5.0):
        self.live, self.stale_after_s = live, stale_after_s

    def device_view(self, did: str, now: float | None = None) -> dict | None:
        """The REST form of one device: every stats field, plus subject, alive, age_s, stale."""
        entry = self.live.devices.get(did)
        if entry is None:
            return None
        now = time.time() if now is None else now
        stats = entry.stats or {}
        view = {k: stats.get(k) for k in wire.STATS_FIELDS}
        view |= {k: v for k, v in stats.items() if k not in view}
        age = now - entry.updated if entry.stats is not None else None
        stale = age is None or age > self.stale_after_s
        alive = did in self.live.alive
        view.update(device=did, segment=entry.segment, subject=entry.subject, alive=alive,
                    age_s=None if age is None else round(age, 3), stale=stale,
                    online=bool(stats.get("online")) if not stale else alive)
        return view

    def device_views(self, subject: str | None = None) -> list[dict]:
        """Every device's view, by id; ``subject``: only that subject's."""
        now = time.time()
        return [self.device_view(did, now) for did, e in sorted(self.live.devices.items())
                if subject is None or e.subject == subject]

    def joint_angles(self, subject: str, seconds: float, kind: str = "auto",
                     names: list[str] | None = None) -> dict | None:
        """The subject's newest joint angles of ``kind`` (``auto``: :meth:`LiveState.angles_kind`)
        and the column form of the last ``seconds`` of them, ``names`` only (None: all), of the
        names the messages carry (in their order); None if there are none."""
        code = self.live.angles_kind(subject) if kind == "auto" else wire.FRAME_KINDS[kind]
        rows = self.live.angles.get(subject, {}).get(code) if code is not None else None
        if not rows:
            return None
        rx, newest = rows[-1]
        latest = newest.to_json(subject)
        every = list(latest["angles"])  # the messages' own names, in their order
        kept = [a for r, a in rows if r >= rx - seconds and len(a.angles) == len(every)]
        names = every if names is None else [n for n in every if n in names]
        columns = np.array([a.angles for a in kept], np.float64)[:, [every.index(n) for n in names]]
        values = np.round(columns, 3).T.tolist()
        return {"subject": subject, "kind": wire.kind_name(code), "names": names,
                "latest": latest | {"rx": round(rx, 4)},
                "t": [a.t_us / 1e6 for a in kept], "seq": [a.seq for a in kept],
                "angles": {n: [None if math.isnan(v) else v for v in column] for n, column in zip(names, values)}}

    def history(self, did: str, seconds: float) -> dict | None:
        """Column form ``{"t": [...], <field>: [...]}`` of the last ``seconds`` of a device."""
        entry = self.live.devices.get(did)
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
        """Every subject with a device or a pose frame (or a refused one), sorted."""
        return sorted({e.subject for e in self.live.devices.values()} | set(self.live.poses) | set(self.live.pose_refused))

    def subject_views(self) -> list[dict]:
        return [self.subject_view(name) for name in self.subject_names()]

    def subject_view(self, name: str, with_devices: bool = False) -> dict:
        """The REST form of one subject; ``with_devices``: also each device's view
        (``device_list``) and the body's segments it has no device for (``missing_segments``)."""
        now = time.time()
        views = self.device_views(name)
        pose = self.live.latest_pose(name)
        view = {
            "subject": name,
            "devices": len(views),
            "online": sum(1 for v in views if v["online"]),
            "msgs_per_s": round(sum(v["msgs_per_s"] or 0.0 for v in views), 3),
            "bytes_per_s": round(sum(v["bytes_per_s"] or 0.0 for v in views), 3),
            "stats_age_s": round(now - self.live.stats_times[name], 3) if name in self.live.stats_times else None,
            "pose": None if pose is None else {
                "seq": pose.frame.seq, "t": pose.frame.t_us / 1e6,
                "kind": wire.kind_name(pose.frame.kind),
                "age_s": round(now - pose.rx, 3)},
            **self.exact_latency_view(name),
            **self.live.subject_stats.get(name, {}),
        }
        layout = self.subject_layout(name)
        if view.get("bones_m") is None and pose is not None:  # no body announced: the lengths its frames are drawn with
            view |= {"height_m": None,
                     "bones_m": {b: round(m, 5) for b, m in lengths_of(layout, pose.frame.joints).items()}}
        view |= {"layout": layout.name, "pose_refused": self.live.pose_refused.get(name)}
        if with_devices:
            have = {v["segment"] for v in views}
            view |= {"device_list": views, "missing_segments": [s for s in layout.segment_names if s not in have],
                     **layout_view(layout)}
        return view

    def subject_layout(self, name: str) -> Layout:
        """The subject's body layout: its latest frame's, else the one its devices announce (their
        status, asked for when a frame of a layout file's came), else the one its stats name (a
        built-in's), else ``paper10``."""
        pose = self.live.latest_pose(name)
        if pose is not None and pose.frame.layout is not None:
            return pose.frame.layout
        announced = self.live.layouts.layout_of(name)
        if announced is not None:
            return announced
        return LAYOUTS.get(self.live.subject_stats.get(name, {}).get("layout") or "", PAPER10)

    def exact_latency_view(self, subject: str) -> dict:
        """``exact_latency_p50_ms``, ``exact_latency_p99_ms``: frame time -> received here, over
        the subject's last :data:`LATENCY_FRAMES` exact frames (None before the first)."""
        lat = self.live.exact_latency.get(subject)
        if not lat:
            return {"exact_latency_p50_ms": None, "exact_latency_p99_ms": None}
        xs = sorted(lat)
        pick = lambda q: round(xs[min(len(xs) - 1, int(q * len(xs)))], 1)  # noqa: E731 - nearest rank
        return {"exact_latency_p50_ms": pick(0.5), "exact_latency_p99_ms": pick(0.99)}

    def aggregator_views(self) -> list[dict]:
        """The REST form of every aggregator: its figures, late ticks in %, age and staleness."""
        now = time.time()
        out = []
        for aid, agg in sorted(self.live.aggregators.items()):
            f = agg.figures
            late_pct = 100.0 * f["late"] / f["ticks"] if f["ticks"] and f["late"] is not None else None
            age = now - agg.updated
            out.append({"id": aid, **f, "late_pct": None if late_pct is None else round(late_pct, 4),
                        "bad_keys": agg.bad_keys, "serving": sorted(agg.subjects),
                        "age_s": round(age, 3), "stale": age > self.stale_after_s})
        return out
