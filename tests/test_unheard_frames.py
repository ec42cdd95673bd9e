"""Frames nobody hears are made but not sent, through a real router: while no subscriber matches a
subject's pose key, the aggregator counts its frames as ``unheard``; a client that subscribes gets
its pose frames and joint angles from then on, every frame in turn, and none is counted unheard
while it listens; once it leaves, they are counted again (docs/protocol.md, "Pose frame")."""
from __future__ import annotations

import numpy as np
import pytest
from support.stack import aggregator_in_thread, stack, wait_until  # noqa: F401  (stack is a fixture)

from limbstream import wire
from limbstream.services.outputs.subscription import Subscription

pytestmark = pytest.mark.e2e


def test_frames_are_sent_only_while_a_subscriber_hears_them(stack):  # noqa: F811
    live: list[wire.PoseFrame] = []
    angles: list = []
    stats: list[dict] = []
    with aggregator_in_thread(stack) as (agg, settings):
        stack.emulator(1)
        wait_until(lambda: agg.loop.unheard >= 100, 60, "100 frames of s01 made with no subscriber", on_fail=stack.logs)
        assert agg.loop.frames > 0
        with Subscription(settings, "s01", ("pose", "angles", "stats")) as sub:
            def take() -> None:
                for item in sub.drain():
                    if item.kind == "stats":
                        stats.append(item.value["aggregator"])
                    elif item.kind == "angles":
                        angles.append(item.value)
                    elif item.value.kind == wire.KIND_LIVE:
                        live.append(item.value)
            wait_until(lambda: take() or len(live) >= 25, 30, "25 live frames once subscribed", on_fail=stack.logs)
            heard_from = len(stats) + 1  # (the next stats message may have left before we were heard)
            wait_until(lambda: take() or len(stats) >= heard_from + 2, 30, "stats messages while subscribed")
            assert len(angles) > 0, "joint angles come to a subscriber of them"
            unheard_while_subscribed = stats[-1]["unheard"] - stats[heard_from]["unheard"]
            seq = np.array([f.seq for f in live])
        assert unheard_while_subscribed == 0, stats[heard_from:]
        assert (np.diff(seq) == 1).all(), "every live frame reaches a subscriber in turn"
        assert seq[0] > 0, "seq counts the frames made before anyone listened"
        after = agg.loop.unheard
        wait_until(lambda: agg.loop.unheard > after + 50, 30, "frames counted unheard again once the client left")
