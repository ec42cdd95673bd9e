"""The C pieces of the SlimeVR gateway: irregular arrivals on a uniform grid per device
(limbstream.kernel.GridBank, firmware_c/host/lsw_grid.c) and the rotation datagrams read in C
(services/gateway/slimevr_rx.py, firmware_c/host/lsw_slimevr.c) against the Python decoder."""
from __future__ import annotations

import fcntl
import math
import random
import socket
import struct
import termios
import time

import numpy as np
import pytest

from limbstream import quat
from limbstream.kernel import GridBank, SvrTracker
from limbstream.services.gateway import slimevr_protocol as proto
from limbstream.services.gateway.slimevr_rx import Receiver, ipv4
from limbstream.device_emulator.slimevr_tracker import rotation_payload, rotation_q15_payload
from support.stack import wait_until

IDENTITY = (1.0, 0.0, 0.0, 0.0)


def turn(angle: float) -> np.ndarray:
    return np.array([math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0])


def yaw(q) -> float:
    return 2 * math.atan2(q[2], q[0])


def sample_at(grid: GridBank, at: float) -> tuple[bool, np.ndarray, int]:
    """Device 0's sample at grid instant ``at`` (its grid placed one period before, so the tick
    moves it there): (taken, y, stamp)."""
    d = grid.devices[0]
    d.has_instant, d.instant, d.shift = 1, at - grid.settings.period_us, 0.0
    grid.tick(1, at)
    assert d.instant == at
    return bool(grid.have[0]), grid.y[0].copy(), int(grid.stamp[0])


def test_grid_samples_follow_the_packets():
    """A device's grid sample is the packet that arrived less than ``late_us`` after its instant
    (delayed on its way) or ``early_us`` before it, its truth sample restamped at the instant; else
    the SLERP of the packets around the instant; the newest held for at most ``hold_us`` (counted
    when older than a quarter period)."""
    grid = GridBank(1, 20_000.0, hold_us=15_000.0, late_us=10_000.0, early_us=1_000.0, phase_gain=0.02,
                    rise_after=4, axes=IDENTITY, truth=True)
    grid.offset_us = 1_000.0
    grid.devices[0].online = 1
    for t, angle in ((0.0, 0.0), (20_000.0, 0.2), (40_000.0, 0.4)):
        grid.push(0, t, turn(angle), 0.0)
    assert grid.truth(0)[0].tolist() == [1_000, 21_000, 41_000]
    assert not sample_at(grid, -1.0)[0]
    taken, y, stamp = sample_at(grid, 30_000.0)  # half a period before the next packet: between the two
    assert taken and yaw(y) == pytest.approx(0.3, abs=1e-6) and stamp == 31_000
    assert grid.truth(0)[0].tolist() == [1_000, 21_000, 41_000] and grid.devices[0].held == 0
    taken, y, stamp = sample_at(grid, 33_000.0)  # the packet at 40 ms came 7 ms late for this instant
    assert taken and yaw(y) == pytest.approx(0.4, abs=1e-6) and stamp == 34_000
    assert grid.truth(0)[0].tolist() == [1_000, 21_000, 34_000]
    taken, y, _ = sample_at(grid, 40_500.0)  # it arrived just before this instant: its own
    assert taken and yaw(y) == pytest.approx(0.4, abs=1e-6) and grid.truth(0)[0].tolist() == [1_000, 21_000, 41_500]
    taken, y, _ = sample_at(grid, 44_000.0)  # within a quarter period after the newest packet: on time
    assert taken and yaw(y) == pytest.approx(0.4, abs=1e-6) and grid.devices[0].held == 0
    taken, y, _ = sample_at(grid, 50_000.0)
    assert taken and yaw(y) == pytest.approx(0.4, abs=1e-6) and grid.devices[0].held == 1
    assert not sample_at(grid, 56_000.0)[0]  # held too long: the tracker went quiet
    assert grid.devices[0].quiet == 1


def test_grid_sample_is_the_slerp_of_python_and_turned_by_the_axes():
    """Between two packets the sample is limbstream.quat.slerp of them, turned by the bank's axes
    (axes * q), to float32 rounding."""
    rng = np.random.default_rng(3)
    axes = quat.normalize(rng.normal(size=4))
    grid = GridBank(1, 20_000.0, hold_us=15_000.0, late_us=1.0, early_us=1.0, phase_gain=0.02,
                    rise_after=4, axes=axes, truth=False)
    grid.devices[0].online = 1
    q0, q1 = quat.normalize(rng.normal(size=4)), quat.normalize(rng.normal(size=4))
    grid.push(0, 0.0, q0, 0.0)
    grid.push(0, 20_000.0, q1, 0.0)
    _, y, _ = sample_at(grid, 7_000.0)
    want = quat.multiply(axes, quat.slerp(q0, q1, 0.35))
    assert quat.angle_deg(y.astype(np.float64), want) < 1e-4


