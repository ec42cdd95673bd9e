"""Why a receiver drops a device's message: every reason it counts, with the check it stands for.

A device's drops are counted on it by reason (stats ``dropped_by_reason``): its segment points'
(:data:`POINT_DROPS`) and its truth tap's (:data:`RAW_DROPS`). A message no device can be
charged with is counted per aggregator (stats ``bad_keys``, :data:`UNCHARGED`). docs/protocol.md
holds these tables as ``python -m limbstream.wire`` prints them.
"""
from __future__ import annotations

from .point import UNIT_TOLERANCE

POINT_DROPS: dict[str, str] = {
    "size": "payload is empty, or not the size of its version (36 bytes for 1, 48 for 2)",
    "version": "version byte is neither 1 nor 2",
    "non_finite": "a quaternion or rate component is NaN or ±Inf",
    "non_unit": f"quaternion norm outside 1 ± {UNIT_TOLERANCE:g}",
    "time_range": "device time outside [0, 2⁵³) µs",
    "duplicate": "sequence number below the next expected one (duplicate or late); exception: until a stream "
                 "is settled, earlier points of its start (history of a device the aggregator joined late, which "
                 "can arrive after live points) are inserted in time order. A stream is settled once its start is "
                 "complete, once the aggregator's own query of the device's cache for it has ended (see \"Joining "
                 "late\" above), or 5 s after its first point; and a point of a gap not filled yet (the device's "
                 "cache answering the aggregator's query for it, below) is inserted likewise, once",
    "time_backwards": "device time or sample index not after the previous point's (except the `FINAL` repeat of "
                      "the newest point, next sequence number: it ends the stream)",
    "stale_stream": "a stream id the device already replaced",
    "buffer_full": "the device's row of points in the aggregator is full: its oldest point is forgotten",
    "segment_not_in_layout": "the device's segment is not in its subject's body layout (\"Body layouts in the "
                             "aggregator\"): its points are left out, the rest of the subject streams",
}
"""Segment points dropped and counted on their device, by reason."""

RAW_DROPS: dict[str, str] = {
    "raw_size": "payload shorter than its header, with no samples, or not the size its count says",
    "raw_version": "version byte is not 1, 2 or 3",
    "raw_non_finite": "a quaternion component is NaN or ±Inf",
    "raw_time_backwards": "device or reference times going back within the batch",
    "raw_time_range": "device times outside [0, 2⁵³) µs",
    "raw_other_stream": "a batch of a stream that has ended (one of a stream whose first point has not arrived "
                        "yet is held, up to 16 per device, until it does)",
    "raw_before_first_point": "a sample older than the stream's first known segment point: nothing to compare it "
                              "with (counted per sample)",
    "raw_overflow": "more samples wait for their reconstruction than the aggregator keeps (counted per sample)",
    "raw_segment_not_in_layout": "a batch of a device whose segment is not in its subject's body layout (as "
                                 "`segment_not_in_layout`)",
}
"""Truth-tap batches (or their samples) dropped and counted on their device, by reason."""

STATUS_DROPS: dict[str, str] = {
    "status_body": "a device status whose `body` (its wearer's dimensions, \"Body dimensions\") is malformed: not "
                   "an object of `layout`, `height_m` and `bones`, a layout that is neither built in nor a good "
                   "layout table (\"Layout files on the wire\"), a bone missing, unknown or not in (0, 1.5] m, a "
                   "height outside [0.5, 2.5] m. The rest of the status is taken; the subject keeps the body it had",
    "status_layout": "a device status whose `body` is of another layout than its subject's, the one its devices "
                     "named first (\"Body layouts in the aggregator\"). The rest of the status is taken; the subject "
                     "keeps its layout and body",
}
"""Parts of a device's status dropped and counted on the device, by reason."""

UNCHARGED: dict[str, str] = {
    "key": "a key that is not a device key of the kind its subscription carries "
           "(`limbstream/<subject>/<segment>/seg` for segment points), or not a subject's `truth` key for a subject "
           "truth-tap message",
    "seg_undecodable": "a segment point that does not decode (`size`, `version`, `non_finite`, `non_unit`), on the key of a device not seen "
                       "before: no device is made for it",
    "raw_undecodable": "a truth-tap batch that does not decode, on the key of a device not seen before (or its "
                       "entry in a subject truth-tap message)",
    "truth_size": "a subject truth-tap message shorter than its header or one of its entries, with no entries "
                  "or more than 1024, or with bytes after its last entry (its batches are not taken in)",
    "truth_version": "a subject truth-tap message whose version byte is not 1",
    "truth_segment": "a subject truth-tap message with an entry that names no segment (not a key chunk) or names "
                     "one twice (a batch of it that does not decode counts on its device, as on its `raw` key)",
    "too_many_devices": "a message of a new device while the aggregator tracks its most devices (`max_devices`)",
    "config_reply": "a device's config reply (its status) that does not decode",
}
"""Messages no device can be charged with, counted per aggregator (``bad_keys``), by reason."""


def truth_reason(reason: str) -> str:
    """The :data:`UNCHARGED` reason of a subject truth-tap message its decoder refused with ``reason``."""
    return f"truth_{reason}"


def undecodable(kind: str) -> str:
    """The :data:`UNCHARGED` reason of an undecodable message of ``kind`` (``seg``, ``raw``)."""
    return f"{kind}_undecodable"


def device_reason(kind: str, reason: str) -> str:
    """The reason a device's message of ``kind`` (``seg``, ``raw``) that its decoder refused with
    ``reason`` is counted under: :data:`POINT_DROPS` as is, :data:`RAW_DROPS` prefixed."""
    return reason if kind == "seg" else f"{kind}_{reason}"
