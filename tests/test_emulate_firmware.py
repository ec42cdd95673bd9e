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
import zenoh.ext as zext

from limbstream import quat, wire, zconfig
from support.firmware import require_tools
from support.stack import wait_until

pytestmark = pytest.mark.qemu

LIVE_FLAGS = ["--threshold", str(wire.LIVE_MODE["threshold"]), "--max-len", "25",
              "--live-bound-deg", str(wire.LIVE_MODE["live_bound_deg"])]


@pytest.fixture(scope="module")
def elf(tmp_path_factory):
    require_tools("arm-none-eabi-gcc", "qemu-system-arm", "make")
    from limbstream.services.gateway import firmware
    return firmware.build(tmp_path_factory.mktemp("device"))


@pytest.fixture(scope="module")
def short_clip(cmu_npz, tmp_path_factory):
    """A motion file with one short CMU clip (369 samples, 7.4 s at 50 Hz)."""
    data = np.load(cmu_npz)
    path = tmp_path_factory.mktemp("clip") / "clip.npz"
    np.savez(path, clip_05_06=data["clip_05_06"], fs=data["fs"], segment_names=data["segment_names"])
    return path


class PointLog:
    """Every segment point on the router, by device, read as the aggregator reads them: an
    advanced subscriber that recovers a point lost on the way from the device's cache (on a
    loaded machine a plain subscriber here once missed a run of points the devices had put)."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.sub = zext.declare_advanced_subscriber(
            self.session, wire.device_selector("seg"), zenoh.handlers.FifoChannel(100_000),
            history=zext.HistoryConfig(detect_late_publishers=True, max_samples=1024),
            recovery=zext.RecoveryConfig(heartbeat=True), subscriber_detection=True)
        self.points: dict[str, list[wire.SegmentPoint]] = {}

    def poll(self) -> dict[str, list[wire.SegmentPoint]]:
        while (sample := self.sub.try_recv()) is not None:
            subject, segment, _ = wire.parse_device_key(str(sample.key_expr))
            self.points.setdefault(wire.device_id(subject, segment), []).append(
                wire.decode_point(sample.payload.to_bytes()))
        return self.points

    def ended(self, devices: int) -> bool:
        points = self.poll()
        return len(points) == devices and all(p[-1].flags & wire.FLAG_FINAL for p in points.values())

    def close(self):
        self.session.close()


def run_once(stack, clip, *extra: str, speed: float = 2.0) -> dict[str, list[tuple]]:
    """The points of one ``emulate --once`` run of one subject at ``speed`` times real time:
    {device: [(index, q, omega, flags)]}."""
    log = PointLog(stack.endpoint)
    try:
        child = stack.start("emulate", "emulate", "--connect", stack.endpoint, "--subjects", "1", "--source", str(clip),
                            "--once", "--speed", f"{speed:g}", "--no-truth", "--no-sync", *LIVE_FLAGS, *extra)
        wait_until(lambda: log.ended(10), 120, f"the 10 devices' last points ({' '.join(extra) or 'host kernel'})",
                   on_fail=stack.logs)
        child.signal(15)
        wait_until(lambda: not child.alive(), 30, "the emulator to stop", on_fail=stack.logs)
        return {d: [(p.index, p.q, p.omega, p.flags) for p in points] for d, points in log.poll().items()}
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
    fastSW on the M4, and sends the host devices' points bit for bit (libm aside: a difference
    names where the first point differs and the largest orientation difference)."""
    raw = ["--imu", "raw", "--imu-model", "icm42688p", "--mounting-deg", "90", "--heading-deg", "180"]
    stack.router()
    # Real time, as a device runs: each M4 runs VQF in double precision (77,557 instructions per
    # device sample), and ten of them at twice real time beside a loaded suite on 2 cores fell
    # behind (one device's points then began later than the host's).
    host = run_once(stack, short_clip, *raw, speed=1.0)
    fw = run_once(stack, short_clip, *raw, "--firmware", "--firmware-elf", str(elf), speed=1.0)
    assert sorted(host) == sorted(fw) and len(host) == 10
    report = {device: compare_points(host[device], fw[device]) for device in sorted(host)}
    print("\n".join(f"{device}: {text}" for device, (_, text) in report.items()))
    assert all(ok for ok, _ in report.values()), report
    counts = [len(p) for p in host.values()]
    assert all(10 < n < 700 for n in counts), counts


def compare_points(host: list[tuple], fw: list[tuple]) -> tuple[bool, str]:
    """Whether a firmware device's points are the host device's, and what differs: bit for bit,
    or (libm: newlib's float sin, cos, acos on the M4 against glibc's) where the first point
    differs and the largest orientation difference between points of the same sample, which must
    stay under 0.01 deg with at least 90 % of the sample indices in common."""
    first = next((i for i, (a, b) in enumerate(zip(fw, host)) if a != b), None)
    if first is None and len(fw) == len(host):
        return True, f"{len(host)} points, bit for bit"
    mine, theirs = {p[0]: p[1] for p in fw}, {p[0]: p[1] for p in host}
    common = sorted(set(mine) & set(theirs))
    gap = max((float(quat.angle_deg(np.array(mine[i], np.float64), np.array(theirs[i], np.float64))) for i in common),
              default=float("inf"))
    shared = len(common) / max(len(mine), len(theirs))
    text = (f"first point that differs: {first} of {len(host)} (firmware: {len(fw)} points); largest orientation "
            f"difference {gap:.3g} deg; {100 * shared:.0f} % of the sample indices in common")
    return gap < 0.01 and shared >= 0.9, text


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
                            "--firmware-elf", str(elf), "--no-sync", "--no-truth", *LIVE_FLAGS)
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
