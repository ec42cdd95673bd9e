"""Live frames through a real router, as an independent client sees them: per subject, their
``seq`` and times strictly increase over a run, and a live deadline the aggregator's loop misses
(here: its loop stalled in-process by holding its lock) is counted in the subject's stats
(docs/protocol.md, "Live frames")."""
from __future__ import annotations

import time

import numpy as np
import pytest
from support.stack import aggregator_in_thread, stack, wait_until  # noqa: F401  (stack is a fixture)

from limbstream import wire
from limbstream.services.outputs.subscription import Subscription

pytestmark = pytest.mark.e2e

STALL_S = 0.3
STALLS = 3


def test_live_frames_keep_time_order_and_missed_deadlines_are_counted(stack):  # noqa: F811
    frames: list[wire.PoseFrame] = []
    stats: list[dict] = []
    with aggregator_in_thread(stack) as (agg, settings):
        stack.emulator(1)
        with Subscription(settings, "s01", ("pose", "stats")) as sub:
            def take() -> None:
                for item in sub.drain():
                    if item.kind == "stats":
                        stats.append(item.value)
                    elif item.value.kind == wire.KIND_LIVE:
                        frames.append(item.value)
            wait_until(lambda: take() or len(frames) >= 50, 60, "50 live frames of s01", on_fail=stack.logs)
            for _ in range(STALLS):  # the loop waits for its lock: a stalled loop, deadlines pass
                with agg.lock:
                    time.sleep(STALL_S)  # (the stall itself, not a wait for something)
                want = len(frames) + 25
                wait_until(lambda n=want: take() or len(frames) >= n, 30, "25 more live frames", on_fail=stack.logs)
            counted = len(stats)
            wait_until(lambda: take() or len(stats) > counted, 10, "a stats message after the stalls")
    seq = np.array([f.seq for f in frames], np.int64)
    t = np.array([f.t_us for f in frames], np.int64)
    assert (np.diff(seq) == 1).all(), "seq goes up by one per frame (none lost on loopback)"
    step = np.diff(t)
    assert (step > 0).all(), f"live frame times go back: {step[step <= 0]} us at seq {seq[1:][step <= 0]}"
    period_us = 1e6 / wire.DEVICE_RATE_HZ
    assert step.min() >= 0.45 * period_us, step.min()
    missed = stats[-1]["live_missed"]
    assert missed >= STALLS * (STALL_S * wire.DEVICE_RATE_HZ - 2), stats[-1]
    # each missed deadline is a frame period's worth of time with no frame
    gaps = np.round(step / period_us).astype(np.int64) - 1
    assert gaps.sum() >= STALLS * (STALL_S * wire.DEVICE_RATE_HZ - 2), gaps
