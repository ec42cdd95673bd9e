"""Device clocks and their synchronisation in the live system (docs/reliability.md, "Device
clocks"): the real router, time service, emulators and aggregator on loopback, each sample's
timestamp measured against its reference time from the truth tap (what an external reference
system would give). Without a network: tests/test_clock.py.

Every test prints one ``CLOCK |`` line that docs/reliability.md collects:
``pytest tests/test_clock_live.py -s | grep 'CLOCK |'``.
"""
from __future__ import annotations

import collections
import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from support.stack import StatsWatch, stack, wait_until  # noqa: F401  (fixture)

from limbstream.device.clocks import ClockSettings, DeviceClocks, TimeBase
from limbstream.device.sync import RESUME_SPREAD_S, SyncClient
from limbstream import wire, zconfig

T0 = 1_800_000_000_000_000  # us

# the timestamps' error is a timing figure: the sync exchanges' round trips set it, and beside three
# other workers on two cores they stretch to milliseconds; these run with the slow end-to-end tests, alone
pytestmark = pytest.mark.slow


def report(what: str, how: str, result: str) -> None:
    print(f"\nCLOCK | {what} | {how} | {result} |")


# ----------------------------------------------------------------------------- live system


class Taps:
    """Truth-tap samples as they arrive: per device, (reference time, stamp) pairs."""

    def __init__(self, endpoint: str, subjects: str = "*"):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.sub = self.session.declare_subscriber(wire.subject_selector(wire.TRUTH, subjects),  # the emulator's:
                                                   zenoh.handlers.FifoChannel(1 << 16))  # per subject
        self.samples: dict[str, list] = collections.defaultdict(list)

    def poll(self) -> dict[str, np.ndarray]:
        while (sample := self.sub.try_recv()) is not None:
            for key, payload in wire.truth_batches(str(sample.key_expr), sample.payload.to_bytes()):
                subject, segment, _ = wire.parse_device_key(key)
                b = wire.decode_raw(payload)
                self.samples[f"{subject}/{segment}"].extend(zip(b.ref_us.tolist(), b.t_us.tolist()))
        return {k: np.array(v, np.int64) for k, v in self.samples.items()}

    def errors_after(self, t_us: float) -> dict[str, np.ndarray]:
        """|stamp - reference| per device, us, for samples taken after true time ``t_us``."""
        return {k: np.abs(v[v[:, 0] > t_us, 1] - v[v[:, 0] > t_us, 0]) for k, v in self.poll().items()}

    def close(self):
        self.session.close()


