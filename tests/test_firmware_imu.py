"""The device firmware under QEMU fed raw IMU samples (RAW frames): VQF and fastSW on the
Cortex-M4 give the host's raw-sample pipeline's points (kernel.fusion.ImuBank), byte for byte,
in 6D and 9D; bad raw samples are counted as on the host, malformed RAW frames by reason, and
the stream goes on."""
from __future__ import annotations


import queue
import threading
import time

import numpy as np
import pytest
import scipy.io

from limbstream import quat, wire
from limbstream.kernel import fusion
from limbstream.services.gateway import firmware
from limbstream.services.gateway.serial_port import SerialLink
from limbstream.wire import serial_link as link
from support import require_data
from support.firmware import drain, final_point, require_tools

pytestmark = pytest.mark.qemu

LIVE = wire.DeviceConfig(**wire.LIVE_MODE)
T0_US = 1_790_000_000_000_000
START, COUNT = 9500, 1500
"""BROAD trial 21 from 3.5 s before its fast motion: 5.3 s, 263 device samples."""


@pytest.fixture(scope="module", params=fusion.VQF_PRECISIONS)
def precision(request) -> str:
    """VQF's precision: the firmware built with it, the host's bank run in it."""
    return request.param


@pytest.fixture(scope="module")
def device(tmp_path_factory, precision):
    require_tools("arm-none-eabi-gcc", "arm-none-eabi-g++", "qemu-system-arm", "make")
    elf = firmware.build(tmp_path_factory.mktemp("device"), vqf_precision=precision)
    with firmware.FirmwareDevice(elf) as fw:
        port = SerialLink(fw.port)
        try:
            assert port.configure(LIVE).ok
            yield port
        finally:
            port.close()


@pytest.fixture(scope="module")
def broad() -> dict:
    d = scipy.io.loadmat(require_data("broad/21_undisturbed_fast_combined.mat"), squeeze_me=True)
    part = slice(START, START + COUNT)
    rate = float(d["sampling_rate"])
    return {"gyr": d["imu_gyr"][part], "acc": d["imu_acc"][part], "mag": d["imu_mag"][part], "rate": rate,
            "ticks": np.round(np.arange(COUNT) / rate * 1e6).astype(np.int64)}


def host_points(d: dict, stream: int, nine_d: bool, precision: str, bad=None) -> tuple[list[bytes], fusion.ImuBank]:
    """The host pipeline's messages for the raw samples (VQF in ``precision``), one ImuBank call
    each, then END's."""
    bank = fusion.ImuBank(1, d["rate"], nine_d=nine_d, threshold=LIVE.threshold, max_len=LIVE.max_len,
                          live_bound_deg=LIVE.live_bound_deg, ring=4, vqf_precision=precision)
    bank.segments.stream[0] = stream
    out: list[bytes] = []
    for tick, g, a, m in samples(d, bad):
        _, payload, _ = bank.update_raw_wire(np.array([tick]), np.array([T0_US + tick]), g[None], a[None],
                                             m[None] if nine_d else None)
        if payload:  # one device: at most one message per call
            out.append(payload)
    out.append(final_point(bank.segments, 0, stream, out[-1]))
    return out, bank


def samples(d: dict, bad=None):
    """(tick, gyr, acc, mag) per raw sample; ``bad`` (index -> change) spoils some."""
    for i in range(COUNT):
        row = [int(d["ticks"][i]), d["gyr"][i].copy(), d["acc"][i].copy(), d["mag"][i].copy()]
        if bad and i in bad:
            bad[i](row)
        yield row


def firmware_points(port: SerialLink, d: dict, stream: int, nine_d: bool, bad=None, between=None) -> list[bytes]:
    settings = fusion.imu_settings(d["rate"], nine_d=nine_d)
    assert port.fusion(settings).ok and port.start(stream).ok
    for i, (tick, g, a, m) in enumerate(samples(d, bad)):
        if between is not None:
            between(i)
        port.raw(tick, T0_US + tick, g, a, m if nine_d else None)
    # Answered after the FINAL point, so every point is in; the firmware first fuses all the samples
    # sent at once above, and END waits for that while the device beats (SerialLink.end)
    assert port.end().ok
    return drain(port)


def differences(got: list[bytes], expected: list[bytes]) -> str:
    """Where the firmware's points first differ from the host's, and their largest angle."""
    pairs = list(zip(got, expected))
    first = next((i for i, (a, b) in enumerate(pairs) if a != b), None)
    angles = quat.angle_deg(np.array([wire.decode_point(a).q for a, _ in pairs]),
                            np.array([wire.decode_point(b).q for _, b in pairs]))
    return f"{len(got)} vs {len(expected)} points; first differs at {first}; largest angle {angles.max():.2e} deg"


