"""The Zenoh objects of a device (its publishers, its liveliness token) and the answer to its
config queries (docs/protocol.md), for the device host (:mod:`limbstream.device.host`)."""
from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from typing import Any

import zenoh
import zenoh.ext as zext

from limbstream import wire, zconfig

log = logging.getLogger("limbstream.device")
RAW_CACHE = 64
"""Truth-tap batches a device keeps for recovery (32 s at 50 Hz in batches of 25)."""
RAW_HEARTBEAT_S = 0.5
"""A device's truth-tap publisher's miss-detection heartbeat period, s (periodic)."""
TRUTH_HEARTBEAT_S = 2.0
"""A subject's truth-tap publisher's miss-detection heartbeat period, s (sporadic: only after a
message went out since the last heartbeat)."""


def point_publisher(session: zenoh.Session, subject: str, segment: str, cache: int, heartbeat_s: float):
    """The segment point publisher: an advanced publisher with a cache of ``cache`` points (a
    router restart or a cut link costs nothing), miss detection and the "seg" options (never drop
    a point under load).

    Its miss-detection heartbeat is sporadic, every ``heartbeat_s`` seconds only if a point went
    out since the last one: a streaming device sends a point at least every ``max_len`` samples,
    and each point's sequence number already tells a subscriber what it missed before it; the
    heartbeat is what tells it, within ``heartbeat_s``, that it missed the last point before a
    pause (a FINAL point, a device that stops)."""
    return zext.declare_advanced_publisher(
        session, wire.seg_key(subject, segment),
        cache=zext.CacheConfig(max_samples=cache),
        sample_miss_detection=zext.MissDetectionConfig(sporadic_heartbeat=heartbeat_s),  # type: ignore[call-arg]  # (the stubs want every option)
        publisher_detection=True,
        **zconfig.publisher_options(wire.SEG),
    )


def raw_publisher(session: zenoh.Session, subject: str, segment: str):
    """The truth-tap publisher, recoverable too (:data:`RAW_CACHE`, heartbeat every
    :data:`RAW_HEARTBEAT_S`), so a cut link costs no evaluation samples."""
    return zext.declare_advanced_publisher(
        session, wire.raw_key(subject, segment), cache=zext.CacheConfig(max_samples=RAW_CACHE),
        sample_miss_detection=zext.MissDetectionConfig(heartbeat=RAW_HEARTBEAT_S),  # type: ignore[call-arg]
        publisher_detection=True, **zconfig.publisher_options(wire.RAW))


def truth_publisher(session: zenoh.Session, subject: str):
    """The subject truth-tap publisher (``limbstream/<subject>/truth``, one message per batch for
    all the subject's devices), recoverable as a device's (:data:`RAW_CACHE` messages). Its
    heartbeat is sporadic, every :data:`TRUTH_HEARTBEAT_S` only after a message went out: each
    message's sequence number shows a subscriber what it missed before it; the heartbeat shows
    a missed last message before a pause (a flushed tap, a host that stops)."""
    return zext.declare_advanced_publisher(
        session, wire.truth_key(subject), cache=zext.CacheConfig(max_samples=RAW_CACHE),
        sample_miss_detection=zext.MissDetectionConfig(sporadic_heartbeat=TRUTH_HEARTBEAT_S),  # type: ignore[call-arg]
        publisher_detection=True, **zconfig.publisher_options(wire.TRUTH))


def alive_token(session: zenoh.Session, subject: str, segment: str):
    """The device's liveliness token: it is online while the token is declared."""
    return session.liveliness().declare_token(wire.alive_key(subject, segment))


class Refused(Exception):
    """A device cannot apply or answer a config query now; the message is the error reply."""


def answer_config(query: zenoh.Query, targets: Sequence, apply: Callable[[Any, wire.DeviceConfig], None],
                  status: Callable[[Any], wire.DeviceStatus]) -> None:
    """Apply and answer one config query for the devices it names (``targets``: objects with
    ``config``, ``subject`` and ``segment``): a payload is decoded against each device's config
    and applied (``apply(device, config)``); every target replies with its status. A bad payload,
    or a device that refuses (:class:`Refused`), gets an error reply ``{"error": reason}``; a bad
    payload ends the query there (it is bad for every device)."""
    payload = query.payload.to_bytes() if query.payload is not None else b""
    for d in targets:
        try:
            if payload:
                config = wire.decode_config(payload, d.config)
                apply(d, config)
                log.info("%s/%s: %s", d.subject, d.segment, config)
            answer = status(d)
        except wire.WireError as exc:
            query.reply_err(json.dumps({"error": str(exc)}))
            return
        except Refused as exc:
            query.reply_err(json.dumps({"error": str(exc)}))
            continue
        query.reply(wire.config_key(d.subject, d.segment), wire.encode_status(answer))