def test_grid_instants_follow_the_lower_edge_of_the_arrivals():
    """With arrivals late by 0..3 ms (and a tracker clock 200 ppm fast), every grid instant after
    the first second is before its packet's arrival by at most the jitter, and nearly all at or
    before it (the rest by less than 0.1 ms): the point made at that instant counts as known at
    the packet (the live error against the truth tap)."""
    grid = GridBank(1, 20_000.0, hold_us=1e9, late_us=10_000.0, early_us=1_000.0, phase_gain=0.02,
                    rise_after=4, axes=IDENTITY, truth=False)
    grid.devices[0].online = 1
    rng = random.Random(5)
    period = 20_000.0 * (1 - 200e-6)
    packets = [("packet", 7_300.0 + j * period + rng.uniform(0, 3_000)) for j in range(500)]
    ticks = [("tick", 100_000.0 + k * 20_000.0) for k in range(495)]
    instants = []
    for kind, t in sorted(packets + ticks, key=lambda e: e[1]):
        if kind == "packet":
            grid.push(0, t, IDENTITY, 0.0)
        elif grid.tick(1, t - 30_000.0):
            instants.append(grid.devices[0].instant)
    arrivals = np.array([t for _, t in packets])
    gaps = np.diff(instants)
    assert len(instants) >= 490 and gaps.min() >= 0.75 * 20_000 and gaps.max() <= 1.25 * 20_000 + 1
    offsets = []  # arrival of each instant's packet (the nearest) minus the instant
    for at in instants[50:]:
        j = int(np.argmin(np.abs(arrivals - at)))
        offsets.append(arrivals[j] - at)
    offsets = np.array(offsets)
    assert offsets.min() >= -100.0 and offsets.max() <= 3_000.0, (offsets.min(), offsets.max())
    assert np.mean(offsets >= 0) > 0.95, np.mean(offsets >= 0)
    assert len(grid.jitter_us(0)) >= 490 and grid.jitter_us(0).max() < 5_000.0  # within a quarter period


def test_truth_is_due_when_settled_and_taken_in_order():
    """Truth samples are due in batches once no later tick can restamp them (arrived before the
    last instant plus ``late_us``), or when some have waited ``max_age``; taken stamps never go
    back; more than the C buffer holds drops the oldest, counted."""
    grid = GridBank(2, 10_000.0, hold_us=20_000.0, late_us=5_000.0, early_us=500.0, phase_gain=0.02,
                    rise_after=5, axes=IDENTITY, truth=True)
    grid.devices[0].online = grid.devices[1].online = 1
    for j in range(30):
        grid.push(0, 1_000.0 + j * 10_000.0, turn(0.01 * j), now=1.0)
    assert grid.truth_due(2, 1.0, 25, 0.5) == []  # no grid instant yet: nothing settled
    d = grid.devices[0]
    d.has_instant, d.instant = 1, 200_000.0  # samples up to 205 ms arrived are settled: 21 of them
    assert grid.truth_due(2, 1.0, 25, 0.5) == []
    assert grid.truth_due(2, 1.6, 25, 0.5) == [(0, 21)]  # waited long enough
    d.instant = 250_000.0
    assert grid.truth_due(2, 1.0, 25, 0.5) == [(0, 26)]
    d.truth_t[3] = d.truth_t[2] - 5  # a restamp earlier than the sample before
    t, q = grid.take_truth(0, 26, now=2.0)
    assert len(t) == 26 and np.all(np.diff(t) >= 0) and t[3] == t[2]
    assert yaw(q[5]) == pytest.approx(0.05, abs=1e-6)
    assert d.truth_len == 4 and d.truth_since == 2.0
    for j in range(600):
        grid.push(1, j * 100.0, IDENTITY, now=3.0)
    assert grid.devices[1].truth_len == 512 and grid.devices[1].truth_dropped == 88
    assert grid.truth(1)[1][0] == 88 * 100.0  # the oldest went


# ---------------------------------------------------------------- rotation datagrams in C

ADDRESS = ("10.0.0.7", 40_000)


