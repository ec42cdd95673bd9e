"""``limbstream emulate --firmware --source X --once`` sends the points of
``limbstream emulate --source X --once``: for each of a subject's 10 devices, the same
segment points (sample index, quaternion, rate, end-of-stream flag) bit for bit, in live mode
(wire.LIVE_MODE, max_len 25), the firmware running under QEMU (one process per device) behind
its serial link. A firmware process that dies is a device gone offline and comes back as a new
stream."""
from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest
import zenoh
from limbstream import wire
from support.firmware import require_tools
from support.points import PointLog
from support.stack import PAPER10, wait_until

pytestmark = pytest.mark.qemu

LIVE_FLAGS = ["--threshold", str(wire.LIVE_MODE["threshold"]), "--max-len", "25",
              "--live-bound-deg", str(wire.LIVE_MODE["live_bound_deg"])]


@pytest.fixture(scope="module")
def elf(tmp_path_factory):
    require_tools("arm-none-eabi-gcc", "qemu-system-arm", "make")
    from limbstream.services.gateway import firmware
    return firmware.build(tmp_path_factory.mktemp("device"))


def one_clip(cmu_npz, tmp_path_factory, name: str) -> Path:
    """A motion file with the one CMU clip ``name``."""
    data = np.load(cmu_npz)
    path = tmp_path_factory.mktemp("clip") / "clip.npz"
    np.savez(path, **{f"clip_{name}": data[f"clip_{name}"]}, fs=data["fs"], segment_names=data["segment_names"])
    return path


@pytest.fixture(scope="module")
def short_clip(cmu_npz, tmp_path_factory):
    """A motion file with one short CMU clip (369 samples, 7.4 s at 50 Hz)."""
    return one_clip(cmu_npz, tmp_path_factory, "05_06")


def run_once(stack, clip, *extra: str, speed: float = 2.0) -> dict[str, list[tuple]]:
    """The points of one ``emulate --once`` run of one subject at ``speed`` times real time:
    {device: [(index, q, omega, flags)]}."""
    log = PointLog(stack.endpoint)
    try:
        child = stack.start("emulate", "emulate", "--connect", stack.endpoint, "--subjects", "1", "--source", str(clip),
                            "--once", "--speed", f"{speed:g}", "--no-truth", "--no-sync", *LIVE_FLAGS, *extra)
        wait_until(lambda: log.ended(10), 120, f"the 10 devices' last points ({' '.join(extra) or 'host kernel'})",
                   on_fail=lambda: f"{log.describe()}\n{stack.logs()}")
        points = log.fill_starts()  # before the emulator stops: its caches answer
        print(f"emulate {' '.join(extra)}: Zenoh reported missed {log.misses or 'none'}; "
              f"points taken from the caches (starts, misses) {log.filled or 'none'}")
        child.signal(15)
        wait_until(lambda: not child.alive(), 30, "the emulator to stop", on_fail=stack.logs)
        return {d: [(p.index, p.q, p.omega, p.flags) for p in device_points] for d, device_points in points.items()}
    finally:
        log.close()


def test_firmware_devices_send_the_host_devices_points(stack, elf, short_clip):
    stack.router()
    host = run_once(stack, short_clip)
    fw = run_once(stack, short_clip, "--firmware", "--firmware-elf", str(elf))
    assert sorted(host) == sorted(fw) and len(host) == 10
    for device in host:
        assert fw[device] == host[device], f"{device}: {len(fw[device])} points vs {len(host[device])}\n{stack.logs()}"
    counts = [len(p) for p in host.values()]
    assert all(10 < n < 369 / 2 for n in counts), counts  # live mode compresses; every device has points
    assert all(p[2] is not None for points in host.values() for p in points), "live mode: every point has its rate"


def test_firmware_devices_fuse_raw_samples_as_the_host_devices_do(stack, elf, short_clip):
    """``--imu raw``: a real part strapped at up to 90 deg, headings anywhere: each firmware device
    is sent its FUSION settings (its start heading) and its sensor's RAW samples, runs VQF and
    fastSW on the M4, and sends the host devices' points bit for bit (VQF's elementary functions
    are the same source on both: firmware_c/src/lsw_math.hpp)."""
    raw = ["--imu", "raw", "--imu-model", "icm42688p", "--mounting-deg", "90", "--heading-deg", "180"]
    stack.router()
    # Real time, as a device runs: each M4 runs VQF in double precision (80,011 instructions per
    # device sample); one that falls behind on a loaded machine keeps beating and ends its stream
    # (test_firmware_imu.py::test_a_device_behind_its_frames_keeps_beating_and_ends_its_stream).
    host = run_once(stack, short_clip, *raw, speed=1.0)
    fw = run_once(stack, short_clip, *raw, "--firmware", "--firmware-elf", str(elf), speed=1.0)
    assert_same_points(host, fw)
    counts = [len(p) for p in host.values()]
    assert all(10 < n < 700 for n in counts), counts


