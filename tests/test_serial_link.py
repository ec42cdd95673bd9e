"""The serial link codec (limbstream/wire/serial_link.py) against the firmware's
(firmware_c/src/lsw_link.c, in the host library): the same frames byte for byte, the same
frames read and the same bad ones counted, by reason, from any byte stream."""
from __future__ import annotations

import ctypes

import numpy as np
import pytest

from limbstream import kernel, wire
from limbstream.wire import serial_link as link


class CReader(ctypes.Structure):
    """LswLinkReader (lsw_link.h)."""

    _fields_ = [("raw", ctypes.c_uint8 * (link.MAX_FRAME)), ("n", ctypes.c_size_t), ("overflow", ctypes.c_uint8),
                ("payload", ctypes.c_uint8 * link.MAX_FRAME), ("payload_len", ctypes.c_size_t),
                ("frames", ctypes.c_uint32), ("bad", ctypes.c_uint32 * len(link.BAD_REASONS))]


lib = ctypes.CDLL(kernel._lib._name)  # own handle: own argtypes
lib.lsw_crc16.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
lib.lsw_crc16.restype = ctypes.c_uint16
lib.lsw_link_frame.argtypes = [ctypes.c_void_p, ctypes.c_uint8, ctypes.c_char_p, ctypes.c_size_t]
lib.lsw_link_frame.restype = ctypes.c_size_t
lib.lsw_link_feed.argtypes = [ctypes.POINTER(CReader), ctypes.c_uint8]
lib.lsw_link_feed.restype = ctypes.c_int


def c_frame(kind: int, body: bytes) -> bytes:
    out = ctypes.create_string_buffer(link.MAX_FRAME)
    n = lib.lsw_link_frame(out, kind, body, len(body))
    return out.raw[:n]


def c_read(data: bytes) -> tuple[list[tuple[int, bytes]], dict[str, int]]:
    """The good frames (type, body) the C reader finds in data, and its bad counts."""
    reader = CReader()
    frames = []
    for byte in data:
        if lib.lsw_link_feed(ctypes.byref(reader), byte):
            payload = bytes(reader.payload[:reader.payload_len])
            frames.append((payload[1], payload[2:]))
    return frames, dict(zip(link.BAD_REASONS, reader.bad))


def test_crc16_check_value():
    assert link.crc16(b"123456789") == lib.lsw_crc16(b"123456789", 9) == 0x29B1  # CRC-16/CCITT-FALSE


def test_frames_are_the_same_bytes():
    rng = np.random.default_rng(1)
    for _ in range(500):
        body = rng.integers(0, 4, rng.integers(0, link.MAX_PAYLOAD - 1)).astype(np.uint8).tobytes()  # many zeros
        kind = int(rng.integers(0, 256))
        assert link.frame(kind, body) == c_frame(kind, body)
        assert b"\0" not in link.frame(kind, body)[:-1]
        assert link.cobs_decode(link.frame(kind, body)[:-1])[2:-2] == body


def test_cobs_round_trip_past_one_block():
    data = bytes(range(1, 256)) * 3 + b"\0\0" + bytes(300)
    assert link.cobs_decode(link.cobs_encode(data)) == data


def test_readers_agree_on_a_damaged_stream():
    """Good frames with noise, cuts, flipped bits and overlong runs between them: both readers
    keep the same frames and count the same bad ones."""
    rng = np.random.default_rng(2)
    parts = []
    for _ in range(400):
        body = rng.integers(0, 256, int(rng.integers(0, 40))).astype(np.uint8).tobytes()
        good = link.frame(int(rng.choice([link.SAMPLE, link.CONFIG, 0x55])), body)
        damage = rng.integers(0, 6)
        if damage == 1:
            good = good[: int(rng.integers(1, len(good)))] + b"\0"  # cut
        elif damage == 2:
            at = int(rng.integers(0, len(good) - 1))
            good = good[:at] + bytes([good[at] ^ (1 << int(rng.integers(0, 8))) or 1]) + good[at + 1:]
        elif damage == 3:
            good = rng.integers(0, 256, int(rng.integers(1, 300))).astype(np.uint8).tobytes() + good  # noise
        parts.append(good)
    stream = b"".join(parts)
    py = link.FrameReader({t: tuple(range(256)) for t in range(256)})  # every type and length: as the C reader
    chunks = np.split(np.frombuffer(stream, np.uint8), np.sort(rng.integers(0, len(stream), 50)))
    frames = [f for chunk in chunks for f in py.feed(chunk.tobytes())]
    c_frames, c_bad = c_read(stream)
    assert frames == c_frames and py.bad == c_bad
    assert len(frames) > 150 and all(py.bad[r] > 0 for r in ("cobs", "length", "crc")), py.bad


