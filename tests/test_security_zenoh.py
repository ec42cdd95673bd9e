"""Zenoh security as shipped in deploy/zenoh/: TLS + user/password + access control, against the
Python router (``limbstream router --zenoh-config``) with real emulator and aggregator processes.

Certificates are made at test time with deploy/zenoh/make-certs.sh (openssl); the shipped
JSON files are used with their /etc/limbstream paths and passwords replaced.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time

import pytest
import zenoh
from support.stack import PAPER10, ROOT, stack, wait_until  # noqa: F401  (fixture)

from limbstream import wire, zconfig

DEPLOY = ROOT / "deploy" / "zenoh"
USERS = ("dev-s01", "dev-s02", "aggregator", "dashboard", "ops")


def _materialise(name: str, tmp, certs, passwords: dict) -> dict:
    """A shipped config with the cert paths, dictionary file and passwords of this test."""
    text = (DEPLOY / name).read_text().replace("/etc/limbstream/tls", str(certs))
    text = text.replace("/etc/limbstream/usrpwd.txt", str(tmp / "usrpwd.txt"))
    for user, password in passwords.items():
        text = text.replace(f"CHANGE-ME-{user}", password)
    return json.loads(text)


@pytest.fixture
def secure(stack, tmp_path):  # noqa: F811
    """A TLS router with user/password auth and the shipped ACL; returns client config makers."""
    if shutil.which("openssl") is None:
        pytest.fail("openssl is needed to make test certificates")
    certs = tmp_path / "tls"
    subprocess.run(["bash", str(DEPLOY / "make-certs.sh"), str(certs), "localhost", "127.0.0.1"], check=True,
                   capture_output=True)
    passwords = {u: f"pw-{u}-{time.monotonic_ns() % 10**8}" for u in (*USERS, "router")}
    (tmp_path / "usrpwd.txt").write_text("".join(f"{u}:{passwords[u]}\n" for u in USERS))
    router_cfg = tmp_path / "router.json"
    router_cfg.write_text(json.dumps(_materialise("router-secure.json", tmp_path, certs, passwords)))
    endpoint = f"tls/127.0.0.1:{stack.port}"
    router = stack.start("router", "router", "--listen", endpoint, "--zenoh-config", str(router_cfg))
    stack._wait_port(stack.port, router, 20.0)

    def client_file(user: str, password: str | None = None) -> str:
        cfg = _materialise("client-aggregator.json", tmp_path, certs, passwords)
        cfg["transport/auth/usrpwd/user"] = user
        cfg["transport/auth/usrpwd/password"] = password or passwords[user]
        path = tmp_path / f"client-{user}.json"
        path.write_text(json.dumps(cfg))
        return str(path)

    def session(user: str, password: str | None = None, timeout_ms: int = -1) -> zenoh.Session:
        extra = json.loads(open(client_file(user, password)).read()) | {"connect/timeout_ms": timeout_ms}
        return zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,), extra=extra))

    return {"endpoint": endpoint, "client_file": client_file, "session": session, "certs": certs}


def test_device_may_publish_only_under_its_own_prefix(stack, secure):  # noqa: F811
    ep = secure["endpoint"]
    stack.start("aggregate", "aggregate", "--connect", ep, "--zenoh-config", secure["client_file"]("aggregator"))
    stack.start("emulate", "emulate", "--connect", ep, "--subjects", "1", *PAPER10,
                "--zenoh-config", secure["client_file"]("dev-s01"))
    ops = secure["session"]("ops")
    rogue = secure["session"]("dev-s01")
    try:
        stats = ops.declare_subscriber("limbstream/*/stats", zenoh.handlers.FifoChannel(4096))
        seen = ops.declare_subscriber("limbstream/*/*/seg", zenoh.handlers.FifoChannel(1 << 14))
        devices: dict[str, dict] = {}

        def poll():
            while (sample := stats.try_recv()) is not None:
                for d in wire.decode_stats(sample.payload.to_bytes())["devices"]:
                    devices[d["device"]] = d
            return devices
        wait_until(lambda: len(poll()) == 10 and all(d["online"] and d["points"] > 3 and d["aad_deg"] is not None
                                                     for d in devices.values()),
                   60, "s01 streaming over TLS + auth + ACL (advanced pub/sub, liveliness, config)",
                   on_fail=stack.logs)
        # the same user publishes under its own prefix (delivered) and another subject's (refused)
        point = wire.encode_point(wire.SegmentPoint(9, 0, 0, 1_700_000_000_000_000, (1.0, 0.0, 0.0, 0.0)))
        for _ in range(20):
            rogue.put("limbstream/s02/hip/seg", point)
            rogue.put("limbstream/s01/extra/seg", point)
        own, other = 0, 0

        def delivered():
            nonlocal own, other
            while (sample := seen.try_recv()) is not None:
                key = str(sample.key_expr)
                own += key == "limbstream/s01/extra/seg"
                other += key.startswith("limbstream/s02/")
            return own == 20
        wait_until(delivered, 10, "the allowed puts to arrive")
        time.sleep(0.5)  # the refused ones would have arrived together with the allowed ones
        delivered()
        print(f"\nACL: dev-s01 puts under limbstream/s01: {own}/20 delivered; under limbstream/s02: {other}/20")
        assert other == 0, f"{other} puts of dev-s01 under another subject's prefix got through"
        assert not any(k.startswith("s02/") for k in poll()), "the aggregator must never see s02"
        # config queries (egress to the device, replies back) pass the ACL too
        replies = list(ops.get(wire.config_key("s01", "hip"), timeout=5.0))
        assert replies and replies[0].ok is not None, replies
    finally:
        rogue.close()
        ops.close()


def test_wrong_password_and_plain_tcp_are_refused(stack, secure):  # noqa: F811
    with pytest.raises(zenoh.ZError):
        secure["session"]("dev-s01", password="wrong", timeout_ms=3000)
    with pytest.raises(zenoh.ZError):  # no TLS on a TLS-only router
        zconfig.open_session(zconfig.ZenohSettings(
            connect=(f"tcp/127.0.0.1:{stack.port}",),
            extra={"connect/timeout_ms": 3000, "transport/auth/usrpwd/user": "ops",
                   "transport/auth/usrpwd/password": "x"}))
    result = subprocess.run([sys.executable, "-m", "limbstream.cli", "emulate", "--zenoh-config", "/nonexistent.json"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode != 0 and "--zenoh-config /nonexistent.json" in result.stderr, result.stderr