@pytest.mark.slow  # (80 s: ten M4s fusing at real time; alone, as the slow end-to-end tests run)
def test_ideal_raw_sensors_on_a_longer_clip_give_the_same_points_on_the_firmware(stack, elf, cmu_npz, tmp_path_factory):
    """CMU 131_02 (520 samples) with ``--imu raw`` (an ideal part): with the libm of each target
    (glibc's on the host, newlib's on the M4) r_thigh's points differed from its 28th on."""
    clip = one_clip(cmu_npz, tmp_path_factory, "131_02")
    stack.router()
    host = run_once(stack, clip, "--imu", "raw", speed=1.0)
    fw = run_once(stack, clip, "--imu", "raw", "--firmware", "--firmware-elf", str(elf), speed=1.0)
    assert_same_points(host, fw)


def assert_same_points(host: dict[str, list[tuple]], fw: dict[str, list[tuple]]) -> None:
    """Every device's points (index, q, omega, flags) from the firmware are the host's, all of
    them bit for bit; a difference names the device, where it begins and both points there."""
    assert sorted(host) == sorted(fw) and len(host) == 10
    for device in sorted(host):
        first = next((i for i, (a, b) in enumerate(zip(fw[device], host[device])) if a != b), None)
        assert first is None and len(fw[device]) == len(host[device]), (
            f"{device}: {len(fw[device])} points on the firmware, {len(host[device])} on the host; first that "
            f"differs: {first}: firmware {fw[device][first] if first is not None else None}, host "
            f"{host[device][first] if first is not None else None}")


def qemu_children(pid: int) -> list[int]:
    """Pids of the QEMU processes whose parent is ``pid``."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        name, rest = text[text.index("(") + 1:text.rindex(")")], text[text.rindex(")") + 2:].split()
        if name.startswith("qemu-system") and int(rest[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def test_a_firmware_device_that_dies_comes_back_as_a_new_stream(stack, elf):
    stack.router()
    log = PointLog(stack.endpoint)
    alive = log.session.liveliness().declare_subscriber(wire.device_selector("alive"), zenoh.handlers.FifoChannel(256))
    try:
        child = stack.start("emulate", "emulate", "--connect", stack.endpoint, "--subjects", "1", "--firmware",
                            "--firmware-elf", str(elf), "--no-sync", "--no-truth", *PAPER10, *LIVE_FLAGS)
        wait_until(lambda: len(log.poll()) == 10, 60, "points of the 10 firmware devices", on_fail=stack.logs)
        qemus = qemu_children(child.pid)
        assert len(qemus) == 10, qemus
        os.kill(qemus[0], signal.SIGKILL)
        events: list[tuple[str, str]] = []

        def came_back() -> str | None:
            while (sample := alive.try_recv()) is not None:
                events.append((str(sample.kind), str(sample.key_expr)))
            gone = [key for kind, key in events if "DELETE" in kind]
            return gone[0] if gone and any("PUT" in kind and key == gone[0] for kind, key in events) else None

        key = wait_until(came_back, 60, "the killed device to go offline and come back", on_fail=stack.logs)
        subject, segment, _ = wire.parse_device_key(key)
        device = wire.device_id(subject, segment)
        first = log.poll()[device][0].stream
        new = wait_until(lambda: next((p for p in log.poll()[device] if p.stream != first), None), 30,
                         f"points of {device}'s new stream", on_fail=stack.logs)
        assert new.index == 0 and new.seq == 0, new  # a new stream from its first sample
        assert len(qemu_children(child.pid)) == 10 and child.alive()
    finally:
        log.close()


def test_up_passes_firmware_on_and_emulate_refuses_what_firmware_cannot_model():
    import argparse

    from limbstream.cli import emulate, up
    parser = argparse.ArgumentParser()
    up.add_arguments(parser)
    [argv] = [a for name, a in up.plan(parser.parse_args(["--no-sync", "--firmware"])) if name == "emulator"]
    sub = argparse.ArgumentParser()
    emulate.add_arguments(sub)
    assert sub.parse_args(argv[1:]).firmware
    args = sub.parse_args(["--firmware", "--clock-offset-ms", "5", "--no-sync"])
    with pytest.raises(SystemExit, match="--firmware feeds every device its motion's own samples"):
        emulate.run(args)
