"""The device firmware (firmware_c/m4/device_main.c) under QEMU, over its serial link.

Fed the samples an emulated device takes, it sends the same segment point messages as the
host's emulated devices (kernel.SegmenterBank, the emulator's end-of-stream rule), byte for
byte, for the 10 devices of a CMU subject in live mode. Bad input on the link (garbage, cut
frames, wrong checksums, unknown types, out-of-range tunables) is counted by reason and
refused with the contract's sentences, and the stream goes on unchanged.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from limbstream import kernel, wire
from limbstream.device_emulator.feeds import LoopFeed
from limbstream.services.gateway import firmware
from limbstream.services.gateway.serial_port import SerialLink
from limbstream.sources import load
from limbstream.wire import serial_link as link
from firmware import drain, final_point, require_tools

pytestmark = pytest.mark.qemu

LIVE = wire.DeviceConfig(**wire.LIVE_MODE)
PERIOD_US = 20_000
T0_US = 1_790_000_000_000_000


@pytest.fixture(scope="module")
def elf(tmp_path_factory):
    require_tools("arm-none-eabi-gcc", "qemu-system-arm", "make")
    return firmware.build(tmp_path_factory.mktemp("device"))


@pytest.fixture
def device(elf):
    """A running firmware device and the host's link to it."""
    with firmware.FirmwareDevice(elf) as fw:
        port = SerialLink(fw.port)
        try:
            yield port
        finally:
            port.close()


@pytest.fixture(scope="module")
def clip(cmu_npz) -> np.ndarray:
    """(m, 10, 4) float32: a short CMU clip at 50 Hz, as an emulated subject's devices sample it."""
    motion = next(m for m in load(cmu_npz) if "05_06" in m.name)
    return LoopFeed(motion, 50.0, once=True).q


def host_points(q: np.ndarray, streams: list[int], config: wire.DeviceConfig) -> list[list[bytes]]:
    """The segment point messages of the host's emulated devices for samples q (m, S, 4): one
    SegmenterBank tick per sample, then each stream's end as the emulator ends it (its last
    sample flushed as a held FINAL point, or its last point repeated as FINAL)."""
    m, count = q.shape[:2]
    bank = kernel.SegmenterBank(count, config.threshold, config.max_len, live_bound_deg=config.live_bound_deg, ring=4)
    bank.stream[:count] = streams
    out: list[list[bytes]] = [[] for _ in range(count)]
    for k in range(m):
        bank.sample[k % 4] = k
        bank.t_us[k % 4] = T0_US + k * PERIOD_US
        slots, payload, ends = bank.update_wire(np.full(count, k * PERIOD_US, np.uint32), q[k])
        for slot, start, end in zip(slots, [0, *ends[:-1]], ends):
            out[slot].append(payload[start:end])
    for s in range(count):
        out[s].append(final_point(bank, s, streams[s], out[s][-1] if out[s] else b""))
    return out


def other_version(kind: int, body: bytes) -> bytes:
    """A well-formed frame of link version 2."""
    payload = bytes([2, kind]) + body
    return link.cobs_encode(payload + link.crc16(payload).to_bytes(2, "little")) + b"\0"


def stream_through(port: SerialLink, stream: int, q: np.ndarray, between=None) -> list[bytes]:
    """One stream on the device: START, the samples q (m, 4), END; the points it sent.
    ``between(k)`` may send anything before sample k."""
    drain(port)
    assert port.start(stream).ok
    for k, y in enumerate(q):
        if between is not None:
            between(k)
        port.sample(k * PERIOD_US, T0_US + k * PERIOD_US, y)
    assert port.end().ok  # the device answers after its FINAL point: every point is in
    return drain(port)


def test_points_equal_the_host_devices_bit_for_bit(device, clip):
    """The 10 devices of a subject in live mode, one stream each through the firmware."""
    identity = device.identify()
    assert (identity.link_version, identity.point_version, identity.dim) == (link.LINK_VERSION, wire.VERSION_RATE, 4)
    assert device.configure(LIVE).ok
    streams = [1000 + s for s in range(clip.shape[1])]
    expected = host_points(clip, streams, LIVE)
    for s, stream in enumerate(streams):
        got = stream_through(device, stream, clip[:, s])
        assert got == expected[s], f"segment {s}: first differing point " + str(next(
            (i, wire.decode_point(a), wire.decode_point(b)) for i, (a, b) in enumerate(zip(got, expected[s])) if a != b)
            if len(got) == len(expected[s]) else f"counts {len(got)} != {len(expected[s])}")
    decoded = [wire.decode_point(p) for p in expected[0]]
    # live mode: version 2 points with rates, fewer points than samples, the last one FINAL
    assert all(p.omega is not None for p in decoded) and any(any(p.omega) for p in decoded)
    assert 5 < len(decoded) < len(clip) / 2 and decoded[-1].flags == wire.FLAG_FINAL
    status = device.status()
    assert (status.samples, status.points, status.config) == (len(clip), len(expected[-1]), LIVE)
    assert sum(status.bad.values()) == 0 and status.frames > len(clip) * len(streams)


