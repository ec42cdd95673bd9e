"""The dashboard's tests' pieces: fixtures of a Zenoh router for a module, a session publishing
on it (``pub``) and a dashboard client (``client``); device stats and pose frames as the
aggregator sends them, a device's config queryable."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import zenoh
from fastapi.testclient import TestClient

from limbstream import wire, zconfig
from limbstream.launch import free_port, wait_until
from limbstream.services.dashboard.app import create_app
from limbstream.services.dashboard.settings import DashboardSettings

TOKEN = "test-token-123"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def router():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zconfig.open_session(zconfig.ZenohSettings(mode="router", connect=(), listen=(endpoint,)))
    yield endpoint
    session.close()


def make_client(router: str, **overrides) -> TestClient:
    settings = DashboardSettings(router=router, api_token=TOKEN, config_timeout_s=1.0, **overrides)
    return TestClient(create_app(settings))


@pytest.fixture(scope="module")
def pub(router):
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(router,)))
    yield session
    session.close()


@pytest.fixture
def client(router):
    with make_client(router) as c:
        wait_until(lambda: c.get("/health").status_code == 200, 10, "zenoh session")
        yield c


def publish_until(client: TestClient, publish, predicate, what: str, timeout: float = 10.0):
    """Publish repeatedly until ``predicate()`` holds (the subscriber may join late)."""
    def step():
        publish()
        return predicate()
    return wait_until(step, timeout, what, interval=0.05)


def device_stats(subject: str, segment: str, **values) -> dict:
    base = {k: None for k in wire.STATS_FIELDS}
    base.update(device=f"{subject}/{segment}", segment=segment, online=True, samples=500, points=50,
                icr=0.1, msgs_per_s=5.0, bytes_per_s=180.0, aad_deg=1.5, p99_deg=4.0, max_deg=6.0,
                live_err_deg=9.0, watermark_lag_s=0.4, gaps=0, dropped=0, threshold=0.01)
    base.update(values)
    return base


def pose_frame(seq: int, kind: int = wire.KIND_EXACT, seed: int = 0) -> wire.PoseFrame:
    rng = np.random.default_rng(seed + seq)
    q = rng.normal(size=(10, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    joints = rng.uniform(-1, 1, size=(len(wire.JOINTS), 3))
    return wire.PoseFrame(seq, 1_700_000_000_000_000 + seq * 20_000, kind, 0, q.astype(np.float32),
                          joints.astype(np.float32))


class Device:
    """A device's config queryable, as the contract describes it (the emulator implements the
    same in the end-to-end test)."""

    def __init__(self, session: zenoh.Session, subject: str, segment: str, reject: str | None = None):
        self.config = wire.DeviceConfig(0.01, 25)
        self.reject = reject
        self.queryable = session.declare_queryable(wire.config_key(subject, segment), self.on_query)

    def on_query(self, query: zenoh.Query) -> None:
        if query.payload is not None:
            if self.reject:
                query.reply_err(json.dumps({"error": self.reject}))
                return
            try:
                self.config = wire.decode_config(query.payload.to_bytes(), self.config)
            except wire.WireError as exc:
                query.reply_err(json.dumps({"error": str(exc)}))
                return
        query.reply(query.key_expr, wire.encode_status(wire.DeviceStatus("x/hip", self.config, 7, 10, 1)))


def joint_angles(seq: int, kind: int = wire.KIND_LIVE, basis: str = "segments", knee: float = 10.0) -> wire.JointAngles:
    """A joint-angle message as the aggregator makes it: ``knee_angle_r`` = ``knee``, the left
    elbow missing, or no numbers at all where ``basis`` gives none."""
    a = len(wire.JOINT_ANGLES)
    angles = np.linspace(-30.0, 60.0, a)
    flags = np.zeros(a, np.uint8)
    angles[wire.JOINT_ANGLES.index("knee_angle_r")] = knee
    flags[wire.JOINT_ANGLES.index("elbow_flex_l")] = wire.ANGLE_MISSING
    if not wire.ANGLE_BASES[wire.BASIS[basis]].valid:
        flags |= wire.ANGLE_UNCALIBRATED
    angles[(flags & (wire.ANGLE_MISSING | wire.ANGLE_UNCALIBRATED)) != 0] = np.nan
    return wire.JointAngles(seq, 1_700_000_000_000_000 + seq * 20_000, kind, wire.BASIS[basis], math.nan,
                            angles.astype(np.float32), flags)
