"""The SlimeVR gateway's tests' pieces: a datagram header, a gateway running in a thread, trackers
streaming, a free UDP port."""
from __future__ import annotations

import contextlib
import json
import math
import socket
import struct
import threading
import time

import zenoh

from limbstream import wire, zconfig
from limbstream.device.clocks import ClockSettings
from limbstream.device.host import HostSettings
from limbstream.device_emulator.slimevr_tracker import Tracker
from limbstream.services.gateway.slimevr import GatewaySettings, SlimeVRGateway

def header(kind: int, number: int) -> bytes:
    return struct.pack(">iq", kind, number)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Running:
    """A gateway in a thread on a peer Zenoh session (its own subscribers see what it publishes),
    with a subscriber to every segment point and liveliness token. ``reads``: "ticks" (kernel
    arrival stamps and the whole receive buffer), "between" (a buffer capped by the system: also
    reads between ticks), "as they come" (as on a system without kernel arrival stamps)."""

    def __init__(self, reads: str = "ticks", **overrides):
        self.session = zconfig.open_session(zconfig.ZenohSettings(mode="peer", connect=()))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.address = self.sock.getsockname()
        settings = GatewaySettings(**{"subject": "s01", "clock": ClockSettings(sync=False), "timeout_s": 0.6,
                                      "host": HostSettings(config=wire.DeviceConfig(**{**wire.LIVE_MODE, "max_len": 25})),
                                      **overrides})
        self.gateway = SlimeVRGateway(self.session, self.sock, settings)
        self.gateway.rx.kernel_stamps &= reads != "as they come"
        if reads == "between":
            self.gateway.rcvbuf = 0
        self.points = self.session.declare_subscriber(wire.device_selector("seg"), zenoh.handlers.FifoChannel(100000))
        self.received: dict[str, list] = {}
        self.stop = threading.Event()
        self.reports: list[dict] = []
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        try:
            self.gateway.run(self.stop, on_report=self.reports.append, report_s=0.2)
        except BaseException as exc:  # the test fails on it
            self.error = exc
            raise

    def poll(self) -> dict[str, list]:
        while (s := self.points.try_recv()) is not None:
            subject, segment, _ = wire.parse_device_key(str(s.key_expr))
            self.received.setdefault(f"{subject}/{segment}", []).append(wire.decode_point(s.payload.to_bytes()))
        return self.received

    def report(self) -> dict:
        return self.reports[-1] if self.reports else {}

    def status(self, device: str) -> dict:
        replies = list(self.session.get(wire.config_key(*device.split("/")), timeout=5.0))
        return json.loads(replies[0].ok.payload.to_bytes())

    def alive(self) -> set[str]:
        return {"/".join(wire.parse_device_key(str(r.ok.key_expr))[:2])
                for r in self.session.liveliness().get(wire.device_selector("alive"), timeout=2.0) if r.ok}

    def close(self):
        self.stop.set()
        self.thread.join(10)
        assert not self.thread.is_alive() and self.error is None
        self.gateway.undeclare()
        self.sock.close()
        self.session.close()


def stream(trackers: list[Tracker], sensors: dict, seconds: float, rate: float = 50.0, q15: bool = False,
           stop: threading.Event | None = None) -> None:
    """Every tracker sends its sensors' orientations (a turn about Y, 1 rad/s) at ``rate`` Hz."""
    start = time.monotonic()
    k = 0
    while time.monotonic() - start < seconds and not (stop and stop.is_set()):
        angle = 1.0 * k / rate
        q = (math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)
        for t in trackers:
            for sensor in sensors[t.mac_text]:
                t.rotation(sensor, q, q15=q15)
            t.pump()
        k += 1
        time.sleep(max(0.0, start + k / rate - time.monotonic()))


@contextlib.contextmanager
def streaming(trackers: list[Tracker], sensors: dict, seconds: float = 30.0, q15: bool = False):
    """The trackers connect, then stream their sensors (``{mac: [sensor ids]}``, :func:`stream`)
    from a thread until the block ends (or ``seconds``)."""
    stop = threading.Event()
    sender = threading.Thread(target=stream, args=(trackers, sensors, seconds), kwargs={"q15": q15, "stop": stop})
    try:
        for t in trackers:
            t.connect()
        sender.start()
        yield
    finally:
        stop.set()
        if sender.is_alive():
            sender.join()
