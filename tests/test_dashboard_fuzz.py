"""Property-based fuzz of the dashboard API from its OpenAPI schema (schemathesis): no request,
authenticated or not, gets a 5xx, and every response conforms to the schema."""
from __future__ import annotations

import socket
import threading
import time

import pytest
import uvicorn
from hypothesis import HealthCheck, settings
from support.profiles import scaled
from support.stack import free_port, http_json, wait_until
from support.dashboard import Device, device_stats, joint_angles, pose_frame

from limbstream import wire, zconfig
from limbstream.device.clocks import ClockSettings
from limbstream.services.gateway.slimevr import GatewaySettings, SlimeVRGateway
from limbstream.services.dashboard.app import create_app
from limbstream.services.dashboard.settings import DashboardSettings

schemathesis = pytest.importorskip("schemathesis")

pytestmark = pytest.mark.e2e  # a real Zenoh router, uvicorn and a gateway serve the fuzzed API

TOKEN = "fuzz-token"


@pytest.fixture(scope="module")
def served():
    """A router, a publisher with one answering device, one subject's frames, joint angles and its calibrate
    queryable (as the contract describes the aggregator's: this one refuses, the subject is not
    complete), a SlimeVR gateway named ``slimevr`` (no tracker: it lists no sensor and refuses
    every assignment), and the dashboard served by uvicorn on a free port (in a thread)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zconfig.open_session(zconfig.ZenohSettings(mode="router", connect=(), listen=(endpoint,)))
    pub = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
    device = Device(pub, "s01", "hip")
    refusal = wire.encode_calibrate_answer(wire.CalibrateAnswer(False, "s01: device(s) missing: l_shank"))
    calibrate = pub.declare_queryable(wire.calibrate_key("s01"), lambda q: q.reply(q.key_expr, refusal))
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", 0))
    gateway = SlimeVRGateway(pub, udp, GatewaySettings("s01", clock=ClockSettings(sync=False), max_devices=4))
    stop = threading.Event()
    gateway_thread = threading.Thread(target=gateway.run, args=(stop,), daemon=True)
    gateway_thread.start()
    port = free_port()
    app = create_app(DashboardSettings(router=endpoint, api_token=TOKEN, config_timeout_s=1.0))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{port}"
    try:
        wait_until(lambda: http_json(url + "/health", timeout=1)[0] == 200, 20, "dashboard health")

        def feed():
            pub.put(wire.stats_key("s01"), wire.encode_stats("s01", time.time(), [device_stats("s01", "hip")]))
            pub.put(wire.pose_key("s01"), wire.encode_pose(pose_frame(1)))
            pub.put(wire.angles_key("s01"), wire.encode_angles(joint_angles(1)))
            return all(http_json(url + path)[0] == 200 for path in ("/api/subjects/s01/pose", "/api/devices/s01/hip",
                                                                    "/api/subjects/s01/joints"))
        wait_until(feed, 20, "s01 stats, pose and joint angles")
        wait_until(lambda: http_json(url + "/api/gateways")[1] == [{"gateway": "slimevr", "subject": "s01", "sensors": [],
                                                                  "segments": list(wire.SEGMENTS)}],
                   20, "the gateway listed")
        yield url
    finally:
        server.should_exit = True
        thread.join(10)
        stop.set()
        gateway_thread.join(10)
        gateway.undeclare()
        udp.close()
        device.queryable.undeclare()
        calibrate.undeclare()
        pub.close()
        router.close()


@pytest.fixture(scope="module")
def api_schema(served):
    return schemathesis.openapi.from_url(served + "/openapi.json")


# The SSE stream is endless by design (tested in test_dashboard_api).
schema = schemathesis.pytest.from_fixture("api_schema").exclude(path_regex="^/sse/")


@schema.parametrize()
@settings(max_examples=scaled(40), deadline=None, suppress_health_check=list(HealthCheck))
def test_no_server_errors(case, served):
    for headers in ({"Authorization": f"Bearer {TOKEN}"}, None):
        response = case.call(base_url=served, headers=headers, timeout=10)
        assert response.status_code < 500, (case.method, case.formatted_path, response.status_code, response.text[:300])
        case.validate_response(response)
        if headers and case.formatted_path == "/api/devices/s01/hip/config" and response.status_code == 200:
            confirmed.add(response.json()["threshold"])


confirmed: set = set()


def test_fuzz_reached_the_device():
    """The explicit examples (``s01/hip``) sent configs through Zenoh to the answering device."""
    assert confirmed, "no config was confirmed by the device during the fuzz run"