@pytest.mark.parametrize("nine_d", [False, True], ids=["6D", "9D"])
def test_raw_samples_give_the_host_pipelines_points(device, broad, nine_d, precision):
    """In each precision, the firmware built with it sends the host's points bit for bit."""
    drain(device)
    expected, bank = host_points(broad, 40 + nine_d, nine_d, precision)
    got = firmware_points(device, broad, 40 + nine_d, nine_d)
    assert got == expected, differences(got, expected)
    decoded = [wire.decode_point(p) for p in expected]
    assert len(decoded) > 20 and all(p.omega is not None for p in decoded)
    status = device.fusion_status()
    host = bank.imu_status()
    assert (status.mode, status.raw, status.samples) == (bank.mode, COUNT, int(host["outputs"][0]))
    assert np.array_equal(np.float32(status.bias), host["bias"][0].astype(np.float32))
    assert status.rest == bool(host["rest"][0])
    assert status.faults == {name: int(host[name][0]) for name in fusion.FAULTS}


def test_bad_raw_samples_and_frames_are_counted_and_the_stream_goes_on(device, broad, precision):
    """Invalid samples (NaN, saturated, stuck, back in time) are handled as on the host; RAW frames
    that are cut, corrupted or of the wrong length are counted by reason and change nothing."""
    def nan(row):
        row[1][0] = np.nan

    def saturate(row):
        row[2][1] = 300.0

    def stuck(row):
        row[1][:] = 0.0

    def back(row):
        row[0] -= 10_000

    bad = {100: nan, 200: saturate, 201: saturate, 300: stuck, 400: back}
    good = link.encode_raw(0, T0_US, [0, 0, 0], [0, 0, 9.8])
    malformed = {"length": link.frame(link.RAW, bytes(47)), "crc": good[:6] + bytes([good[6] ^ 0x10]) + good[7:],
                 "cobs": bytes([60, 1, 2]) + b"\0"}
    sent = []

    def between(i: int) -> None:
        if i % 250 == 125:
            reason = list(malformed)[(i // 250) % len(malformed)]
            device.send(malformed[reason])
            sent.append(reason)

    drain(device)
    before = device.status().bad
    expected, bank = host_points(broad, 50, False, precision, bad)
    assert firmware_points(device, broad, 50, False, bad, between) == expected
    after = device.status().bad
    assert {reason: after[reason] - before[reason] for reason in malformed} == {
        reason: sent.count(reason) for reason in malformed}
    faults = device.fusion_status().faults
    assert faults == {name: int(bank.imu_status()[name][0]) for name in fusion.FAULTS}
    assert (faults["invalid"], faults["saturated"], faults["time_back"]) == (1, 2, 1) and faults["gyr_stuck"] >= 1


BACKLOG = 8000
"""Raw samples sent at once: seconds of work for the firmware under QEMU (VQF in double)."""


def test_a_device_behind_its_frames_keeps_beating_and_ends_its_stream(device, broad, precision):
    """A device that falls behind (a slow core, or frames sent faster than it fuses them) keeps
    sending its heartbeat every second while it works through them, so the host does not take it for
    hung (SerialGateway's silence watchdog), and END's ack, which comes after every frame sent before
    it, is waited for while the device is heard (SerialLink.end)."""
    drain(device)
    settings = fusion.imu_settings(broad["rate"])
    assert device.fusion(settings).ok and device.start(60).ok
    rows = np.arange(BACKLOG) % COUNT
    period_us = 1e6 / broad["rate"]
    frames = b"".join(link.encode_raw(int(round(i * period_us)), T0_US + int(round(i * period_us)), broad["gyr"][r],
                                      broad["acc"][r]) for i, r in enumerate(rows))
    done: dict = {}

    def send_and_end() -> None:
        try:
            device.send(frames)
            done["ack"] = device.end(timeout_s=3.0)
        except Exception as exc:  # noqa: BLE001  (reported below)
            done["error"] = exc

    sender = threading.Thread(target=send_and_end)
    start = time.monotonic()
    sender.start()
    beats = [start]
    while sender.is_alive() or not device.inbox.empty():
        try:
            kind, _ = device.inbox.get(timeout=0.05)
        except queue.Empty:
            continue
        if kind == "status":
            beats.append(time.monotonic())
    took = time.monotonic() - start
    assert "error" not in done and done["ack"].ok, done
    gaps = np.diff(beats + [time.monotonic()])
    assert gaps.max() < 2.5, f"{took:.1f} s of work, heartbeats {np.round(np.diff(beats), 2)}"


def test_bad_fusion_settings_are_refused(device):
    settings = fusion.imu_settings(200.0)
    settings.raw_period_s = 0.0
    ack = device.fusion(settings)
    assert not ack.ok and ack.error == "fusion settings refused"
