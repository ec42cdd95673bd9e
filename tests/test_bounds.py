"""Every device tunable is bounded once (limbstream.wire.TUNABLES) and refused identically on
every path: the command line, the dashboard's REST body, a device's config queryable (a real
emulator behind a real router) and the kernel binding."""
from __future__ import annotations

import argparse
import json
import math

import pytest
from fastapi.testclient import TestClient
from support.stack import stack, wait_until  # noqa: F401  (the fixture)

from limbstream.cli import flags
from limbstream import kernel, wire, zconfig
from limbstream.cli import up
from limbstream.services.dashboard.app import create_app
from limbstream.services.dashboard.settings import DashboardSettings


def bad_values(t: wire.Tunable) -> list:
    """Values every path must refuse: below and above the bounds, NaN, infinity, a string, a
    boolean, and for integers a fraction."""
    values = [t.low - 1, t.high * 2 + 1, math.nan, math.inf, "twelve", True]
    return values + ([t.low + 0.5] if t.type is int else [])


CASES = [(t, v) for t in wire.TUNABLES.values() for v in bad_values(t)]
IDS = [f"{t.name}={v!r}" for t, v in CASES]


def expected_message(t: wire.Tunable, value) -> str:
    with pytest.raises(ValueError) as info:
        t.check(value)
    message = str(info.value)
    assert message.startswith(f"{t.name} must be {t.describe()}"), message
    return message


@pytest.mark.parametrize("t, value", CASES, ids=IDS)
def test_cli_refuses_with_the_contract_message(t, value, capsys):
    """``limbstream emulate`` and ``limbstream up`` (the same flags): exit 2, the flag and the
    contract's sentence."""
    for add_arguments in (flags.add_device_config, up.add_arguments):
        parser = argparse.ArgumentParser(prog="limbstream")
        add_arguments(parser)
        with pytest.raises(SystemExit) as exit_info:
            parser.parse_args([t.flag, str(value)])
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert t.flag in err and f"{t.name} must be {t.describe()}, got" in err, err


@pytest.mark.parametrize("t, value", CASES, ids=IDS)
def test_queryable_codec_refuses_with_the_contract_message(t, value):
    message = expected_message(t, value)
    payload = json.dumps({t.name: value}).encode()  # NaN / Infinity: Python's JSON extension
    with pytest.raises(wire.WireError) as info:
        wire.decode_config(payload, wire.DeviceConfig())
    assert info.value.reason == "config" and message in str(info.value), (message, str(info.value))


def test_rest_refuses_with_the_contract_message():
    settings = DashboardSettings(router="tcp/127.0.0.1:1", api_token="tok", config_timeout_s=0.5)
    with TestClient(create_app(settings)) as client:
        for t, value in CASES:
            if isinstance(value, float) and not math.isfinite(value):
                continue  # strict JSON has no NaN / Infinity: such a body is not JSON at all
            r = client.put("/api/devices/s01/hip/config", json={t.name: value},
                           headers={"Authorization": "Bearer tok"})
            assert r.status_code == 422 and expected_message(t, value) in r.text, (t.name, value, r.text)
        r = client.put("/api/devices/s01/hip/config", content=b'{"threshold": NaN}',
                       headers={"Authorization": "Bearer tok", "Content-Type": "application/json"})
        assert r.status_code == 422, r.text


@pytest.mark.parametrize("t, value", [c for c in CASES if isinstance(c[1], (int, float)) and not isinstance(c[1], bool)],
                         ids=[i for c, i in zip(CASES, IDS) if isinstance(c[1], (int, float)) and not isinstance(c[1], bool)])
def test_kernel_binding_refuses_with_the_contract_message(t, value):
    settings = {name: tunable.default for name, tunable in wire.TUNABLES.items()} | {t.name: value}
    with pytest.raises(ValueError, match=f"^{t.name} must be"):
        kernel.make_settings(settings["threshold"], settings["max_len"], 4, settings["live_bound_deg"])


def test_a_live_device_refuses_and_keeps_its_config(stack):  # noqa: F811
    """A real emulator's queryable answers every bad value with the contract's message in an
    error reply and keeps running with its settings; a partial update keeps the other values
    (``--max-len 100000`` at start, then a threshold-only update: once a 502)."""
    stack.router()
    stack.emulator(1, 1.0, "--max-len", str(wire.MAX_LEN.high), "--no-truth")
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    key = wire.config_key("s01", "hip")
    try:
        def status():
            replies = list(session.get(key, timeout=5.0))
            return wire.decode_status(replies[0].ok.payload.to_bytes()) if replies and replies[0].ok else None

        before = wait_until(status, 30, "the device's config queryable")
        assert before.config.max_len == wire.MAX_LEN.high, before
        for t, value in CASES:
            replies = list(session.get(key, payload=json.dumps({t.name: value}).encode(), timeout=5.0))
            assert len(replies) == 1 and replies[0].err is not None, (t.name, value)
            error = json.loads(replies[0].err.payload.to_bytes())["error"]
            assert expected_message(t, value) in error, (t.name, value, error)
        assert status().config == before.config, "a refused update changed the device"
        replies = list(session.get(key, payload=b'{"threshold": 0.5}', timeout=5.0))
        after = wire.decode_status(replies[0].ok.payload.to_bytes())
        assert after.config == wire.DeviceConfig(0.5, wire.MAX_LEN.high), after
    finally:
        session.close()