def error_trace(taps: Taps, device: str, started_us: float) -> str:
    """Device ``device``'s largest timestamp error per 2 s since ``started_us`` (a failure's trace)."""
    v = taps.poll()[device]
    bins = ((v[:, 0] - started_us) // 2e6).astype(int)
    err = np.abs(v[:, 1] - v[:, 0])
    return " ".join(f"{2 * b}s:{err[bins == b].max():.0f}" for b in np.unique(bins))


def printed_offsets(child) -> dict[str, float]:
    """The clock offsets an emulator printed at its start, ms."""
    text = Path(child.log).read_text()
    return {m[1]: float(m[2]) for m in re.finditer(r"clock (\S+): offset ([+-][\d.]+) ms", text)}


def p99s(errors: dict[str, np.ndarray]) -> dict[str, float]:
    return {k: float(np.percentile(v, 99)) for k, v in errors.items() if len(v)}


def mean_over_first(history: list[dict], frames: int) -> float:
    """A subject's mean frame error over its first ``frames`` compared frames, deg, from its stats
    messages (each: the mean over all frames so far, the error window being longer): the error
    sum is interpolated between the two messages around ``frames``. Emulators that started at
    different instants are thus compared over the same stretch of their motion."""
    counts = np.array([h.get("frame_error_frames") or 0 for h in history], float)
    sums = np.array([(h.get("frame_aad_deg") or 0.0) for h in history]) * counts
    assert counts[-1] >= frames, (counts[-1], frames)
    return float(np.interp(frames, counts, sums)) / frames


def test_loopback_sync_keeps_every_device_on_the_common_time_base_and_frames_aligned(stack, watch):  # noqa: F811
    """Three emulators of the same motion (subjects s01-s02): perfect clocks (s01, s02), clocks
    off by up to +-2 s drifting up to +-100 ppm with sync (s03, s04), and the same clocks without
    sync (s05, s06). Every synced device's timestamps are within 5 ms (p99) of the reference
    from 10 s after its emulator started (the target, 1 ms, is measured by bench/clock_sync.py
    hour; here 0.33-0.71 ms alone and 1.67 ms on a loaded CI machine: the bound keeps 3x that).
    Over the first 1000 frames of each subject (the same stretch of the same motion, whenever its
    emulator started), the synced subjects' alignment-aware frame error is within 0.1 deg of the
    perfect clocks'; without sync it is many times larger."""
    taps = Taps(stack.endpoint)
    try:
        stack.start("clock", "clock", "--connect", stack.endpoint)
        stack.aggregator()
        clocks = ["--clock-offset-ms", "2000", "--clock-drift-ppm", "100"]
        stack.emulator(2, 1.0, "--no-sync")
        started = time.time() * 1e6
        synced_emulator = stack.emulator(2, 1.0, "--first-subject", "3", "--seed", "-2", *clocks)
        stack.emulator(2, 1.0, "--first-subject", "5", "--seed", "-4", "--no-sync", *clocks)

        def settled():
            subjects = watch.poll() and watch.subjects
            return len(subjects) == 6 and all((s.get("frame_error_frames") or 0) > 1000 for s in subjects.values())
        wait_until(settled, 90, "1000 compared frames per subject", interval=0.2, on_fail=stack.logs)
        p99 = p99s({k: v for k, v in taps.errors_after(started + 10e6).items() if k[:3] in ("s03", "s04")})
        devices = watch.poll()
        frame_aad = {s: mean_over_first(h, 1000) for s, h in sorted(watch.subject_history.items())}
        printed = printed_offsets(synced_emulator)
        report_offset = {k: (devices[k]["clock_offset_ms"], printed[k]) for k in printed}
        worst = max(p99, key=p99.get)
        report("loopback, 20 devices, offsets +-2 s, drift +-100 ppm", "router + clock + emulator + aggregator",
               f"timestamp error p99 from 10 s after start: worst device {p99[worst]:.0f} us ({worst}), median "
               f"{np.median(list(p99.values())):.0f} us; frame_aad_deg perfect {frame_aad['s01']:.3f}/"
               f"{frame_aad['s02']:.3f}, synced {frame_aad['s03']:.3f}/{frame_aad['s04']:.3f}, unsynced "
               f"{frame_aad['s05']:.2f}/{frame_aad['s06']:.2f}")
        assert len(p99) == 20 and max(p99.values()) <= 5000, p99
        for k, (reported, drawn) in report_offset.items():  # the device's own estimate vs its drawn offset
            assert devices[k]["synced"] is True and abs(reported - drawn) < 0.1 * 60 + 1.0, (k, reported, drawn)
        for d in ("s05/hip", "s01/hip"):
            assert devices[d]["synced"] is False and devices[d]["clock_offset_ms"] is None, devices[d]
        for perfect, synced in (("s01", "s03"), ("s02", "s04")):
            assert frame_aad[synced] <= frame_aad[perfect] + 0.1, frame_aad
        for perfect, unsynced in (("s01", "s05"), ("s02", "s06")):
            assert frame_aad[unsynced] > frame_aad[perfect] + 3.0, frame_aad
        assert all(d["restarts"] == 0 for d in devices.values())
    finally:
        taps.close()


def test_delay_and_jitter_in_the_exchange_path_keep_devices_synced(stack, watch):  # noqa: F811
    """``tc netem`` is not available on these kernels: the time service delays each direction
    of every exchange by 10 ms +- 5 ms (uniform, per direction and query). Devices see the
    jitter and poll every second; from 60 s after start every device's timestamps are within
    5 ms (p99) of the reference (measured 1.4-1.6 ms; the bound keeps 3x that for a loaded machine)."""
    taps = Taps(stack.endpoint)
    try:
        stack.start("clock", "clock", "--connect", stack.endpoint, "--sync-delay-ms", "10", "--sync-jitter-ms", "5")
        started = time.time() * 1e6
        stack.emulator(1, 1.0, "--clock-offset-ms", "2000", "--clock-drift-ppm", "100")
        wait_until(lambda: taps.poll() and all(len(v) and v[-1, 0] > started + 80e6 for v in taps.poll().values())
                   and len(taps.samples) == 10, 120, "80 s of samples", interval=0.5, on_fail=stack.logs)
        p99 = p99s(taps.errors_after(started + 60e6))
        worst = max(p99, key=p99.get)
        rtt = [watch.device_status(f"s01/{seg}")["sync_rtt_ms"] for seg in wire.SEGMENTS]
        report("exchange path delayed 10 +- 5 ms each way (in the time service)", "router + clock + emulator",
               f"timestamp error p99 from 60 s after start: worst device {p99[worst]:.0f} us, median "
               f"{np.median(list(p99.values())):.0f} us (round trips seen {min(rtt, default=0):.0f}-"
               f"{max(rtt, default=0):.0f} ms)")
        assert len(p99) == 10 and max(p99.values()) <= 5000, (p99, error_trace(taps, worst, started))
    finally:
        taps.close()


class RogueService:
    """A time service in the test process that answers with a chosen fault: ``good``,
    ``malformed`` (short payload), ``other`` (an answer to another request), ``future`` (an
    hour ahead), ``negative`` (claims it held the query longer than the round trip)."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.queryable = self.session.declare_queryable(wire.time_key(), zenoh.handlers.FifoChannel(1024))
        self.mode = "good"
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        while True:
            query = self.queryable.recv()
            if self.stop.is_set():
                query.drop()
                return
            with query:
                now = time.time_ns() // 1000
                r = wire.decode_time_request(query.payload.to_bytes())
                answer = {
                    "good": wire.TimeAnswer(r.id, r.t1_us, now, now),
                    "other": wire.TimeAnswer(r.id + 1, r.t1_us, now, now),
                    "future": wire.TimeAnswer(r.id, r.t1_us, now + 3_600_000_000, now + 3_600_000_000),
                    "negative": wire.TimeAnswer(r.id, r.t1_us, now - 1_000_000, now + 1_000_000),
                }.get(self.mode)
                payload = b"\x01short" if answer is None else wire.encode_time_answer(answer)
                query.reply(wire.time_key(), payload)

    def close(self):
        self.stop.set()
        self.session.get(wire.time_key(), allowed_destination=zenoh.Locality.SESSION_LOCAL, timeout=1.0)
        self.thread.join(2)
        self.queryable.undeclare()
        self.session.close()


def test_bad_time_answers_are_discarded_and_counted(stack, watch):  # noqa: F811
    """Malformed answers, answers to another request, answers from the future and answers with a
    negative round trip are counted by reason in the device's status (and stats) and change
    nothing: the devices keep their estimate and stay synced; their timestamps drift only as
    far as the estimate's drift error allows over the ~20 s without a valid answer."""
    rogue = RogueService(stack.endpoint)
    taps = Taps(stack.endpoint)
    try:
        stack.aggregator()
        stack.emulator(1, 1.0, "--clock-offset-ms", "500", "--clock-drift-ppm", "50")
        wait_until(lambda: len(watch.poll()) == 10 and all(d.get("synced") for d in watch.devices.values()),
                   40, "devices synced", interval=0.2, on_fail=stack.logs)
        bad_since = time.time() * 1e6
        for mode, reason in (("malformed", "malformed"), ("other", "malformed"), ("future", "future"),
                             ("negative", "negative_rtt")):
            rogue.mode = mode
            before = {seg: watch.device_status(f"s01/{seg}")["sync_bad"].get(reason, 0) for seg in wire.SEGMENTS}
            wait_until(lambda reason=reason, before=before: all(
                watch.device_status(f"s01/{seg}")["sync_bad"].get(reason, 0) > before[seg] for seg in wire.SEGMENTS),
                40, f"every device to discard a {mode} answer", interval=0.5, on_fail=stack.logs)
        rogue.mode = "good"
        statuses = [watch.device_status(f"s01/{seg}") for seg in wire.SEGMENTS]
        totals = collections.Counter()
        for s in statuses:
            totals.update(s["sync_bad"])
        wait_until(lambda: all(sum((d.get("sync_bad") or {}).values()) > 0 for d in watch.poll().values()),
                   15, "stats to show the discarded answers")
        p99 = p99s(taps.errors_after(bad_since))
        report("bad time answers (rogue service)", "malformed, other request, 1 h ahead, negative round trip",
               f"discarded by reason {dict(totals)}; devices synced {sum(s['synced'] for s in statuses)}/10, "
               f"timestamp error p99 meanwhile <= {max(p99.values()):.0f} us")
        assert set(totals) == {"malformed", "future", "negative_rtt"}, totals  # 'other' counts as malformed
        assert totals["malformed"] >= 20 and all(s["synced"] for s in statuses), statuses
        assert max(p99.values()) < 4000, p99  # ~20 s on the estimate from the first ~10 s (holdover; ~1 ms)
    finally:
        taps.close()
        rogue.close()


def test_late_service_steps_to_a_new_stream_and_loss_unsyncs_after_holdover(stack, watch):  # noqa: F811
    """Devices that start without a time service stream on their own clocks (unsynced); when the
    service appears they step onto the common time base as a new stream. When it goes away they
    keep their estimate and report themselves unsynced after the holdover (here 4 s); when it is
    back they resync without a step. A rebooted device (process restarted, new clocks) is a new
    stream again and resyncs."""
    taps = Taps(stack.endpoint)
    try:
        stack.aggregator()
        emulator = stack.emulator(1, 1.0, "--clock-offset-ms", "1000", "--clock-drift-ppm", "100",
                                  "--sync-holdover-s", "4")
        wait_until(lambda: len(watch.poll()) == 10 and all(d["points"] > 3 for d in watch.devices.values()),
                   40, "devices streaming unsynced", on_fail=stack.logs)
        assert not any(d["synced"] for d in watch.devices.values())
        clock = stack.start("clock", "clock", "--connect", stack.endpoint)
        appeared = time.monotonic()
        wait_until(lambda: all(d["synced"] and d["restarts"] == 1 for d in watch.poll().values()), 30,
                   "devices synced on a new stream", interval=0.1, on_fail=stack.logs)
        stepped = time.monotonic() - appeared
        after = time.time() * 1e6 + 3e6
        time.sleep(5)
        p99 = p99s(taps.errors_after(after))
        clock.signal(15)
        clock.popen.wait(10)
        lost = time.monotonic()
        wait_until(lambda: not any(d["synced"] for d in watch.poll().values()), 20, "devices unsynced",
                   interval=0.1, on_fail=stack.logs)
        unsynced = time.monotonic() - lost
        stack.start("clock", "clock", "--connect", stack.endpoint)
        wait_until(lambda: all(d["synced"] for d in watch.poll().values()), 30, "devices synced again", interval=0.1)
        assert all(d["restarts"] == 1 for d in watch.devices.values()), "a resync within 128 ms is no step"
        emulator.signal(9)
        emulator.popen.wait(10)
        stack.emulator(1, 1.0, "--clock-offset-ms", "1000", "--clock-drift-ppm", "100", "--clock-seed", "7")
        wait_until(lambda: all(d["synced"] and d["restarts"] == 2 and d["online"] for d in watch.poll().values()),
                   40, "rebooted devices on a new stream, synced", interval=0.1, on_fail=stack.logs)
        report("time service starts after the devices, then is lost and back; device reboot",
               "clock started late, SIGTERM, started again (holdover 4 s); emulator SIGKILL + new clocks",
               f"synced on a new stream {stepped:.1f} s after the service appeared (p99 then "
               f"{max(p99.values()):.0f} us); unsynced {unsynced:.1f} s after the loss; resync without a step; "
               f"reboot: new stream, synced")
        assert max(p99.values()) < 3000, p99  # (measured well under 1 ms; 3x margin for a loaded machine)
        assert 3.5 < unsynced < 12, unsynced
    finally:
        taps.close()


def live_client(endpoint: str, n: int, **settings) -> SyncClient:
    """A SyncClient of ``n`` devices on its own client session, started (workers running)."""
    cs = ClockSettings(**settings)
    base = TimeBase()
    clocks = DeviceClocks(n, cs, 20_000.0, base)
    clocks.boot(base.now_us())
    clocks.start_grid(base.now_us())
    c = SyncClient(zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,))), clocks, cs,
                   [f"s01/d{i}" for i in range(n)])
    c.start()
    return c


