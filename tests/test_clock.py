"""Device clocks and their synchronisation (docs/reliability.md, "Device clocks").

The codec, the estimator, the sync client and the emulator's clocks, without a network; the
live system's clocks: tests/test_clock_live.py.
"""
from __future__ import annotations

import collections

import numpy as np
import pytest
import zenoh

from limbstream.device.clocks import ClockSettings, DeviceClocks, TimeBase
from limbstream.device.sync import RETRY_S, SLEW, SyncClient
from limbstream.timesync import JUMP_CONFIRM, SyncEstimator
from limbstream import kernel, wire, zconfig

T0 = 1_800_000_000_000_000  # us


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


def test_a_jittery_path_is_not_taken_for_service_jumps():
    """One-way delays of 10 +- 5 ms (uniform, each direction): an answer skewed by the jitter
    is not held back as a service jump; holding such answers back picked the skewed ones, three of
    them "agreed", and the window restarted from them: 3-6 ms off for a minute (one device in a
    few hundred, the live test's failure). 200 devices of 80 exchanges a second apart: nothing
    held, every device's line within 2.5 ms of the truth at its end."""
    rng = np.random.default_rng(3)
    outcomes: collections.Counter = collections.Counter()
    worst = 0.0
    for _ in range(200):
        offset, drift = rng.uniform(-2e6, 2e6), rng.uniform(-100e-6, 100e-6)

        def local(T, offset=offset, drift=drift):
            return T + offset + drift * (T - T0)
        est = SyncEstimator()
        for i in range(80):
            T = T0 + i * 1e6
            d1, d2 = rng.uniform(5_000, 15_000, 2)
            outcomes[est.add(local(T), T + d1, T + d1 + 50, local(T + d1 + 50 + d2))] += 1
        L = local(T0 + 80e6)
        worst = max(worst, abs(L + est.predict(L) - (T0 + 80e6)))
    assert outcomes == {"ok": 200 * 80}, outcomes
    assert worst < 2500, worst


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
        # (with the truth tap: the reference times are its)
        e = Emulator(session, {"s01": GeneratorFeed(1, 50.0)}, EmulatorSettings(HostSettings(truth=True), clock=cs))
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
