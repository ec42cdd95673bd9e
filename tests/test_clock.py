"""Device clocks and their synchronisation (docs/reliability.md, "Device clocks").

Codec and estimator tests run without a network; the rest runs the real router, time service,
emulators and aggregator on loopback and measures each sample's timestamp against its
reference time from the truth tap (what an external reference system would give).

Every system test prints one ``CLOCK |`` line that docs/reliability.md collects:
``pytest tests/test_clock.py -s | grep 'CLOCK |'``.
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
from limbstream.device.sync import RESUME_SPREAD_S, RETRY_S, SLEW, SyncClient
from limbstream.timesync import JUMP_CONFIRM, SyncEstimator
from limbstream import kernel, wire, zconfig

T0 = 1_800_000_000_000_000  # us


def report(what: str, how: str, result: str) -> None:
    print(f"\nCLOCK | {what} | {how} | {result} |")


# ----------------------------------------------------------------------------- codec


def test_time_messages_round_trip_and_bad_payloads_have_reasons():
    r = wire.TimeRequest(7, T0)
    assert wire.decode_time_request(wire.encode_time_request(r)) == r
    a = wire.TimeAnswer(7, T0, T0 + 1_500_000, T0 + 1_500_030)
    raw = wire.encode_time_answer(a)
    assert len(raw) == wire.TIME_ANSWER_SIZE == 32 and wire.decode_time_answer(raw) == a
    bad_answers = {
        raw[:-1]: "size",
        bytes([2]) + raw[1:]: "version",
        wire.encode_time_answer(wire.TimeAnswer(7, T0, -5, 10)): "time_range",
        wire.encode_time_answer(wire.TimeAnswer(7, T0, 2**53, 2**53)): "time_range",
        wire.encode_time_answer(wire.TimeAnswer(7, T0, T0 + 10, T0 + 9)): "time_backwards",
    }
    for payload, reason in bad_answers.items():
        with pytest.raises(wire.WireError) as err:
            wire.decode_time_answer(payload)
        assert err.value.reason == reason
    for payload, reason in ((b"", "size"), (bytes([9]) + wire.encode_time_request(r)[1:], "version")):
        with pytest.raises(wire.WireError) as err:
            wire.decode_time_request(payload)
        assert err.value.reason == reason
    # device 2 s behind, 300 us out and 100 us back, 30 us inside the service
    offset, delay = wire.offset_delay(T0, T0 + 2_000_300, T0 + 2_000_330, T0 + 430)
    assert (offset, delay) == (2_000_000 + 100, 400)


def test_truth_tap_v2_carries_reference_times_and_v1_still_decodes():
    t = T0 + np.arange(25) * 20_000
    ref = t - 1234 + np.arange(25)  # a clock slightly off and drifting
    q = np.tile(np.float32([1, 0, 0, 0]), (25, 1))
    v2 = wire.encode_raw(wire.RawBatch(3, 40, t, q, ref))
    assert v2[0] == 2 and len(v2) == 28 + 25 * 24
    back = wire.decode_raw(v2)
    assert np.array_equal(back.t_us, t) and np.array_equal(back.ref_us, ref) and back.first_index == 40
    v1 = wire.decode_raw(wire.encode_raw(wire.RawBatch(3, 40, t, q)))
    assert v1.ref_us is None and np.array_equal(v1.t_us, t)
    backwards = wire.encode_raw(wire.RawBatch(3, 40, t, q, ref[::-1].copy()))
    with pytest.raises(wire.WireError) as err:
        wire.decode_raw(backwards)
    assert err.value.reason == "time_backwards"


def test_time_key_is_a_verbatim_chunk_wildcards_do_not_reach():
    key = zenoh.KeyExpr(wire.time_key())
    assert str(key) == "limbstream/@time"
    for pattern in (f"{wire.PREFIX}/*", f"{wire.PREFIX}/**", "**", wire.device_selector("config")):
        assert not zenoh.KeyExpr(pattern).intersects(key), pattern


# ----------------------------------------------------------------------------- device side, no network


def exchanges(local, service, n, start_s=0.0, every_s=1.0, seed=0, spike=0.0):
    """Four-timestamp exchanges of a device whose clock is ``local(T)``, against a service
    clock ``service(T)``; one-way delays 150 us + exponential(50 us) (+ a ``spike`` share of
    0..3 ms GIL-like stalls)."""
    rng = np.random.default_rng(seed)
    for i in range(n):
        T = T0 + (start_s + i * every_s) * 1e6
        d1, d2 = 150 + rng.exponential(50, 2) + (rng.random(2) < spike) * rng.uniform(0, 3000, 2)
        yield local(T), service(T + d1), service(T + d1) + 30, local(T + d1 + 30 + d2)


def test_estimator_finds_offset_and_drift_and_rejects_bad_exchanges():
    offset, drift = 1_734_000.0, 87e-6  # device 1.734 s ahead, 87 ppm fast

    def local(T):
        return T + offset + drift * (T - T0)
    est = SyncEstimator()
    for t in exchanges(local, lambda T: T, 40, every_s=2.0, spike=0.25):
        est.add(*t)
    for T in T0 + np.array([20.0, 79.0, 100.0]) * 1e6:  # inside and 21 s past the window
        L = local(T)
        assert abs(L + est.predict(L) - T) < 150, (T, L + est.predict(L) - T)
    assert abs(est.b + drift) < 5e-6, est.b
    assert est.add(local(T0), T0 + 5000, T0 + 9000, local(T0) + 1000) == "negative_rtt"
    L = local(T0 + 101e6)
    assert est.add(L, T0 + 101e6 + 3600e6, T0 + 101e6 + 3600e6, L + 300) == "future"
    assert est.add(L, T0 + 101e6 - 3600e6, T0 + 101e6 - 3600e6, L + 300) == "past"


def test_estimator_holds_back_a_service_jump_until_answers_agree():
    def local(T):
        return T + 500_000.0
    est = SyncEstimator()
    for t in exchanges(local, lambda T: T, 20):
        est.add(*t)
    jumped = list(exchanges(local, lambda T: T + 40_000, JUMP_CONFIRM + 1, start_s=20))
    assert [est.add(*t) for t in jumped[:JUMP_CONFIRM - 1]] == ["held"] * (JUMP_CONFIRM - 1)
    assert abs(est.predict(local(T0 + 21e6)) + 500_000) < 100  # still the old line
    assert est.add(*jumped[JUMP_CONFIRM - 1]) == "jump"
    assert abs(est.predict(local(T0 + 23e6)) + 460_000) < 200  # the new one
    assert len(est) == JUMP_CONFIRM


def client(n=1, **settings) -> SyncClient:
    """A SyncClient whose exchanges the test hands in (no session, no workers)."""
    base = TimeBase(1.0, T0)
    clocks = DeviceClocks(n, ClockSettings(**settings), 20_000.0, base)
    clocks.boot(T0)
    clocks.start_grid(T0)
    return SyncClient(None, clocks, ClockSettings(**settings), [f"s01/d{i}" for i in range(n)])


def feed(c: SyncClient, local, service, n, start_s, every_s=1.0):
    for i, (t1, t2, t3, t4) in enumerate(exchanges(local, service, n, start_s, every_s)):
        payload = wire.encode_time_answer(wire.TimeAnswer(i + 1, round(t1), round(t2), round(t3)))
        c._apply(0, i + 1, round(t1), round(t4), payload)


def stamps(c: SyncClient, local, start_s, seconds):
    """Stamps of a device sampling at 50 Hz on its own clock from ``start_s``, and the true times."""
    T = T0 + (start_s + np.arange(0, seconds, 0.02)) * 1e6
    out = np.array([c.stamp(np.array([0]), np.array([local(t)]))[0] for t in T])
    return T, out


def test_a_service_clock_jump_is_followed_at_the_bounded_slew():
    c = client()

    def local(T):
        return T - 250_000.0 + 40e-6 * (T - T0)
    feed(c, local, lambda T: T, 16, 0.0)
    T, s = stamps(c, local, 16.0, 4.0)
    assert np.abs(s - T).max() < 200 and not c.stepped.any()
    feed(c, local, lambda T: T + 100_000, JUMP_CONFIRM + 2, 20.0)  # the service jumps 100 ms
    T, s = stamps(c, local, 20.0 + JUMP_CONFIRM + 2, 10.0)
    err = s - T
    assert not c.stepped.any() and c.synced(0, local(T[-1]))
    rate = (err[50:] - err[:-50]) / (T[50:] - T[:-50])  # over each second (stamps are float64 us)
    assert rate.max() <= SLEW + 5e-6, rate.max()  # never faster than the slew
    assert 0 < err[-1] < 100_000 and err[-1] > err[0] + 0.9 * SLEW * (T[-1] - T[0])  # on its way, not there


def test_first_sync_of_a_streaming_device_is_a_step_and_holdover_expiry_unsyncs():
    c = client(holdover_s=30.0)

    def local(T):
        return T + 1_200_000.0
    T, s = stamps(c, local, 0.0, 1.0)  # streaming before any answer: its own clock
    assert np.allclose(s - T, 1_200_000) and not c.synced(0, local(T[-1]))
    feed(c, local, lambda T: T, 4, 1.0)
    T, s = stamps(c, local, 5.0, 0.1)
    assert c.stepped[0] or abs(s[0] - T[0]) < 300  # stepped at the first stamp after the sync
    assert abs(s[-1] - T[-1]) < 300 and c.synced(0, local(T[-1]))
    assert not c.synced(0, local(T0 + 40e6))  # 35 s without an answer > 30 s holdover
    assert c.status(0).clock_offset_ms is not None


def test_stamper_steps_slews_and_leaves_unsynced_devices_on_their_own_clock():
    """One C call stamps devices in every state: first stamp (on its line), a pending step, a
    slew-limited move towards a new line, on its line, and never synced (its own clock)."""
    st = kernel.Stamper(5, SLEW)
    st.ever[:4] = True
    st.a[:] = 1000.0
    st.b[:] = 50e-6
    st.ref[:] = 1e9
    local = np.full(5, 1e9)
    first, steps = st.stamp(np.arange(5), local)
    assert np.array_equal(first, np.r_[np.full(4, 1e9 + 1000.0), 1e9]) and steps == 0 and not st.stepped.any()
    st.a[1] = st.a[2] = 5000.0   # new lines 4 ms away: device 1 steps, device 2 slews
    st.step[1] = True
    dt = 20_000.0
    out, steps = st.stamp(np.array([4, 3, 2, 1, 0]), local + dt)   # any order of slots
    drift = 50e-6 * dt
    assert out[3] == 1e9 + dt + 5000.0 + drift and steps == 1 and st.stepped[1] and not st.step[1], "a step"
    assert out[2] == 1e9 + dt + 1000.0 + drift + SLEW * dt, "the slew is bounded"
    assert out[4] == out[1] == 1e9 + dt + 1000.0 + drift and out[0] == 1e9 + dt, (out, "on its line; own clock")
    later, steps = st.stamp(np.array([1]), local[:1] + 2 * dt)
    assert steps == 0 and not st.stepped[1] and later[0] == 1e9 + 2 * dt + 5000.0 + 50e-6 * 2 * dt


def test_past_its_holdover_a_device_polls_at_the_short_back_off():
    """However long a device's poll interval grew, its next exchange is due by the end of its
    holdover, and while no answer comes it asks again after 1, 2, 4, 8, 8 ... s."""
    c = client(holdover_s=4.0, poll_s=512.0)
    delays = [c._apply(0, i + 1, round(t1), round(t4), wire.encode_time_answer(wire.TimeAnswer(i + 1, round(t1), round(t2), round(t3))))
              for i, (t1, t2, t3, t4) in enumerate(exchanges(lambda T: T, lambda T: T, 24, 0.0))]
    assert max(delays) <= 4.0 and delays[-1] == 4.0, delays
    lost = [c._apply(0, 99, 0, 0, None) for _ in range(6)]
    assert lost == [1.0, 2.0, 4.0, RETRY_S, RETRY_S, RETRY_S], lost


# ----------------------------------------------------------------------------- emulator, no network


def test_devices_sample_on_their_own_clock_grid(tmp_path):
    """A fast clock takes more samples than a slow one; stamps increase; each sample's stamp
    minus its reference time is the clock's error (no sync)."""
    from limbstream.device_emulator.emulator import Emulator, EmulatorSettings
    from limbstream.device.feeds import GeneratorFeed
    from limbstream.device.host import HostSettings

    session = zconfig.open_session(zconfig.ZenohSettings(mode="peer", connect=()))
    try:
        cs = ClockSettings(offset_ms=50, drift_ppm=1000, sync=False, seed=3)
        e = Emulator(session, {"s01": GeneratorFeed(1, 50.0)}, EmulatorSettings(HostSettings(truth=False), clock=cs))
        e.declare()
        e.clocks.boot(T0)
        e.start_us = T0
        e.clocks.start_grid(T0)
        t, ref = collections.defaultdict(list), collections.defaultdict(list)
        for k in range(5000):
            e.step(k)
            row = k % e._ring
            for slot in np.flatnonzero(e._ring_n[row] >= 0):
                t[slot].append(e._ring_t[row, slot])
                ref[slot].append(e._ring_ref[row, slot])
        span_s = 5000 * e.tick_us / 1e6
        for slot in range(10):
            expect = (span_s * 1e6 * (1 + e.clocks.drift[slot]) - e.clocks.phase_us[slot]) / 20_000
            assert abs(e.n[slot] - expect) <= 1.5, (slot, e.n[slot], expect)
            assert np.all(np.diff(t[slot]) > 0)
            err = np.array(t[slot]) - np.array(ref[slot])
            want = e.clocks.offset_us[slot] + e.clocks.drift[slot] * (np.array(ref[slot]) - T0)
            assert np.abs(err - want).max() <= 1.5  # both rounded to us
        assert e.n.max() - e.n.min() >= 3  # +-1000 ppm over 100 s: samples apart
        e.undeclare()
    finally:
        session.close()