def polled(c: SyncClient, predicate):
    """A wait_until predicate that first lets ``c`` take its results in (the tick loop's part)."""
    return lambda: c.poll() >= 0 and predicate()


def test_a_returning_time_service_is_asked_at_once_whatever_the_poll_interval(stack):  # noqa: F811
    """The resync by its cause: when the querier's matching listener sees a time service again,
    every device sends its exchange within RESUME_SPREAD_S (plus the workers' turn), also devices
    whose next exchange was 500 s away."""
    stack.router()
    n = 40
    clock = stack.start("clock", "clock", "--connect", stack.endpoint)
    c = live_client(stack.endpoint, n)
    try:
        wait_until(polled(c, c.ready), 30, "first burst", on_fail=stack.logs)
        wait_until(polled(c, lambda: len(c._heap) == n), 10, "no exchange under way")
        with c._cond:  # what long-settled devices look like: the next exchange minutes away
            c._heap = [(time.monotonic() + 500.0, slot) for _, slot in c._heap]
        clock.signal(15)
        clock.popen.wait(10)
        wait_until(polled(c, lambda: not c.service_present()), 20, "the service gone")
        resumes = len(c.resumes)
        before = c.valid.copy()
        stack.start("clock", "clock", "--connect", stack.endpoint)
        wait_until(polled(c, lambda: len(c.resumes) > resumes and np.all(c.sent_at > c.resumes[-1])), 30,
                   "every device asked the returned service", on_fail=stack.logs)
        late = float(np.max(c.sent_at - c.resumes[-1]))
        wait_until(polled(c, lambda: np.all(c.valid > before)), 10, "every device answered")
        report("time service returns", f"{n} devices, next exchange 500 s away; service stopped and started",
               f"matching seen -> every device's exchange sent within {late:.3f} s")
        assert late < 2 * RESUME_SPREAD_S, late
    finally:
        c.close()
        c.session.close()


