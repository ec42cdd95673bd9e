"""A SlimeVR tracker for the tests, written from the tracker firmware's side of the protocol
(big-endian; ``i32 type, i64 packet number, payload``): it looks for its server with handshakes,
reports its sensors, answers heartbeats and pings, and sends rotations (type 17, or 23 in Q15),
battery and signal packets, alone or in bundles (100, 101)."""
from __future__ import annotations

import math
import socket
import struct
import time

from limbstream.pacing import PacedLoop

GREETING = b"Hey OVR =D 5"
AXES_INVERSE = (math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0)
"""+90 degrees about X: what a tracker sends for limbstream orientation q is AXES_INVERSE * q."""


def to_tracker_axes(q) -> tuple[float, float, float, float]:
    """(w, x, y, z) in limbstream's axes -> the tracker's (the gateway turns it back)."""
    aw, ax, ay, az = AXES_INVERSE
    bw, bx, by, bz = (float(v) for v in q)
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def rotation_payload(sensor: int, q) -> bytes:
    w, x, y, z = q
    return struct.pack(">BB4fB", sensor, 1, x, y, z, w, 0)


def rotation_q15_payload(sensor: int, q) -> bytes:
    w, x, y, z = (max(-32768, min(32767, round(v * 32768))) for v in q)
    return struct.pack(">B4h3h", sensor, x, y, z, w, 0, 0, 128)


def sensor_info_payload(sensor: int, position: int, status: int = 1, imu: int = 10) -> bytes:
    return struct.pack(">BBBHBBBff", sensor, status, imu, 0, 1, position, 0, 100.0, 100.0)


def handshake_payload(mac: bytes) -> bytes:
    firmware = b"0.6.0"
    return (struct.pack(">7i", 4, 10, 2, 0, 0, 0, 21) + bytes([len(firmware)]) + firmware + mac
            + bytes([1]) + b"\x00" * 5)


class Tracker:
    """One simulated tracker on its own UDP socket.

    Parameters
    ----------
    server : (host, port) of the gateway.
    mac : 6 bytes.
    positions : {sensor id: SlimeVR body position id (0: none)}.
    """

    def __init__(self, server: tuple[str, int], mac: bytes, positions: dict[int, int]):
        self.server, self.mac, self.positions = server, mac, positions
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.number = 0
        self.connected = False
        self.acked: set[int] = set()
        self.heartbeats = self.pings = 0
        self.features: bytes | None = None
        self.last_heard = 0.0

    @property
    def mac_text(self) -> str:
        return ":".join(f"{b:02X}" for b in self.mac)

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> Tracker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def send_raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.server)

    def send(self, kind: int, payload: bytes = b"", number: int | None = None) -> None:
        if number is None:
            self.number += 1
            number = self.number
        self.send_raw(struct.pack(">iq", kind, number) + payload)

    def bundle(self, items: list[tuple[int, bytes]], compact: bool = False) -> None:
        self.number += 1
        body = b"".join((bytes([len(p) + 1, kind]) if compact else struct.pack(">Hi", len(p) + 4, kind)) + p
                        for kind, p in items)
        self.send_raw(struct.pack(">iq", 101 if compact else 100, self.number) + body)

    def pump(self) -> None:
        """Read what the server sent and answer it as the firmware does."""
        while True:
            try:
                data = self.sock.recv(2048)
            except BlockingIOError:
                return
            self.last_heard = time.monotonic()
            if data[0] == 3 and data[1:13] == GREETING:
                self.connected = True
                continue
            if len(data) < 4:
                continue
            kind = data[3]
            if kind == 1:
                self.heartbeats += 1
                self.send(0)
            elif kind == 10:
                self.pings += 1
                self.send_raw(data)  # the firmware returns the ping as it came
            elif kind == 15 and len(data) >= 6:
                self.acked.add(data[4])
            elif kind == 22:
                self.features = data[12:]

    def connect(self, timeout: float = 10.0) -> None:
        """Handshake until the server answers, then sensor infos (until acknowledged) and feature flags."""
        deadline = time.monotonic() + timeout
        while not self.connected:
            if time.monotonic() > deadline:
                raise TimeoutError(f"tracker {self.mac_text}: no handshake answer")
            self.send(3, handshake_payload(self.mac), number=0)
            wait = time.monotonic() + 0.2
            while not self.connected and time.monotonic() < wait:
                time.sleep(0.005)
                self.pump()
        self.send(22, b"\x07")
        while not set(self.positions) <= self.acked:
            if time.monotonic() > deadline:
                raise TimeoutError(f"tracker {self.mac_text}: sensor info not acknowledged")
            for sensor, position in self.positions.items():
                if sensor not in self.acked:
                    self.send(15, sensor_info_payload(sensor, position))
            wait = time.monotonic() + 0.2
            while not set(self.positions) <= self.acked and time.monotonic() < wait:
                time.sleep(0.005)
                self.pump()

    def rotation(self, sensor: int, q, q15: bool = False) -> None:
        """Send sensor ``sensor``'s orientation ``q`` (w, x, y, z, limbstream axes)."""
        q = to_tracker_axes(q)
        if q15:
            self.send(23, rotation_q15_payload(sensor, q))
        else:
            self.send(17, rotation_payload(sensor, q))

    def battery(self, voltage: float, level: float) -> None:
        self.send(12, struct.pack(">ff", voltage, level))

    def signal(self, dbm: int) -> None:
        self.send(19, struct.pack(">Bb", 255, dbm))