# ----------------------------------------------------------------------------- live system


class Taps:
    """Truth-tap samples as they arrive: per device, (reference time, stamp) pairs."""

    def __init__(self, endpoint: str, subjects: str = "*"):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.sub = self.session.declare_subscriber(wire.device_selector("raw", subjects),
                                                   zenoh.handlers.FifoChannel(1 << 16))
        self.samples: dict[str, list] = collections.defaultdict(list)

    def poll(self) -> dict[str, np.ndarray]:
        while (sample := self.sub.try_recv()) is not None:
            subject, segment, _ = wire.parse_device_key(str(sample.key_expr))
            b = wire.decode_raw(sample.payload.to_bytes())
            self.samples[f"{subject}/{segment}"].extend(zip(b.ref_us.tolist(), b.t_us.tolist()))
        return {k: np.array(v, np.int64) for k, v in self.samples.items()}

    def errors_after(self, t_us: float) -> dict[str, np.ndarray]:
        """|stamp - reference| per device, us, for samples taken after true time ``t_us``."""
        return {k: np.abs(v[v[:, 0] > t_us, 1] - v[v[:, 0] > t_us, 0]) for k, v in self.poll().items()}

    def close(self):
        self.session.close()


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
        assert len(p99) == 10 and max(p99.values()) <= 5000, p99
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
