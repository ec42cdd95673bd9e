"""``limbstream gateway serial`` end to end: the device firmware under QEMU, the gateway feeding
it generator motion over its serial link (a TCP socket), a router and an aggregator. The
device is a limbstream device like an emulated one: its points reach the aggregator, its
liveliness token and truth tap are there, its config queryable answers with the firmware's own
counters, refuses out-of-range tunables with the contract's sentence and applies a good change
once the firmware has acked it; when the firmware dies the device goes offline."""
from __future__ import annotations

import json
import signal

import pytest
import zenoh

from limbstream import wire, zconfig
from limbstream.services.gateway import firmware
from support.firmware import require_tools
from support.stack import StatsWatch, wait_until

pytestmark = pytest.mark.qemu

SUBJECT, SEGMENT = "s01", "l_thigh"


@pytest.fixture(scope="module")
def elf(tmp_path_factory):
    require_tools("arm-none-eabi-gcc", "qemu-system-arm", "make")
    return firmware.build(tmp_path_factory.mktemp("device"))


def ask(session: zenoh.Session, payload: dict | None = None):
    """(ok, decoded answer) of the device's config queryable."""
    replies = list(session.get(wire.config_key(SUBJECT, SEGMENT), timeout=10.0,
                               payload=None if payload is None else json.dumps(payload).encode()))
    assert len(replies) == 1, replies
    reply = replies[0]
    if reply.ok is not None:
        return True, wire.decode_status(reply.ok.payload.to_bytes())
    return False, json.loads(reply.err.payload.to_bytes())


@pytest.mark.parametrize("tty", [False, True], ids=["tcp", "tty"])
def test_gateway_bridges_the_firmware_device(stack, elf, tty):
    """Over a TCP socket, and over a tty (QEMU's pseudo-terminal: how a USB or UART device appears)."""
    stack.router()
    device = firmware.FirmwareDevice(elf, tty=tty)
    try:
        gateway = stack.start("gateway", "gateway", "serial", "--port", device.port, "--subject", SUBJECT,
                              "--segment", SEGMENT, "--source", "generator", "--threshold", "9e-4",
                              "--live-bound-deg", "5", "--connect", stack.endpoint, "-v")
        stack.aggregator()
        watch = StatsWatch(stack.endpoint)
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
        try:
            points = session.declare_subscriber(wire.seg_key(SUBJECT, SEGMENT), zenoh.handlers.FifoChannel(4096))
            raw = session.declare_subscriber(wire.raw_key(SUBJECT, SEGMENT), zenoh.handlers.FifoChannel(256))
            device_id = wire.device_id(SUBJECT, SEGMENT)
            stats = wait_until(lambda: watch.poll().get(device_id, {}).get("points", 0) >= 5 and watch.devices[device_id],
                               60, "the aggregator to take in the firmware device's points", on_fail=stack.logs)
            assert stats["points"] >= 5
            received = [wire.decode_point(s.payload.to_bytes()) for s in iter(points.try_recv, None)]
            assert received and all(p.omega is not None for p in received), "live mode: points with rates"
            batch = wait_until(lambda: raw.try_recv(), 30, "a truth-tap batch of the fed samples")
            assert wire.decode_raw(batch.payload.to_bytes()).stream == received[0].stream
            alive = list(session.liveliness().get(wire.alive_key(SUBJECT, SEGMENT), timeout=5.0))
            assert len(alive) == 1

            ok, status = ask(session)
            assert ok and status.config == wire.DeviceConfig(**wire.LIVE_MODE) and status.samples > 0
            assert status.stream == received[0].stream
            ok, refused = ask(session, {"max_len": 0})
            with pytest.raises(ValueError) as contract:
                wire.MAX_LEN.check(0)
            assert not ok and refused["error"] == f"config: {contract.value}"
            ok, status = ask(session, {"threshold": 2e-3})
            assert ok and status.config.threshold == 2e-3 and status.config.max_len == 25
            ok, again = ask(session)
            assert ok and again.config.threshold == 2e-3 and again.samples >= status.samples

            device.stop()  # the firmware dies: the device goes offline
            wait_until(lambda: not list(session.liveliness().get(wire.alive_key(SUBJECT, SEGMENT), timeout=2.0)),
                       30, "the device's liveliness token to go", on_fail=stack.logs)
            assert gateway.alive(), "the gateway keeps running and retries the link"
        finally:
            session.close()
            watch.close()
    finally:
        device.stop()


def test_a_hung_device_goes_offline_and_comes_back_as_a_new_stream(stack, elf):
    """The firmware frozen (QEMU stopped): no heartbeat, so the gateway takes the device offline
    after --silence-s; resumed, it is back online with a new stream."""
    stack.router()
    device = firmware.FirmwareDevice(elf)
    try:
        stack.start("gateway", "gateway", "serial", "--port", device.port, "--subject", SUBJECT, "--segment", SEGMENT,
                    "--source", "generator", "--max-len", "5", "--silence-s", "3", "--connect", stack.endpoint, "-v")
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
        try:
            alive = session.liveliness().declare_subscriber(wire.alive_key(SUBJECT, SEGMENT),
                                                            zenoh.handlers.FifoChannel(64), history=True)
            points = session.declare_subscriber(wire.seg_key(SUBJECT, SEGMENT), zenoh.handlers.FifoChannel(4096))
            events: list[str] = []

            def seen(kind: str) -> int:
                events.extend(str(s.kind) for s in iter(alive.try_recv, None))
                return sum(kind in e for e in events)

            wait_until(lambda: seen("PUT") == 1, 30, "the device online", on_fail=stack.logs)
            first = wire.decode_point(wait_until(points.try_recv, 30, "a point", on_fail=stack.logs).payload.to_bytes())
            device.process.send_signal(signal.SIGSTOP)
            wait_until(lambda: seen("DELETE") == 1, 30, "the silent device to go offline", on_fail=stack.logs)
            device.process.send_signal(signal.SIGCONT)
            wait_until(lambda: seen("PUT") == 2, 60, "the device back online", on_fail=stack.logs)
            new = wait_until(lambda: next((p for p in (wire.decode_point(s.payload.to_bytes())
                                                       for s in iter(points.try_recv, None)) if p.stream != first.stream),
                                          None), 30, "a point of the new stream", on_fail=stack.logs)
            assert new.seq == 0 and new.index == 0
        finally:
            session.close()
    finally:
        device.process.send_signal(signal.SIGCONT)
        device.stop()
