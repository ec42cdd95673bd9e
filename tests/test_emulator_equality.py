"""The emulator's batched computations against the plain ones they replaced
(tests/support/reference_emulator, the code of ded8972): the generator's orientations, and what an
emulator publishes tick by tick (segment points and truth-tap batches, byte for byte, in order),
on the same input."""
from __future__ import annotations

import random

import numpy as np
import pytest
from support.reference_emulator import ReferenceEmulator, orientations

from limbstream import quat, zconfig
from limbstream.device.clocks import ClockSettings
from limbstream.device.feeds import GeneratorFeed, LoopFeed
from limbstream.device.host import HostSettings
from limbstream.device_emulator.emulator import Emulator, EmulatorSettings
from limbstream.sources import Motion
from limbstream.sources.generator import GeneratorSource

T0 = 1_790_000_000_000_000


@pytest.mark.parametrize("mounting", [False, True])
def test_the_generator_turns_its_tree_as_it_did_one_rotation_at_a_time(mounting):
    for seed in range(6):
        source = GeneratorSource(seed, 50.0, mounting_offsets=mounting)
        for t in (np.arange(60 * 50 + 7) / 50.0, np.array([0.0]), np.arange(3) / 50.0 + 1234.5):
            assert np.array_equal(source.orientations(t), orientations(source, t)), (seed, len(t))


class Recorder:
    """A publisher that keeps what it is given: ``sent`` (key, payload) in the order of puts."""

    def __init__(self, key: str, sent: list):
        self.key, self.sent = key, sent

    def put(self, payload) -> None:
        self.sent.append((self.key, bytes(payload)))

    def undeclare(self) -> None:
        pass


def feeds() -> dict:
    """Generator subjects, a clip looped and a clip played once (its devices end mid-run)."""
    rng = np.random.default_rng(5)
    q = quat.normalize(np.cumsum(rng.normal(0, 0.05, (173, 10, 4)), axis=0) + [1, 0, 0, 0])
    clip = Motion(np.arange(173) / 50.0, q, GeneratorSource.segments, "clip")
    return {"s00": LoopFeed(clip, 50.0, start=0.5), "s01": GeneratorFeed(1, 50.0), "s02": LoopFeed(clip, 50.0, once=True),
            "s03": GeneratorFeed(3, 50.0)}


def published(kind: type, session, clock: ClockSettings, ticks: int) -> list[tuple[str, bytes]]:
    """(key, payload) of every put of an emulator of ``kind`` over ``ticks`` ticks and its finish."""
    random.seed(11)  # the stream ids
    e = kind(session, feeds(), EmulatorSettings(HostSettings(truth=True), clock=clock))
    e.declare()
    sent: list[tuple[str, bytes]] = []
    for d in e.devices:
        d.publisher, d.raw_pub = Recorder(f"seg/{d.subject}/{d.segment}", sent), Recorder(f"raw/{d.subject}/{d.segment}", sent)
    e.clocks.boot(T0)
    e.start_us = T0
    e.clocks.start_grid(T0)
    for k in range(ticks):
        e.step(k)
    e.finish()
    e.undeclare()
    return sent


@pytest.mark.parametrize("clock", [ClockSettings(sync=False),
                                   ClockSettings(offset_ms=40, drift_ppm=3000, jitter_us=200, sync=False, seed=4)],
                         ids=["shared grid", "own clocks"])
def test_the_emulator_publishes_what_it_did_device_by_device(clock):
    session = zconfig.open_session(zconfig.ZenohSettings(mode="peer", connect=()))
    try:
        new = published(Emulator, session, clock, 600)
        old = published(ReferenceEmulator, session, clock, 600)
    finally:
        session.close()
    assert sum(key.startswith("raw/") for key, _ in new) > 100 and sum(key.startswith("seg/") for key, _ in new) > 100
    assert len(new) == len(old)
    assert new == old
