"""The dashboard's Zenoh side: subscriptions that feed the :class:`~.inbox.Inbox`, and the
device-config, calibration and gateway queries.

Nothing here opens a session at import time; :func:`open_bridge` runs in the app lifespan.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass

import zenoh

from limbstream import wire, zconfig

from .inbox import Inbox

log = logging.getLogger("limbstream.dashboard")

STATS_SELECTOR = wire.subject_selector(wire.STATS)
POSE_SELECTOR = wire.subject_selector(wire.POSE)
ANGLES_SELECTOR = wire.subject_selector(wire.ANGLES)
ALIVE_SELECTOR = wire.device_selector(wire.ALIVE)


class ConfigError(Exception):
    """A device config query failed. ``status`` is the HTTP status to answer with."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


@dataclass
class Bridge:
    """An open session with its subscribers. ``close()`` undeclares them (and closes the
    session if the bridge opened it)."""

    session: zenoh.Session
    owns_session: bool
    subscribers: list

    def close(self) -> None:
        for sub in self.subscribers:
            try:
                sub.undeclare()
            except zenoh.ZError:
                pass
        self.subscribers.clear()
        if self.owns_session:
            self.session.close()


def open_bridge(inbox: Inbox, settings: zconfig.ZenohSettings | None = None,
                session: zenoh.Session | None = None) -> Bridge:
    """Subscribe to every subject's stats, pose and joint-angle streams and to device liveliness.

    Parameters
    ----------
    inbox : where callbacks hand the payloads off (they do nothing else).
    settings : used to open a session when ``session`` is None.
    session : an already open session (not closed by :meth:`Bridge.close`).
    """
    owns = session is None
    if session is None:
        session = zconfig.open_session(settings or zconfig.ZenohSettings())

    def on_stats(sample: zenoh.Sample) -> None:
        inbox.put_stats(str(sample.key_expr), sample.payload.to_bytes())

    def on_pose(sample: zenoh.Sample) -> None:
        inbox.put_pose(str(sample.key_expr), sample.payload.to_bytes())

    def on_angles(sample: zenoh.Sample) -> None:
        inbox.put_angles(str(sample.key_expr), sample.payload.to_bytes())

    def on_alive(sample: zenoh.Sample) -> None:
        inbox.put_alive(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

    subs = [
        session.declare_subscriber(STATS_SELECTOR, on_stats),
        session.declare_subscriber(POSE_SELECTOR, on_pose),
        session.declare_subscriber(ANGLES_SELECTOR, on_angles),
        session.liveliness().declare_subscriber(ALIVE_SELECTOR, on_alive, history=True),
    ]
    return Bridge(session, owns, subs)


def query_config(session: zenoh.Session, subject: str, segment: str, update: dict | None,
                 timeout_s: float) -> wire.DeviceStatus:
    """Send ``update`` (some tunables, e.g. ``{"threshold": 0.001}``) to a device, or read its
    status when None, and return the status the device confirms.

    Blocking: run it in a worker thread. Raises :class:`ConfigError` with status 504 (no
    reply within ``timeout_s``), 422 (the device refused it: its message) or 502 (a reply
    that is not a device status).
    """
    key = wire.config_key(subject, segment)
    payload = None if update is None else wire.encode_config(update)
    replies = session.get(key, payload=payload, timeout=timeout_s)
    rejected, broken = [], []
    for reply in replies:
        if reply.ok is not None:
            try:
                return wire.decode_status(reply.ok.payload.to_bytes())
            except wire.WireError as exc:
                broken.append(str(exc))
                continue
        raw = reply.err.payload.to_bytes()
        try:
            rejected.append(str(json.loads(raw).get("error", raw.decode(errors="replace"))))
        except (ValueError, AttributeError):
            rejected.append(raw.decode(errors="replace"))
    if rejected:
        raise ConfigError(422, f"device {subject}/{segment} rejected the config: {'; '.join(rejected)}")
    if broken:
        raise ConfigError(502, f"device {subject}/{segment} answered with a bad config: {'; '.join(broken)}")
    raise ConfigError(504, f"device {subject}/{segment} did not confirm within {timeout_s:g} s")


def query_calibrate(session: zenoh.Session, subject: str, pose: str, timeout_s: float) -> wire.CalibrateAnswer:
    """Ask the aggregator serving ``subject`` to calibrate its devices from ``pose`` (blocking:
    run it in a worker thread). Raises :class:`ConfigError`: 504 (no aggregator answered within
    ``timeout_s``), 502 (an error or a bad answer)."""
    replies = session.get(wire.calibrate_key(subject), payload=wire.encode_calibrate_request(pose), timeout=timeout_s)
    for reply in replies:
        if reply.ok is None:
            raise ConfigError(502, f"the aggregator failed the calibration: {reply.err.payload.to_string()}")
        try:
            return wire.decode_calibrate_answer(reply.ok.payload.to_bytes())
        except wire.WireError as exc:
            raise ConfigError(502, str(exc)) from None
    raise ConfigError(504, f"no aggregator serving {subject} answered within {timeout_s:g} s")


def query_gateways(session: zenoh.Session, timeout_s: float) -> list[dict]:
    """Every reachable gateway's sensor listing (wire.gateway), sorted by name (blocking: run it
    in a worker thread). A reply that is not a listing is logged and left out."""
    gateways = []
    for reply in session.get(wire.gateway_selector(), timeout=timeout_s):
        try:
            if reply.ok is None:
                raise wire.WireError("gateway", reply.err.payload.to_string())
            gateways.append(wire.decode_sensors(reply.ok.payload.to_bytes()))
        except wire.WireError as exc:
            log.warning("a gateway's listing left out: %s", exc)
    return sorted(gateways, key=lambda g: g["gateway"])


def query_assign(session: zenoh.Session, gateway: str, assignment: wire.Assignment, timeout_s: float) -> dict:
    """Ask gateway ``gateway`` to apply ``assignment``; its sensor listing after it (blocking:
    run it in a worker thread). Raises :class:`ConfigError`: 409 (refused: the gateway's
    sentence), 404 (no gateway of that name answered within ``timeout_s``), 502 (a bad answer)."""
    replies = session.get(wire.gateway_key(gateway), payload=wire.encode_assignment(assignment), timeout=timeout_s)
    for reply in replies:
        if reply.ok is None:
            raw = reply.err.payload.to_bytes()
            try:
                message = str(json.loads(raw)["error"])
            except (ValueError, KeyError, TypeError):
                message = raw.decode(errors="replace")
            raise ConfigError(409, message)
        try:
            return wire.decode_sensors(reply.ok.payload.to_bytes())
        except wire.WireError as exc:
            raise ConfigError(502, str(exc)) from None
    raise ConfigError(404, f"no gateway named {gateway} answered within {timeout_s:g} s")