def test_the_link_works_unchanged_over_a_tty(elf, clip):
    """UART0 on a pseudo-terminal, opened as a serial device is (raw mode): the same points."""
    with firmware.FirmwareDevice(elf, tty=True) as fw:
        assert fw.port.startswith("/dev/")
        port = SerialLink(fw.port)
        try:
            assert port.identify().link_version == link.LINK_VERSION
            assert port.configure(LIVE).ok
            assert stream_through(port, 3, clip[:, 9]) == host_points(clip[:, 9:], [3], LIVE)[0]
        finally:
            port.close()


def test_plain_fastsw_points_are_version_1(device, clip):
    """With the live rule off (the default settings) the points are plain fastSW's, without rates."""
    expected = host_points(clip[:, :2], [7, 8], wire.DeviceConfig())
    for s in range(2):
        got = stream_through(device, 7 + s, clip[:, s])
        assert got == expected[s]
    assert all(len(p) == wire.POINT_SIZE for p in got)


def test_bad_input_is_counted_and_the_stream_goes_on(device, clip):
    """Bad frames between a stream's samples: each counted by its reason, none changes a point."""
    good = link.encode_sample(0, 0, [1, 0, 0, 0])
    bad_frames = {
        "crc": good[:5] + bytes([good[5] ^ 0x40]) + good[6:],
        "cobs": bytes([40, 1, 2]) + b"\0",                         # a block running past the frame
        "type": link.frame(0x7F, b"\1\2"),
        "length": link.frame(link.SAMPLE, bytes(27)),            # a sample body one byte short
        "version": other_version(link.SAMPLE, bytes(28)),
    }
    garbage = np.random.default_rng(5).integers(1, 256, 300, dtype=np.uint8).tobytes() + b"\0"  # overlong: length
    cut = good[:10] + b"\0"                                      # truncated: too short after COBS, or bad CRC
    sent = []

    def between(k: int) -> None:
        if k % 20 == 10:
            reason = list(bad_frames)[(k // 20) % len(bad_frames)]
            device.send(bad_frames[reason])
            sent.append(reason)
        elif k % 20 == 15:
            device.send(garbage if k % 40 == 15 else cut)
            sent.append("garbage" if k % 40 == 15 else "cut")

    assert device.configure(LIVE).ok
    expected = host_points(clip[:, :1], [77], LIVE)[0]
    assert stream_through(device, 77, clip[:, 0], between) == expected
    status = device.status()
    counted = {reason: sent.count(reason) for reason in bad_frames}
    counted["length"] += sent.count("garbage")
    assert sum(status.bad.values()) == len(sent), (status.bad, sent)
    for reason, n in counted.items():
        assert status.bad[reason] >= n, (reason, status.bad, sent)
    assert status.samples == len(clip) and status.rejected == 0


@pytest.mark.parametrize("values", [{"threshold": -1e-3}, {"threshold": 2e6}, {"max_len": 0}, {"max_len": 2.5},
                                    {"max_len": 100_001}, {"live_bound_deg": 180.5}, {"threshold": float("nan")}])
def test_out_of_range_tunables_are_refused_with_the_contracts_sentence(device, values):
    before = device.status()
    ack = device.configure(dataclasses.replace(LIVE, **values))
    name, value = next(iter(values.items()))
    with pytest.raises(ValueError) as contract:
        wire.TUNABLES[name].check(value)
    assert not ack.ok and ack.error == str(contract.value)
    after = device.status()
    assert after.config == before.config and after.refused == before.refused + 1


def test_a_sample_cut_by_line_noise_is_lost_alone(device, clip):
    """Noise without a delimiter spoils the frame it runs into (counted); the next is read."""
    assert device.start(5).ok
    device.send(b"\x13\x37" + link.encode_sample(0, T0_US, clip[0, 0]))
    device.sample(PERIOD_US, T0_US + PERIOD_US, clip[1, 0])
    status = device.status()
    assert status.samples == 1 and sum(status.bad.values()) == 1, status
