"""The device host (limbstream.device.host) on a real Zenoh session: a subject's config queryable
answers each device it names with its status, applies a good config, refuses a bad payload for
all with one error, and a device that cannot answer with its own error while the others answer;
devices come online and go offline with their liveliness tokens."""
from __future__ import annotations

import json
import threading

import pytest
import zenoh

from limbstream import wire, zconfig
from limbstream.device.host import Device, DeviceHost, HostSettings, Refused


@pytest.fixture
def host():
    session = zconfig.open_session(zconfig.ZenohSettings(mode="peer", connect=()))
    configs: list[tuple[str, wire.DeviceConfig]] = []

    def configure(d: Device, config: wire.DeviceConfig) -> None:
        configs.append((d.id, config))
        d.config = config

    def status(d: Device) -> wire.DeviceStatus:
        if d.segment == "neck":
            raise Refused("neck: link down")
        return wire.DeviceStatus(d.id, d.config, 7, 100, 10)

    h: DeviceHost = DeviceHost(session, HostSettings(truth=False), configure, status)
    for segment in ("hip", "neck", "l_thigh"):
        h.add("s01", segment)
    h.declare()
    stop = threading.Event()

    def serve() -> None:  # as a device loop does between its ticks
        while not stop.wait(0.005):
            h.answer_queries()

    server = threading.Thread(target=serve)
    server.start()
    yield h, session, configs
    stop.set()
    server.join()
    h.close()
    session.close()


def ask(session: zenoh.Session, key: str, payload: dict | bytes | None = None) -> tuple[dict, list[str]]:
    body = json.dumps(payload).encode() if isinstance(payload, dict) else payload
    ok, errors = {}, []
    for reply in session.get(key, payload=body, timeout=5.0):
        if reply.ok is not None:
            status = wire.decode_status(reply.ok.payload.to_bytes())
            ok[status.device] = status
        else:
            errors.append(json.loads(reply.err.payload.to_bytes())["error"])
    return ok, errors


def test_config_queries_are_answered_per_device(host):
    h, session, configs = host
    for d in h.devices:
        h.online(d)
    ok, errors = ask(session, wire.device_selector("config", "s01"))
    assert set(ok) == {"s01/hip", "s01/l_thigh"} and errors == ["neck: link down"], (ok, errors)
    ok, errors = ask(session, wire.config_key("s01", "hip"), {"threshold": 2e-3})
    assert ok["s01/hip"].config.threshold == 2e-3 and configs == [("s01/hip", ok["s01/hip"].config)]
    ok, errors = ask(session, wire.device_selector("config", "s01"), {"max_len": 0})
    assert not ok and len(errors) == 1 and errors[0].startswith("config: max_len"), errors  # refused for all, once
    assert len(configs) == 1


def test_offline_devices_answer_nothing_and_lose_their_token(host):
    h, session, _ = host
    hip = h.by_id["s01/hip"]
    h.online(hip)
    alive = {str(r.ok.key_expr) for r in session.liveliness().get(wire.device_selector("alive"), timeout=2.0) if r.ok}
    assert alive == {wire.alive_key("s01", "hip")}
    ok, errors = ask(session, wire.device_selector("config", "s01"))
    assert set(ok) == {"s01/hip"} and not errors
    h.offline(hip)
    assert not hip.online and not list(session.liveliness().get(wire.device_selector("alive"), timeout=2.0))
    assert ask(session, wire.config_key("s01", "hip")) == ({}, [])

