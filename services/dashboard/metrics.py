"""Prometheus exposition: per-device gauges read from the live state at scrape time."""
from __future__ import annotations

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector, CollectorRegistry

from .state import LiveState

DEVICE_GAUGES = {
    "msgs_per_s": ("limbstream_device_messages_per_second", "segment-point messages per second received"),
    "bytes_per_s": ("limbstream_device_bytes_per_second", "segment-point bytes per second received"),
    "icr": ("limbstream_device_icr", "segment points over samples (0..1)"),
    "aad_deg": ("limbstream_device_aad_degrees", "average angular deviation of exact frames, degrees"),
    "p99_deg": ("limbstream_device_p99_degrees", "99th percentile angular deviation, degrees"),
    "max_deg": ("limbstream_device_max_degrees", "maximum angular deviation, degrees"),
    "live_err_deg": ("limbstream_device_live_error_degrees", "angular error of live frames, degrees"),
    "watermark_lag_s": ("limbstream_device_watermark_lag_seconds", "lag of the exact-frame watermark, s"),
    "threshold": ("limbstream_device_threshold", "fastSW threshold in use"),
}
DEVICE_COUNTERS = {
    "samples": ("limbstream_device_samples", "samples the device took"),
    "points": ("limbstream_device_points", "segment points received"),
    "gaps": ("limbstream_device_gaps", "sequence gaps detected"),
    "dropped": ("limbstream_device_dropped", "bad segment-point payloads dropped"),
}
LABELS = ["subject", "segment"]
AGGREGATOR_METRICS = {  # figure: (metric, help, counter?)
    "ticks": ("limbstream_aggregator_ticks", "loop ticks", True),
    "late": ("limbstream_aggregator_late_ticks", "ticks started more than one period late", True),
    "missed": ("limbstream_aggregator_missed_points", "segment points lost for good (Zenoh miss detection)", True),
    "load": ("limbstream_aggregator_load", "share of the last second spent working (>= 1: falling behind)", False),
    "recent_max_tick_ms": ("limbstream_aggregator_tick_max_milliseconds", "longest tick in the last second, ms",
                           False),
    "recent_backlog": ("limbstream_aggregator_backlog_messages", "most messages waiting at one tick, last second",
                       False),
    "subjects": ("limbstream_aggregator_subjects", "subjects the aggregator tracks", False),
}


class LiveCollector(Collector):
    """Reads :class:`LiveState` on each scrape (``/metrics`` is async: it runs on the event loop,
    which owns the state)."""

    def __init__(self, live: LiveState):
        self.live = live

    def collect(self):
        views = self.live.device_views()
        for key, (name, doc) in DEVICE_GAUGES.items():
            family = GaugeMetricFamily(name, doc, labels=LABELS)
            for v in views:
                if v.get(key) is not None:
                    family.add_metric([v["subject"], v["segment"]], float(v[key]))
            yield family
        for key, (name, doc) in DEVICE_COUNTERS.items():
            family = CounterMetricFamily(name, doc, labels=LABELS)
            for v in views:
                if v.get(key) is not None:
                    family.add_metric([v["subject"], v["segment"]], float(v[key]))
            yield family
        online = GaugeMetricFamily("limbstream_device_online", "1 if the device is online", labels=LABELS)
        for v in views:
            online.add_metric([v["subject"], v["segment"]], 1.0 if v["online"] else 0.0)
        yield online
        live = self.live
        aggregators = live.aggregator_views()
        for key, (name, doc, counter) in AGGREGATOR_METRICS.items():
            family = (CounterMetricFamily if counter else GaugeMetricFamily)(name, doc, labels=["aggregator"])
            for a in aggregators:
                if a[key] is not None:
                    family.add_metric([a["id"]], a[key])
            yield family
        bad = CounterMetricFamily("limbstream_aggregator_bad_keys", "messages no device could be charged with",
                                  labels=["aggregator", "reason"])
        for a in aggregators:
            for reason, n in a["bad_keys"].items():
                bad.add_metric([a["id"], reason], n)
        yield bad
        yield GaugeMetricFamily("limbstream_dashboard_stream_clients", "connected WebSocket/SSE clients",
                                value=live.client_count())
        skipped = live.clients_skipped + sum(c.skipped for g in live.clients.values() for c in g)
        yield CounterMetricFamily("limbstream_dashboard_frames_skipped", "frames skipped for slow clients",
                                  value=skipped)
        received = CounterMetricFamily("limbstream_dashboard_received", "Zenoh messages received", labels=["kind"])
        for kind, n in sorted(live.received.items()):
            received.add_metric([kind], n)
        yield received
        errors = CounterMetricFamily("limbstream_dashboard_errors", "messages dropped as invalid", labels=["reason"])
        for reason, n in sorted(live.errors.items()):
            errors.add_metric([reason], n)
        yield errors
        if live.inbox is not None:
            dropped = CounterMetricFamily("limbstream_dashboard_handoff_dropped",
                                          "messages dropped or coalesced in the hand-off", labels=["kind"])
            for kind, n in sorted(live.inbox.dropped.items()):
                dropped.add_metric([kind], n)
            yield dropped


def build_registry(live: LiveState) -> CollectorRegistry:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(LiveCollector(live))
    return registry