def receiver(sensors=(0, 1)) -> tuple[GridBank, Receiver, SvrTracker]:
    grid = GridBank(len(sensors), 10_000.0, hold_us=20_000.0, late_us=5_000.0, early_us=500.0, phase_gain=0.02,
                    rise_after=5, axes=IDENTITY, truth=True)
    rx = Receiver(None, grid, len(sensors))
    link = SvrTracker(last_number=-1, online=1)
    rx.route((link, ipv4(ADDRESS[0]), ADDRESS[1], sensor, slot) for slot, sensor in enumerate(sensors))
    for slot in range(len(sensors)):
        grid.devices[slot].online = 1
    return grid, rx, link


def header(kind: int, number: int) -> bytes:
    return struct.pack(">iq", kind, number)


def bundle(items: list[tuple[int, bytes]], compact: bool = False) -> bytes:
    if compact:
        return b"".join(bytes([len(p) + 1, kind]) + p for kind, p in items)
    return b"".join(struct.pack(">Hi", len(p) + 4, kind) + p for kind, p in items)


def rotations_of(datagram: bytes) -> list[tuple[int, tuple]] | None:
    """What the Python decoder makes of a datagram, if it is rotations only: [(sensor, q)]."""
    try:
        messages = proto.decode(datagram).messages
    except proto.ProtocolError:
        return None
    if not messages or not all(isinstance(m, proto.Rotation) for m in messages):
        return None
    return [(m.sensor, m.q) for m in messages]


def datagrams(rng: random.Random, n: int):
    """Rotation datagrams as trackers send them, and broken or foreign ones."""
    for number in range(1, n + 1):
        q = quat.normalize(np.array([rng.gauss(0, 1) for _ in range(4)]))
        kind = rng.randrange(8)
        if kind == 0:
            yield header(17, number) + rotation_payload(rng.randrange(3), q)
        elif kind == 1:
            yield header(23, number) + rotation_q15_payload(rng.randrange(2), q)
        elif kind == 2:
            items = [(17, rotation_payload(s, q)) for s in range(rng.randrange(1, 3))]
            yield header(100, number) + bundle(items)
        elif kind == 3:
            items = [(23, rotation_q15_payload(s, q)) for s in range(rng.randrange(1, 3))]
            yield header(101, number) + bundle(items, compact=True)
        elif kind == 4:  # a battery packet inside the bundle: Python's
            yield header(100, number) + bundle([(17, rotation_payload(0, q)), (12, struct.pack(">ff", 3.9, 0.8))])
        elif kind == 5:
            good = header(17, number) + rotation_payload(0, q)
            yield good[:rng.randrange(len(good))]  # cut
        elif kind == 6:
            yield header(17, number) + struct.pack(">BB4fB", 0, 1, math.nan, 0.0, 0.0, 1.0, 0)
        else:
            yield header(17, rng.randrange(number + 1)) + rotation_payload(0, q)  # maybe out of order


def test_rotation_datagrams_are_taken_in_c_exactly_when_python_decodes_rotations_only():
    """The C side takes a datagram only when the Python decoder reads it as rotations of routed
    sensors with a newer packet number, and puts the decoder's quaternions in the devices'
    histories; everything else (other types, broken, unrouted, out of order) is left to Python."""
    rng = random.Random(11)
    grid, rx, link = receiver()
    last, taken, counts = -1, 0, [0, 0]
    for t, data in enumerate(datagrams(rng, 2000)):
        rotations = rotations_of(data)
        number = struct.unpack_from(">q", data, 4)[0] if len(data) >= 12 else 0
        want = (rotations is not None and all(s in (0, 1) for s, _ in rotations) and number > last
                and number != 0)
        got = rx.datagram(data, ipv4(ADDRESS[0]), ADDRESS[1], 1_000.0 * t, 0.0)
        assert got == want, (data.hex(), rotations)
        if got:
            taken += 1
            last = number
            for sensor, q in rotations:
                counts[sensor] += 1
                _, hist = grid.history(sensor)
                np.testing.assert_allclose(hist[-1], q, atol=1e-15)
    assert taken > 500 and link.packets == taken and link.last_number == last and link.arrived == taken
    assert grid.devices[0].truth_len == min(counts[0], 512)
    assert not rx.datagram(header(17, last + 1) + rotation_payload(0, IDENTITY), ipv4("10.0.0.8"), ADDRESS[1],
                           0.0, 0.0)  # another address: not routed
    link.online = 0
    assert not rx.datagram(header(17, last + 1) + rotation_payload(0, IDENTITY), ipv4(ADDRESS[0]), ADDRESS[1],
                           0.0, 0.0)  # an offline tracker: Python brings it back


