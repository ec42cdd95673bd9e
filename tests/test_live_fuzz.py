"""Live fuzz: random bytes and random JSON on every key the services listen to, while a real
subject streams through router -> aggregator (and the dashboard). Nothing crashes, every bad
message is counted by its reason (the counts are predicted from the payloads sent), and the
good devices lose nothing."""
from __future__ import annotations

import collections
import json
import os
import subprocess
import sys

import numpy as np
import pytest
import zenoh
from support.stack import ROOT, http_json, stack, wait_until  # noqa: F401  (fixture)

from limbstream import wire, zconfig
from limbstream.sources import SEGMENTS

SEED = 7


class Watch:
    """Latest stats per device of the real subject (fuzzed stats keys are ignored, counted)."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.sub = self.session.declare_subscriber(wire.stats_key("s01"), zenoh.handlers.FifoChannel(4096))
        self.devices: dict[str, dict] = {}
        self.extra: dict = {}
        self.undecodable = 0

    def poll(self) -> dict[str, dict]:
        while (sample := self.sub.try_recv()) is not None:
            try:
                data = wire.decode_stats(sample.payload.to_bytes())
            except wire.WireError:
                self.undecodable += 1
                continue
            if "aggregator" in data:  # the aggregator's own message, not a fuzzed look-alike
                self.extra = data
                for d in data["devices"]:
                    self.devices[d["device"]] = d
        return self.devices


def random_json(rng: np.random.Generator, depth: int = 0):
    kind = rng.integers(0, 7 if depth < 3 else 4)
    if kind == 0:
        return None
    if kind == 1:
        return float(rng.choice([np.nan, np.inf, -1.0, 1e308, 0.5]))
    if kind == 2:
        return int(rng.integers(-(2**62), 2**62)) * int(rng.choice([1, 10**30]))
    if kind == 3:
        return "".join(map(chr, rng.integers(32, 0x2FF, rng.integers(0, 12))))
    if kind == 4:
        return [random_json(rng, depth + 1) for _ in range(rng.integers(0, 4))]
    keys = ["threshold", "max_len", "devices", "subject", "t", "x"]
    return {str(rng.choice(keys)): random_json(rng, depth + 1) for _ in range(rng.integers(0, 4))}


def payloads(rng: np.random.Generator, n: int) -> list[bytes]:
    """Random bytes, random JSON, corrupted points and truth batches, in equal shares."""
    out = []
    for k in range(n):
        kind = k % 4
        if kind == 0:
            out.append(rng.bytes(int(rng.integers(0, 120))))
        elif kind == 1:
            out.append(json.dumps(random_json(rng)).encode())
        elif kind == 2:  # a real-looking point with one field broken
            b = bytearray(wire.encode_point(wire.SegmentPoint(1, 0, 0, 0, (1.0, 0.0, 0.0, 0.0))))
            b[int(rng.integers(0, len(b)))] ^= 0xFF
            out.append(bytes(b[: int(rng.integers(30, 40))]))
        else:
            out.append(b"\x01" + rng.bytes(int(rng.integers(19, 200))))
    return out


def expected_reason(kind: str, payload: bytes) -> str | None:
    """The reason the aggregator must count for ``payload`` on a ``kind`` key (None: decodes)."""
    decoder = wire.decode_point if kind == "seg" else wire.decode_raw
    try:
        decoder(payload)
    except wire.WireError as exc:
        return exc.reason if kind == "seg" else f"raw_{exc.reason}"
    return None


def test_random_bytes_and_json_on_every_key(stack):  # noqa: F811
    stack.router()
    aggregator = stack.aggregator()
    emulator = stack.emulator(1, 1.0)
    url = stack.dashboard()
    watch = Watch(stack.endpoint)
    try:
        wait_until(lambda: len(watch.poll()) == 10 and all(d["online"] and d["points"] > 3
                                                          for d in watch.devices.values()),
                   60, "s01's 10 devices streaming", on_fail=stack.logs)
        before = {k: dict(d) for k, d in watch.devices.items()}
        rng = np.random.default_rng(SEED)
        fuzz = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
        expected: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
        sent = collections.Counter()
        config_errors = 0
        try:
            bodies = payloads(rng, 4000)
            for i, body in enumerate(bodies):
                segment = SEGMENTS[i % len(SEGMENTS)]
                # the good subject's own device keys: only payloads that cannot decode, so the
                # expected counts are exact (a valid forged point would be accepted, by design)
                for kind, key in (("seg", wire.seg_key("s01", segment)), ("raw", wire.raw_key("s01", segment))):
                    reason = expected_reason(kind, body)
                    if reason is not None:
                        fuzz.put(key, body)
                        expected[f"s01/{segment}"][reason] += 1
                        sent[kind] += 1
                # everything else: the other subscribed keys, invented devices, malformed keys
                for key in ("limbstream/s01/stats", "limbstream/s01/pose", "limbstream/fz01/stats",
                            "limbstream/fz01/pose", f"limbstream/fz{i % 50:02d}/x{i % 7}/seg",
                            f"limbstream/fz{i % 50:02d}/x{i % 7}/raw", "limbstream/s01/hip/alive"):
                    fuzz.put(key, body)
                    sent["other"] += 1
                if i % 40 == 0:  # config queries with random JSON reach the device's queryable
                    for reply in fuzz.get(wire.config_key("s01", segment), payload=body, timeout=5.0):
                        config_errors += reply.err is not None
                    sent["config"] += 1
        finally:
            fuzz.close()
        print(f"\nlive fuzz sent {dict(sent)}; config queries refused: {config_errors}")

        def counted():
            devices = watch.poll()
            return all(
                all((devices[dev].get("dropped_by_reason") or {}).get(r, 0) >= n for r, n in reasons.items())
                for dev, reasons in expected.items()) and devices
        devices = wait_until(counted, 30, "every bad payload counted on its device",
                             on_fail=lambda: f"\nexpected {dict(expected)}\ngot "
                             f"{ {k: d.get('dropped_by_reason') for k, d in watch.devices.items()} }")
        for dev, reasons in expected.items():
            got = devices[dev]["dropped_by_reason"]
            assert got == dict(reasons), f"{dev}: counted {got}, sent {dict(reasons)}"
        # the good streams were not disturbed: no gaps, points kept coming, the error stays small
        wait_until(lambda: all(watch.poll()[k]["points"] > before[k]["points"] + 3 for k in before),
                   30, "s01 points to keep coming")
        for d in watch.poll().values():
            assert d["online"] and d["gaps"] == 0, d
            assert d["aad_deg"] is not None and d["aad_deg"] < 5.0, d
        bad = watch.extra["aggregator"]["bad_keys"]
        print(f"aggregator bad_keys {bad}")
        assert sum(bad.values()) > 0, bad
        assert bad.keys() <= wire.UNCHARGED.keys(), f"reasons missing from docs/protocol.md: {bad}"
        assert config_errors >= sent["config"] * 0.9, (config_errors, sent)
        assert aggregator.alive() and emulator.alive(), stack.logs()
        status, health = http_json(url + "/health")
        assert status == 200, (status, health)
    finally:
        watch.session.close()


# ----------------------------------------------------------------------------- bad files and flags


BAD_INVOCATIONS = [
    (["emulate", "--rate", "-5"], "--rate"),
    (["emulate", "--subjects", "0"], "--subjects"),
    (["emulate", "--raw-batch", "999999"], "--raw-batch"),
    (["emulate", "--source", "{tmp}/broken.bvh"], "broken.bvh"),
    (["emulate", "--source", "{tmp}/broken.csv"], "broken.csv"),
    (["emulate", "--source", "{tmp}/missing.npz"], "missing.npz"),
    (["emulate", "--zenoh-config", "{tmp}/bad.json"], "bad.json"),
    (["aggregate", "--subjects", "a/b"], "a/b"),
    (["aggregate", "--tick", "0"], "--tick"),
    (["router", "--zenoh-config", "{tmp}/list.json"], "expected a JSON object"),
]


@pytest.mark.parametrize("argv, names", BAD_INVOCATIONS, ids=[" ".join(a) for a, _ in BAD_INVOCATIONS])
def test_bad_files_and_flags_get_clear_errors(tmp_path, argv, names):
    """Exit status != 0, one line naming the flag or file, no traceback."""
    (tmp_path / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    (tmp_path / "broken.csv").write_text("Time (s),Quaternion W\n0.0,1.0\nnot,a,number\n")
    (tmp_path / "bad.json").write_text("{not json")
    (tmp_path / "list.json").write_text("[1, 2]")
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    result = subprocess.run([sys.executable, "-m", "limbstream.cli", *args], cwd=ROOT, capture_output=True,
                            text=True, timeout=60, env=os.environ | {"LIMBSTREAM_ROUTER": "tcp/127.0.0.1:1"})
    err = result.stderr + result.stdout
    assert result.returncode != 0, err
    assert names in err and "Traceback" not in err, err
