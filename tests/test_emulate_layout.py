"""``limbstream emulate --layout full``: a device per segment of the full body, each publishing
its segment points and announcing a body of that layout, the subject's truth tap carrying all
of them (e2e, a real router on loopback)."""
from __future__ import annotations

import json
import threading

import pytest
import zenoh
from support.stack import stack, wait_until  # noqa: F401  (fixture)

from limbstream import wire, zconfig
from limbstream.body import FULL, Body

pytestmark = pytest.mark.e2e


class Heard:
    """Which (subject, segment) published segment points, and the segments of each subject's
    truth-tap messages, as a client of the router hears them."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.lock = threading.Lock()
        self.points: set[tuple[str, str]] = set()
        self.truth: dict[str, set[str]] = {}
        self.subs = [self.session.declare_subscriber(f"{wire.PREFIX}/*/*/{wire.SEG}", self._point),
                     self.session.declare_subscriber(f"{wire.PREFIX}/*/{wire.TRUTH}", self._truth)]

    def _point(self, sample: zenoh.Sample) -> None:
        subject, segment, _ = wire.parse_device_key(str(sample.key_expr))
        wire.decode_point(sample.payload.to_bytes())
        with self.lock:
            self.points.add((subject, segment))

    def _truth(self, sample: zenoh.Sample) -> None:
        subject, _ = wire.parse_subject_key(str(sample.key_expr))
        segments = {segment for segment, _ in wire.decode_truth(sample.payload.to_bytes())}
        with self.lock:
            self.truth.setdefault(subject, set()).update(segments)

    def status(self, subject: str, segment: str) -> dict | None:
        replies = [r.ok for r in self.session.get(wire.config_key(subject, segment), timeout=5.0) if r.ok]
        return json.loads(replies[0].payload.to_bytes()) if replies else None

    def close(self) -> None:
        self.session.close()


@pytest.mark.parametrize("extra, height", [((), 1.75), (("--height-m", "1.6,1.9"), None)],
                         ids=["default body", "--height-m"])
def test_emulate_layout_full_runs_15_devices_per_subject_announcing_the_full_body(stack, extra, height):  # noqa: F811
    stack.router()
    heard = Heard(stack.endpoint)
    try:
        stack.emulator(2, 1.0, "--layout", "full", *extra)
        want = {(s, seg) for s in ("s01", "s02") for seg in FULL.segment_names}

        def all_heard() -> bool:
            with heard.lock:
                return heard.points >= want and all(heard.truth.get(s) == set(FULL.segment_names)
                                                    for s in ("s01", "s02"))
        wait_until(all_heard, 60, "points and truth of the 15 segments of both subjects", on_fail=stack.logs)
        assert {seg for _, seg in heard.points} == set(FULL.segment_names)
        heights = {"s01": height or 1.6, "s02": height or 1.9}
        for subject in ("s01", "s02"):
            for segment in ("l_foot", "chest", "hip"):
                status = wait_until(lambda s=subject, g=segment: heard.status(s, g), 30, f"{subject}/{segment}'s status")
                body = wire.decode_body(status["body"])
                assert status["body"]["layout"] == "full" and body.layout == FULL
                assert body.lengths == Body.from_height(FULL, heights[subject]).lengths
    finally:
        heard.close()