def test_packet_loss_is_counted_from_the_numbers():
    grid, rx, link = receiver()
    for number in (5, 6, 9, 10, 70_000, 70_001):
        assert rx.datagram(header(17, number) + rotation_payload(0, IDENTITY), ipv4(ADDRESS[0]), ADDRESS[1],
                           float(number), 0.0)
    assert link.lost == 2 and link.packets == 6  # 7, 8; a jump of 2**16 or more is a restart, not loss


def sent_out(sock: socket.socket) -> bool:
    """Every datagram ``sock`` sent has left it: queued at the receiver or dropped there (loopback
    delivers in a softirq, which runs later when the machine is busy)."""
    return struct.unpack("i", fcntl.ioctl(sock, termios.TIOCOUTQ, b"\0\0\0\0"))[0] == 0


def socket_receiver(server: socket.socket, tracker: socket.socket) -> tuple[Receiver, SvrTracker]:
    """A receiver reading ``server`` into one device, fed by sensor 0 of ``tracker``."""
    grid = GridBank(1, 10_000.0, hold_us=20_000.0, late_us=5_000.0, early_us=500.0, phase_gain=0.02,
                    rise_after=5, axes=IDENTITY, truth=False)
    grid.devices[0].online = 1
    rx = Receiver(server, grid, 1)
    link = SvrTracker(last_number=-1, online=1)
    rx.route([(link, ipv4("127.0.0.1"), tracker.getsockname()[1], 0, 0)])
    return rx, link


def test_the_socket_is_read_in_batches_and_other_datagrams_come_back_in_order():
    """From a real UDP socket: routed rotations are taken in C, every other datagram comes back
    with its sender and a kernel arrival stamp, in the order sent."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as server, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tracker:
        server.bind(("127.0.0.1", 0))
        server.setblocking(False)
        tracker.bind(("127.0.0.1", 0))
        rx, link = socket_receiver(server, tracker)
        sent, sent_us, back, read_us, read = [], [], [], [], 0
        for number in range(1, 301):
            data = (header(17, number) + rotation_payload(0, IDENTITY) if number % 7
                    else header(12, number) + struct.pack(">ff", 3.9, 0.5))
            sent_us.append(time.time_ns() / 1e3)
            tracker.sendto(data, server.getsockname())
            sent.append(data)
            if number % 50 == 0:  # (within the socket's default buffer)
                wait_until(lambda: sent_out(tracker), 10, "the datagrams delivered", interval=0.001)
                while True:
                    n, slow = rx.drain(0.0, 4096)
                    read += n
                    if slow is not None:
                        back.append(slow)
                        read_us.append(time.time_ns() / 1e3)
                    elif n == 0:
                        break
        assert read == 300 and link.packets == 300 - 42
        assert [data for data, _, _ in back] == [d for d in sent if d[3] == 12]
        assert all(address == tracker.getsockname() for _, address, _ in back)
        # Each stamp lies between its send and its read (microseconds since the epoch). They need not
        # be in order: while the kernel turns stamping on (deferred work), it stamps at the read.
        sent_slow = [t for t, d in zip(sent_us, sent) if d[3] == 12]
        assert all(s - 1.0 <= t <= r + 1.0 for s, (_, _, t), r in zip(sent_slow, back, read_us))
        assert rx.kernel_stamps


def test_datagrams_the_full_socket_buffer_dropped_are_counted():
    """Datagrams the kernel drops on a full receive buffer are counted (SO_RXQ_OVFL): read plus
    dropped is what was sent, so a stall shows as socket drops, not only as lost packet numbers."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as server, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tracker:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # (the kernel's minimum, about 4.6 kB)
        server.bind(("127.0.0.1", 0))
        tracker.bind(("127.0.0.1", 0))
        rx, link = socket_receiver(server, tracker)
        for number in range(1, 301):  # the buffer fills
            tracker.sendto(header(17, number) + rotation_payload(0, IDENTITY), server.getsockname())
        wait_until(lambda: sent_out(tracker), 10, "the datagrams delivered or dropped", interval=0.001)
        read, _ = rx.drain(0.0, 4096)
        assert 0 < read < 300 and link.packets == read
        tracker.sendto(header(17, 301) + rotation_payload(0, IDENTITY), server.getsockname())
        wait_until(lambda: sent_out(tracker), 10, "the last datagram delivered", interval=0.001)
        assert rx.drain(0.0, 4096)[0] == 1  # the count comes with the first datagram queued after the drops
        assert rx.overflows == 300 - read and link.lost == 300 - read
