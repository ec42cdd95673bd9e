"""Every figure of a stats message, declared once.

A stats message (``limbstream/<subject>/stats``, JSON, about 1 Hz) has three scopes of fields:

- ``device``: one entry per device of the subject (``"devices": [...]``);
- ``subject``: top-level fields of the subject's message;
- ``aggregator``: the loop figures of the aggregator that sent it (``"aggregator": {...}``).

The stats codec (:mod:`.stats`), the dashboard's response models, its per-device history, its
Prometheus families and docs/protocol.md's field list all come from :data:`FIELDS`. Adding a
field is one row here plus the code that computes it (docs/protocol.md, "How to add a field").
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Scope = Literal["device", "subject", "aggregator"]


@dataclass(frozen=True)
class StatsField:
    """One field of a stats message.

    Attributes
    ----------
    name : JSON key.
    type : ``float``, ``int``, ``bool``, ``str`` or ``dict`` (of str -> number). Every value may
        also be null (not known yet, or not finite).
    scope : ``device``, ``subject`` or ``aggregator``.
    help : one line for people: what it is, with its unit.
    unit : unit symbol (``deg``, ``s``, ``1/s``, ...), empty when it has none.
    chart : the dashboard keeps a per-device time series of it (device scope, numbers only).
    metric : Prometheus family name, or empty for none (device and aggregator scopes).
    counter : the Prometheus family is a counter (it only grows within a stream), else a gauge.
    """

    name: str
    type: type
    scope: Scope
    help: str
    unit: str = ""
    chart: bool = False
    metric: str = ""
    counter: bool = False


def _device(name, type_, help_, unit="", chart=False, metric="", counter=False) -> StatsField:
    return StatsField(name, type_, "device", help_, unit, chart, metric, counter)


def _aggregator(name, type_, help_, unit="", metric="", counter=False) -> StatsField:
    return StatsField(name, type_, "aggregator", help_, unit, False, metric, counter)


FIELDS: tuple[StatsField, ...] = (
    # ---- per device
    _device("device", str, "device id: subject/segment"),
    _device("segment", str, "segment name"),
    _device("subject", str, "subject name"),
    _device("online", bool, "the device's liveliness token is present"),
    _device("samples", int, "samples the device took in this stream (from sample indices)",
            metric="limbstream_device_samples", counter=True),
    _device("points", int, "segment points received in this stream",
            metric="limbstream_device_points", counter=True),
    _device("icr", float, "inverse compression ratio: points / samples (0..1)", chart=True,
            metric="limbstream_device_icr"),
    _device("msgs_per_s", float, "segment-point messages received per second (5 s window)", "1/s", chart=True,
            metric="limbstream_device_messages_per_second"),
    _device("bytes_per_s", float, "segment-point bytes received per second (5 s window)", "B/s", chart=True,
            metric="limbstream_device_bytes_per_second"),
    _device("aad_deg", float, "average angular deviation of exact frames from the truth tap (the aggregator's error window, --error-window)", "deg",
            chart=True, metric="limbstream_device_aad_degrees"),
    _device("p99_deg", float, "99th percentile of that deviation (the aggregator's error window, --error-window)", "deg", chart=True,
            metric="limbstream_device_p99_degrees"),
    _device("max_deg", float, "largest such deviation (the aggregator's error window, --error-window)", "deg", chart=True,
            metric="limbstream_device_max_degrees"),
    _device("live_err_deg", float, "mean live-view error: the newest segment point at or before each truth "
            "sample, extrapolated to it with its rate (held without one), against the sample (the aggregator's error window, --error-window)", "deg",
            chart=True, metric="limbstream_device_live_error_degrees"),
    _device("live_p50_deg", float, "median of that live-view error (the aggregator's error window, --error-window)", "deg",
            metric="limbstream_device_live_p50_degrees"),
    _device("live_p99_deg", float, "99th percentile of that live-view error (the aggregator's error window, --error-window)", "deg", chart=True,
            metric="limbstream_device_live_p99_degrees"),
    _device("live_max_deg", float, "largest live-view error against the true segment: the live bound's error plus "
            "the sensor's fusion and calibration errors (the aggregator's error window, --error-window)", "deg",
            metric="limbstream_device_live_max_degrees"),
    _device("live_own_p99_deg", float, "99th percentile of the live-view error against the device's own orientation "
            "(what its kernel compressed; truth tap v3; the aggregator's error window, --error-window)", "deg",
            metric="limbstream_device_live_own_p99_degrees"),
    _device("live_own_max_deg", float, "largest live-view error against the device's own orientation: what its live "
            "bound holds, at most live_bound_deg (the aggregator's error window, --error-window)", "deg", chart=True,
            metric="limbstream_device_live_own_max_degrees"),
    _device("live_latency_p50_ms", float, "median live latency: live frame publication (wall clock) minus the "
            "device time the frame shows (last 3000 live frames)", "ms",
            metric="limbstream_device_live_latency_p50_milliseconds"),
    _device("live_latency_p99_ms", float, "99th percentile of that live latency", "ms", chart=True,
            metric="limbstream_device_live_latency_p99_milliseconds"),
    _device("aad_all_deg", float, "average angular deviation of exact frames since the stream began", "deg"),
    _device("error_samples", int, "truth samples compared since the stream began"),
    _device("watermark_lag_s", float, "device time since its newest segment point", "s", chart=True,
            metric="limbstream_device_watermark_lag_seconds"),
    _device("gaps", int, "segment points of the stream missing (sequence gaps not filled from the device's cache; goes down when a gap is filled)", metric="limbstream_device_gaps", counter=True),
    _device("dropped", int, "messages dropped as invalid (all reasons)", metric="limbstream_device_dropped",
            counter=True),
    _device("dropped_by_reason", dict, "dropped messages by reason"),
    _device("threshold", float, "fastSW SSR threshold the device runs (asked every 5 s)",
            metric="limbstream_device_threshold"),
    _device("max_len", int, "max segment length the device runs", "samples", metric="limbstream_device_max_len"),
    _device("live_bound_deg", float, "fastSW live-rule bound the device runs (0: off)", "deg",
            metric="limbstream_device_live_bound_degrees"),
    _device("calibrated", bool, "the device's readings are corrected to its segment's orientation (a calibration "
            "of its current stream; aggregate --calibrate-on-start)", metric="limbstream_device_calibrated"),
    _device("calibration_age_s", float, "time since that calibration (null: none)", "s"),
    _device("calibration_refused", str, "why the stream's calibration was refused (null: it was not)"),
    _device("heading_drift_dps", float, "the sensor heading's drift learned from the last two heading measurements "
            "(rest or yaw reset, then a yaw reset) and compensated (null: not calibrated)", "deg/s"),
    _device("heading_offset_deg", float, "the turn about the vertical applied to the device's calibrated "
            "orientation now, learnt from the subject's joints (aggregate --heading-correction; null: none, the "
            "device is not corrected)", "deg", chart=True, metric="limbstream_device_heading_offset_degrees"),
    _device("heading_rate_dpm", float, "the rate at which that correction changes (the heading drift it follows "
            "relative to the other devices)", "deg/min", metric="limbstream_device_heading_rate_degrees_per_minute"),
    _device("heading_confidence", float, "how well the correction is known (0..1: 1 within a degree or two, 1/2 at "
            "5 deg, towards 0 as it is lost, e.g. a joint that never moves)",
            metric="limbstream_device_heading_confidence"),
    _device("stream", int, "the device's current stream id (a new one after a restart)"),
    _device("restarts", int, "new streams seen after the first", metric="limbstream_device_restarts", counter=True),
    _device("final", bool, "the stream ended (its last point carried FINAL)"),
    _device("clock_offset_ms", float, "device clock minus the common time base, the device's own estimate "
            "(its status; null without sync)", "ms", chart=True, metric="limbstream_device_clock_offset_milliseconds"),
    _device("sync_rtt_ms", float, "round trip of the device's last valid time exchange", "ms",
            metric="limbstream_device_sync_rtt_milliseconds"),
    _device("synced", bool, "the device stamps on the common time base (a valid time answer within its holdover)",
            metric="limbstream_device_synced"),
    _device("sync_bad", dict, "time answers the device discarded, by reason"),
    _device("tracker", str, "the real device a gateway bridges in (SlimeVR: MAC/sensor; null: not bridged)"),
    _device("battery_pct", float, "battery level of the bridged device (its status; null: not reported)", "%",
            chart=True, metric="limbstream_device_battery_percent"),
    _device("signal_dbm", float, "radio signal strength of the bridged device", "dBm",
            metric="limbstream_device_signal_dbm"),
    _device("link_loss", float, "fraction of the bridged device's packets lost on the way to its gateway",
            metric="limbstream_device_link_loss_ratio"),
    _device("link_pps", float, "packets per second the gateway receives from the bridged device", "1/s",
            metric="limbstream_device_link_packets_per_second"),
    _device("fusion", str, "the fusion filter of a device fed raw IMU samples: 6D or 9D (its status; null: the "
            "device is handed orientations)"),
    _device("gyro_bias_dps", float, "size of that filter's gyroscope bias estimate (its status, asked every 5 s)",
            "deg/s", chart=True, metric="limbstream_device_gyro_bias_degrees_per_second"),
    _device("at_rest", bool, "that filter detects rest (its status, asked every 5 s)", metric="limbstream_device_at_rest"),
    _device("raw_faults", dict, "bad raw samples the device counted, by kind (invalid, time_back, gap, saturated, "
            "gyr_stuck; docs/kernel.md)"),
    # ---- per subject
    StatsField("frames", int, "subject", "exact frames made (sent while a subscriber matches the subject's pose key)"),
    StatsField("skipped_frames", int, "subject", "frame times skipped (no data could make them)"),
    StatsField("live_missed", int, "subject", "live frame deadlines missed: the aggregator's loop came more than half a "
               "live period after the deadline, no live frame for it"),
    StatsField("watermark_us", int, "subject", "exact frames are final up to this device time", "us"),
    StatsField("frame_aad_deg", float, "subject", "mean angle between each exact frame's segments and the truth at "
               "the frame's reference instant (alignment-aware error; the segments a frame has, not those it holds as MISSING nor those inside a span of their device's lost points (GAP); truth tap with reference times; the aggregator's error window, --error-window)",
               "deg"),
    StatsField("joint_aad_deg", float, "subject", "mean angle between the estimated and the true relative orientation "
               "of each pair of adjacent segments (the joints) in the exact frames compared for frame_aad_deg; which "
               "way the subject faces does not change it (the aggregator's error window, --error-window)", "deg"),
    StatsField("heading_contradicted", dict, "subject", "the joints whose constraints the subject's motion "
               "contradicts (a hinge bending about another axis, a joint out of range at any heading: its rest pose is "
               "not what it says), each with its share of the last minute; its heading correction stopped (null: "
               "not found, or no correction)"),
    StatsField("frame_error_frames", int, "subject", "exact frames compared with the truth so far"),
    StatsField("facing_deg", float, "subject", "the turn about the vertical from the calibrated frames to the truth's "
               "world, fitted from the first frames compared after the subject's calibration (0: none fitted)", "deg"),
    StatsField("layout", str, "subject", "the subject's body layout, its frames' (docs/body.md): the one its "
               "devices' status body names, else the smallest built-in layout holding its devices' segments "
               "(docs/protocol.md, \"Body layouts in the aggregator\")"),
    StatsField("height_m", float, "subject", "the wearer's height in the body its devices announce (null: none "
               "announced, or one given bone by bone)", "m"),
    StatsField("bones_m", dict, "subject", "the bone lengths of the body its devices announce, by bone of the "
               "layout: its frames' joint positions are drawn with them (null: none announced)", "m"),
    # ---- the aggregator's own loop
    _aggregator("id", str, "host:pid of the aggregator process"),
    _aggregator("subjects", int, "subjects it tracks", metric="limbstream_aggregator_subjects"),
    _aggregator("ticks", int, "loop ticks (one per 20 ms)", metric="limbstream_aggregator_ticks", counter=True),
    _aggregator("late", int, "ticks that started more than one period late",
                metric="limbstream_aggregator_late_ticks", counter=True),
    _aggregator("late_own", int, "of the late ticks, those late by the loop's own work: they would have been "
                "late had every tick taken only its CPU time and the loop never waited for a core (what load on "
                "the machine does not change)"),
    _aggregator("points", int, "segment points taken in"),
    _aggregator("raw_batches", int, "truth-tap batches taken in"),
    _aggregator("frames", int, "exact frames made, all subjects"),
    _aggregator("unheard", int, "pose frames (exact and live) made but not sent, as no subscriber matched their "
                "subject's pose key at the time (docs/protocol.md, \"Pose frame\")"),
    _aggregator("missed", int, "segment points Zenoh reported missed that the device's cache did not give when the aggregator asked again either",
                metric="limbstream_aggregator_missed_points", counter=True),
    _aggregator("max_backlog", int, "most messages waiting at one tick since start"),
    _aggregator("recent_backlog", int, "most messages waiting at one tick, last second",
                metric="limbstream_aggregator_backlog_messages"),
    _aggregator("busy_s", float, "time spent working since start", "s"),
    _aggregator("load", float, "share of the last second spent working (>= 1: falling behind)",
                metric="limbstream_aggregator_load"),
    _aggregator("max_tick_ms", float, "longest tick since start", "ms"),
    _aggregator("recent_max_tick_ms", float, "longest tick in the last second", "ms",
                metric="limbstream_aggregator_tick_max_milliseconds"),
    _aggregator("bad_keys", dict, "messages no device could be charged with, by reason"),
)
"""The stats fields, in message order."""


def scope(name: Scope) -> tuple[StatsField, ...]:
    """The fields of one scope, in message order."""
    return tuple(f for f in FIELDS if f.scope == name)


DEVICE_FIELDS = scope("device")
SUBJECT_FIELDS = scope("subject")
AGGREGATOR_FIELDS = scope("aggregator")
STATS_FIELDS: tuple[str, ...] = tuple(f.name for f in DEVICE_FIELDS)
"""Names of the fields of every device entry."""
AGGREGATOR_FIGURES: tuple[StatsField, ...] = tuple(f for f in AGGREGATOR_FIELDS if f.type in (int, float))
"""The numbers among the aggregator's fields."""
HISTORY_FIELDS: tuple[str, ...] = tuple(f.name for f in DEVICE_FIELDS if f.chart)
"""Per-device series the dashboard keeps for its charts."""
