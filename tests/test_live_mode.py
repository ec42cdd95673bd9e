"""Live mode end to end: a CMU clip streamed through a real router by real emulators
(one with fastSW's live rule, one without) into a real aggregator; its per-device live figures,
measured against the truth tap, show the bound the devices keep."""
from __future__ import annotations

import numpy as np

from limbstream import wire
from limbstream.sources import load_npz
from stack import stack, wait_for_subscribers, wait_until  # noqa: F401  (fixture)

BOUND_DEG = 5.0


def test_live_rule_bounds_the_live_view_through_a_router(stack, watch, cmu_npz, tmp_path):  # noqa: F811
    """s01 runs --live-bound-deg 5, s02 the same clip without the rule: s01's live view is within
    the bound at every truth sample (p99 and max, with margin for float32), s02's held view is
    far off; both reconstruct the exact frames alike, and the rule costs more points (at most 3x at TH 1e-2)."""
    motion = load_npz(cmu_npz)[0]
    m = len(motion.t)
    clip = tmp_path / "clip.npz"  # the first clip alone, which both subjects play from its start
    np.savez(clip, **{f"clip_{motion.name}": motion.q.astype(np.float32)}, fs=motion.fs,
             segment_names=np.array(motion.segments), rest_pose=np.array(motion.rest_pose))
    stack.aggregator()
    keys = [k for s in ("s01", "s02") for seg in motion.segments for k in (wire.seg_key(s, seg), wire.raw_key(s, seg))]
    wait_for_subscribers(stack.endpoint, keys, "the aggregator's subscriptions", on_fail=stack.logs)
    common = ("--source", str(clip), "--same-start", "--once", "--max-len", "25", "--threshold", "1e-2")
    stack.emulator(1, 10.0, *common, "--live-bound-deg", str(BOUND_DEG))
    stack.emulator(1, 10.0, *common, "--first-subject", "2")

    def finished():
        devices = watch.poll()
        done = [d for d in devices.values()
                if d["final"] and d["error_samples"] == m and d["live_bound_deg"] is not None]  # config polled
        return len(done) == 20 and devices
    def report():
        return stack.logs() + "\n" + "\n".join(
            f"{k} final={d['final']} compared={d['error_samples']}/{m} samples={d['samples']} "
            f"points={d['points']} dropped={d['dropped_by_reason']}" for k, d in sorted(watch.devices.items()))
    devices = wait_until(finished, 60, "every device of s01 and s02 to finish its clip", on_fail=report)
    on = [d for k, d in devices.items() if k.startswith("s01/")]
    off = [d for k, d in devices.items() if k.startswith("s02/")]
    assert {d["live_bound_deg"] for d in on} == {BOUND_DEG} and {d["live_bound_deg"] for d in off} == {0.0}

    def figures(group):
        return {name: max(d[name] for d in group) for name in ("live_err_deg", "live_p99_deg", "live_max_deg")} | {
            "icr": sum(d["points"] for d in group) / sum(d["samples"] for d in group),
            "aad": float(np.mean([d["aad_all_deg"] for d in group]))}
    with_rule, without = figures(on), figures(off)
    print(f"\nlive rule {BOUND_DEG:g} deg: {with_rule}\nno live rule: {without}")
    assert with_rule["live_max_deg"] <= BOUND_DEG + 0.05, with_rule
    assert with_rule["live_p99_deg"] <= BOUND_DEG, with_rule
    assert without["live_p99_deg"] >= 3 * BOUND_DEG, without
    assert without["live_err_deg"] > 2 * with_rule["live_err_deg"], (with_rule, without)
    assert with_rule["aad"] <= without["aad"] + 0.05, "the extra points only help the exact frames"
    assert without["icr"] < with_rule["icr"] < 3 * without["icr"], (with_rule, without)
