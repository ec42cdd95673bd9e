"""Prometheus exposition: per-device gauges read from the live state at scrape time."""
from __future__ import annotations

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector, CollectorRegistry

from limbstream import wire

from .state import LiveState
from .views import Views

LABELS = ["subject", "segment"]
DEVICE_METRICS = tuple(f for f in wire.DEVICE_FIELDS if f.metric)
AGGREGATOR_METRICS = tuple(f for f in wire.AGGREGATOR_FIELDS if f.metric)


def _family(f: wire.StatsField, labels: list[str]):
    unit = f", {f.unit}" if f.unit else ""
    return (CounterMetricFamily if f.counter else GaugeMetricFamily)(f.metric, f.help + unit, labels=labels)


class LiveCollector(Collector):
    """Reads :class:`LiveState` and its views on each scrape (``/metrics`` is async: it runs on the
    event loop, which owns the state)."""

    def __init__(self, live: LiveState, views: Views):
        self.live, self.views = live, views

    def collect(self):
        views = self.views.device_views()
        for f in DEVICE_METRICS:
            family = _family(f, LABELS)
            for v in views:
                if v.get(f.name) is not None:
                    family.add_metric([v["subject"], v["segment"]], float(v[f.name]))
            yield family
        online = GaugeMetricFamily("limbstream_device_online", "1 if the device is online", labels=LABELS)
        for v in views:
            online.add_metric([v["subject"], v["segment"]], 1.0 if v["online"] else 0.0)
        yield online
        live = self.live
        aggregators = self.views.aggregator_views()
        for f in AGGREGATOR_METRICS:
            family = _family(f, ["aggregator"])
            for a in aggregators:
                if a[f.name] is not None:
                    family.add_metric([a["id"]], a[f.name])
            yield family
        bad = CounterMetricFamily("limbstream_aggregator_bad_keys", "messages no device could be charged with",
                                  labels=["aggregator", "reason"])
        for a in aggregators:
            for reason, n in a["bad_keys"].items():
                bad.add_metric([a["id"], reason], n)
        yield bad
        yield GaugeMetricFamily("limbstream_dashboard_stream_clients", "connected WebSocket/SSE clients",
                                value=live.fanout.count())
        yield CounterMetricFamily("limbstream_dashboard_frames_skipped", "frames skipped for slow clients",
                                  value=live.fanout.skipped_total())
        received = CounterMetricFamily("limbstream_dashboard_received", "Zenoh messages received", labels=["kind"])
        for kind, n in sorted(live.received.items()):
            received.add_metric([kind], n)
        yield received
        missed = CounterMetricFamily("limbstream_dashboard_missed", "stats and pose messages lost on the way "
                                     "(sequence gaps)", labels=["stream"])
        for stream, n in sorted(live.missed.items()):
            missed.add_metric([stream], n)
        yield missed
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


def build_registry(live: LiveState, views: Views) -> CollectorRegistry:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(LiveCollector(live, views))
    return registry