SEGMENT_POSITIONS = {"neck": 2, "hip": 6, "l_thigh": 7, "r_thigh": 8, "l_shank": 9, "r_shank": 10,
                     "l_lowerarm": 13, "r_lowerarm": 14, "l_upperarm": 15, "r_upperarm": 16}
"""The SlimeVR body position id a tracker on each segment is set to."""


class Fleet:
    """Trackers playing a motion: one per segment and subject, each sending its segment's
    orientation at ``fs`` (the clip looped), answering the server, and reporting its battery and
    signal every second.

    Parameters
    ----------
    server : the gateway's (host, port).
    q : (T, S, 4) orientations (w, x, y, z) of segments ``segments`` at ``fs``.
    subjects : copies of the set of trackers (the second one and later need --assign to be
        placed: the gateway places trackers by body position into one subject).
    """

    def __init__(self, server: tuple[str, int], q, segments, fs: float, subjects: int = 1, q15: bool = False):
        self.q, self.segments, self.fs, self.q15 = q, list(segments), fs, q15
        self.trackers = [Tracker(server, bytes([2, 0x5E, 0, 0, s, k]), {0: SEGMENT_POSITIONS[seg]})
                         for s in range(subjects) for k, seg in enumerate(self.segments)]
        self.sent = 0
        self.loop = PacedLoop(1.0 / fs, clock=time.monotonic)

    def mac(self, subject: int, segment: str) -> str:
        return self.trackers[subject * len(self.segments) + self.segments.index(segment)].mac_text

    def connect(self, timeout: float = 30.0) -> None:
        for t in self.trackers:
            t.connect(timeout)

    def run(self, stop, seconds: float | None = None, spin_s: float = 0.0) -> None:
        """Send until ``stop`` is set or ``seconds`` have passed; ``spin_s``: wait the last this
        long before each send in a busy loop (a steadier send time than sleeping, at a CPU's cost)."""
        n_seg = len(self.segments)

        def send(k: int, now: float) -> None:
            row = self.q[k % len(self.q)]
            for i, t in enumerate(self.trackers):
                t.rotation(0, row[i % n_seg], q15=self.q15)
                if k % int(self.fs) == i % int(self.fs):
                    t.battery(3.9, 0.8)
                    t.signal(-60)
                t.pump()
            self.sent += len(self.trackers)

        def wait(deadline: float) -> None:
            delay = deadline - time.monotonic()
            if delay > spin_s:
                stop.wait(delay - spin_s)
            while time.monotonic() < deadline and not stop.is_set():
                pass

        self.loop.run(stop, send, None if seconds is None else int(round(seconds * self.fs)), wait)

    @property
    def late(self) -> int:
        """Sends that began more than a period late."""
        return self.loop.stats.late

    def close(self) -> None:
        for t in self.trackers:
            t.close()