def test_a_gateway_reader_checks_types_and_lengths():
    reader = link.FrameReader(link.DEVICE_BODIES)
    point = wire.encode_point(wire.SegmentPoint(1, 2, 3, 4, (1.0, 0.0, 0.0, 0.0)))
    data = (link.frame(link.POINT, point) + link.frame(link.POINT, point[:-1]) + link.frame(link.SAMPLE, bytes(28))
            + link.frame(link.ACK, bytes(13)))
    assert reader.feed(data) == [(link.POINT, point), (link.ACK, bytes(13))]
    assert reader.bad == {"cobs": 0, "length": 1, "crc": 0, "version": 0, "type": 1}


@pytest.mark.parametrize("index, value", [(0, -1.0), (1, 0.0), (1, 2.5), (2, 190.0), (0, float("inf"))])
def test_refusals_are_the_contracts_sentences(index, value):
    tunable = list(wire.TUNABLES.values())[index]
    with pytest.raises(ValueError) as contract:
        tunable.check(int(value) if tunable.type is int and value.is_integer() else value)
    assert link.refusal(index, value) == str(contract.value)


def test_the_gateway_side_counts_bad_frames_and_goes_on():
    """A device that sends garbage, a cut frame, a wrong CRC and an unknown type between good
    frames: the host's link counts each by reason and delivers the good ones, in order."""
    import socket
    import threading

    from limbstream.services.gateway.serial_port import SerialLink

    point = wire.encode_point(wire.SegmentPoint(9, 0, 0, 1, (1.0, 0.0, 0.0, 0.0)))
    good = link.frame(link.POINT, point)
    stream = (b"\x01\x02\x03garbage\0" + good[:7] + b"\0" + good[:3] + bytes([good[3] ^ 0x40]) + good[4:]
              + link.frame(0x99, b"xyz") + good + b"\0\0" + link.frame(link.POINT, point[:20]) + good)
    server = socket.create_server(("127.0.0.1", 0))

    def device():
        conn, _ = server.accept()
        for i in range(0, len(stream), 5):  # in pieces, as a UART delivers
            conn.sendall(stream[i:i + 5])
        conn.close()

    thread = threading.Thread(target=device)
    thread.start()
    port = SerialLink(f"tcp:127.0.0.1:{server.getsockname()[1]}")
    try:
        messages = [port.inbox.get(timeout=10) for _ in range(3)]
        assert messages == [("point", point), ("point", point), ("closed", None)]
        # the cut frame is not COBS; the garbage happens to be, and fails its CRC like the flipped frame
        assert port.bad == {"cobs": 1, "length": 1, "crc": 2, "version": 0, "type": 1}, port.bad
    finally:
        port.close()
        thread.join()
        server.close()


def test_raw_and_fusion_messages():
    """RAW and FUSION as a device reads them (54- and 41-byte frames, the fields in order); a
    FUSION_STATUS body decoded; FUSION's refusal worded for the fusion, not a tunable."""
    reader = link.FrameReader(link.HOST_BODIES)
    raw = link.encode_raw(7, 1_790_000_000_000_123, [0.1, -0.2, 0.3], [0.0, 0.5, 9.8])
    settings = kernel.fusion.imu_settings(285.7, nine_d=True, heading_rad=-1.5)
    fusion = link.encode_fusion(3, settings.raw_period_s, settings.out_period, settings.max_gap, settings.acc_limit,
                                True, settings.rest_th_gyr, settings.rest_th_acc, tuple(settings.heading))
    assert (len(raw), len(fusion)) == (54, 41)
    (kind, body), (kind2, body2) = reader.feed(raw + fusion)
    assert kind == link.RAW and np.array_equal(np.frombuffer(body[12:], "<f4"),
                                               np.float32([0.1, -0.2, 0.3, 0.0, 0.5, 9.8, 0, 0, 0]))
    assert int.from_bytes(body[:4], "little") == 7 and int.from_bytes(body[4:12], "little") == 1_790_000_000_000_123
    assert kind2 == link.FUSION and np.frombuffer(body2[2:6], "<f4")[0] == np.float32(1 / 285.7)
    assert int.from_bytes(body2[6:10], "little") == 20_000 and body2[18] == 1  # the device period, us; 9D
    assert np.array_equal(np.frombuffer(body2[19:], "<f4"),
                          np.float32([0.5, 0.5, np.cos(-0.75), np.sin(-0.75)]))  # rest thresholds, heading
    status = link.decode_device(link.FUSION_STATUS, bytes([5, 0, 9, 1]) + np.float32([1e-3, 0, -2e-3]).tobytes()
                                + np.uint32([100, 25, 1, 2, 0, 3, 4]).tobytes())
    assert (status.request, status.mode, status.rest, status.raw, status.samples) == (5, "9D", True, 100, 25)
    assert status.faults == {"invalid": 1, "time_back": 2, "gap": 0, "saturated": 3, "gyr_stuck": 4}
    refused = link.decode_device(link.ACK, bytes([4, 0, link.FUSION, 1, 0xFF]) + bytes(8))
    assert not refused.ok and refused.error == "fusion settings refused"
