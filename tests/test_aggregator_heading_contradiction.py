"""Heading correction in the aggregator, a subject whose rest pose is not what it says beside one
whose is (limbstream.heading.contradiction): the first stops being corrected, its stats say which
joints (``heading_contradicted``, through the stats codec as the dashboard reads it) and the log
says so once; the second goes on being corrected and its field stays null."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from limbstream import wire
from limbstream.wire import SEGMENTS
from test_aggregator_heading import session


@pytest.mark.slow  # a 70 s session, fed tick by tick
def test_a_mislabelled_subject_stops_being_corrected_and_says_so(caplog):
    with caplog.at_level(logging.WARNING, logger="limbstream.aggregator"):
        agg, _, stats, _ = session(True, subjects=(("good", SEGMENTS, None), ("wrong", SEGMENTS, None)),
                                   seconds=70.0, mislabelled=("wrong",))
        sent: dict[str, bytes] = {}
        agg._publish_stats = lambda subject, payload: sent.__setitem__(subject, payload)
        agg.publish_stats(70.0)
        agg.publish_stats(71.0)
    said = [r.getMessage() for r in caplog.records if "contradict" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("subject wrong:") and "hip_l" in said[0], said
    wrong, good = wire.decode_stats(sent["wrong"]), wire.decode_stats(sent["good"])
    assert {"hip_l", "hip_r"} <= set(wrong["heading_contradicted"]), wrong["heading_contradicted"]
    assert all(0.5 < v <= 1.0 for v in wrong["heading_contradicted"].values())
    assert good["heading_contradicted"] is None
    assert all(d["heading_offset_deg"] == 0.0 and d["heading_confidence"] < 0.01 for d in wrong["devices"])
    offsets = np.array([d["heading_offset_deg"] for d in good["devices"]])
    assert np.abs(offsets).max() > 0.5 and all(d["heading_confidence"] > 0.1 for d in good["devices"]), offsets
    seen = [s["heading_contradicted"] for s in stats["wrong"]]
    first = next(k for k, v in enumerate(seen) if v)  # once found, found for good
    assert all(seen[first:]) and not any(stats["good"][k]["heading_contradicted"] for k in range(len(seen)))