def test_a_flapping_service_makes_no_device_step(stack):  # noqa: F811
    """A service that comes and goes, again and again, down each time until every device is past
    its holdover (1 s) and unsynced: devices resync each time it is back, onto the same line: no
    step, no new stream."""
    stack.router()
    n = 10
    service = RogueService(stack.endpoint)
    c = live_client(stack.endpoint, n, holdover_s=1.0)
    try:
        wait_until(polled(c, lambda: np.all(c.valid >= 3)), 30, "first sync")
        c.stamp(np.arange(n), np.array([c.clocks.read(s) for s in range(n)], float))  # the first step, taken
        assert not c.step.any()
        for cycle in range(4):
            service.close()
            wait_until(polled(c, lambda: not any(c.synced(s, c.clocks.read(s)) for s in range(n))), 10,
                       "every device past its holdover")
            valid = c.valid.copy()
            service = RogueService(stack.endpoint)
            wait_until(polled(c, lambda v=valid: np.all(c.valid >= v + 1)), 10, f"resync {cycle}")
            assert all(c.synced(s, c.clocks.read(s)) for s in range(n))
            assert not c.step.any(), f"cycle {cycle}: a device stepped"
        assert len(c.resumes) >= 4
    finally:
        c.close()
        c.session.close()
        service.close()
