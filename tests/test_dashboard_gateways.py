"""The dashboard's gateway endpoints against the real parts: a router, a SlimeVR gateway (a thread
with its own client session) serving simulated trackers over UDP, the dashboard app with its
lifespan (its own client session), and a subscriber to the segment points."""
from __future__ import annotations

import socket
import threading

import zenoh
from support.stack import wait_until
from support.dashboard import AUTH, make_client
from support.slimevr import stream

from limbstream import wire, zconfig
from limbstream.device.clocks import ClockSettings
from limbstream.services.gateway.slimevr import GatewaySettings, SlimeVRGateway
from limbstream.device_emulator.slimevr_tracker import Tracker


def test_sensors_are_listed_and_assigned_through_rest(router):  # noqa: F811
    gateway_session = zconfig.open_session(zconfig.ZenohSettings(connect=(router,)))
    watcher = zconfig.open_session(zconfig.ZenohSettings(connect=(router,)))
    points = watcher.declare_subscriber(wire.device_selector("seg"), zenoh.handlers.FifoChannel(100000))
    received: dict[str, list] = {}

    def poll() -> dict[str, list]:
        while (s := points.try_recv()) is not None:
            subject, segment, _ = wire.parse_device_key(str(s.key_expr))
            received.setdefault(f"{subject}/{segment}", []).append(wire.decode_point(s.payload.to_bytes()))
        return received

    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", 0))
    gateway = SlimeVRGateway(gateway_session, udp, GatewaySettings("s01", name="lab1", clock=ClockSettings(sync=False)))
    stop = threading.Event()
    thread = threading.Thread(target=gateway.run, args=(stop,), daemon=True)
    thread.start()
    a = Tracker(udp.getsockname(), bytes([2, 0, 0, 0, 2, 1]), {0: 0})   # no body position
    b = Tracker(udp.getsockname(), bytes([2, 0, 0, 0, 2, 2]), {0: 7})   # left thigh
    sending = threading.Event()
    sender = threading.Thread(target=stream, args=([a, b], {a.mac_text: [0], b.mac_text: [0]}, 30.0),
                              kwargs={"stop": sending})
    try:
        a.connect()
        b.connect()
        sender.start()
        with make_client(router) as client:
            wait_until(lambda: client.get("/health").status_code == 200, 10, "the dashboard's zenoh session")

            def listing():
                r = client.get("/api/gateways")
                assert r.status_code == 200, r.text
                return r.json()
            gateways = wait_until(lambda: (g := listing()) and len(g[0]["sensors"]) == 2 and g, 10,
                                  "the gateway listing both sensors")
            assert [g["gateway"] for g in gateways] == ["lab1"] and gateways[0]["subject"] == "s01"
            sensors = {f"{s['tracker']}/{s['sensor']}": s for s in gateways[0]["sensors"]}
            assert sensors[f"{a.mac_text}/0"]["device"] is None
            assert sensors[f"{a.mac_text}/0"]["why"] == "no body position and no --assign"
            assert sensors[f"{b.mac_text}/0"]["device"] == "s01/l_thigh" and sensors[f"{b.mac_text}/0"]["online"]

            body = {"tracker": a.mac_text, "sensor": 0, "subject": None, "segment": "hip"}
            assert client.post("/api/gateways/lab1/assign", json=body).status_code == 401
            r = client.post("/api/gateways/lab1/assign", json=body, headers=AUTH)
            assert r.status_code == 200, r.text
            assert {s["device"] for s in r.json()["sensors"]} == {"s01/hip", "s01/l_thigh"}
            wait_until(lambda: len(poll().get("s01/hip", [])) >= 2, 10, "points of the assigned sensor")

            taken = {**body, "segment": "l_thigh"}
            r = client.post("/api/gateways/lab1/assign", json=taken, headers=AUTH)
            assert r.status_code == 409 and r.json()["detail"] == \
                f"s01/l_thigh is fed by {b.mac_text}/0: unassign it first", r.text
            r = client.post("/api/gateways/lab1/assign", json={**body, "tracker": "02:00:00:00:02:09"}, headers=AUTH)
            assert r.status_code == 409 and "no sensor 02:00:00:00:02:09/0" in r.json()["detail"], r.text
            assert client.post("/api/gateways/lab1/assign", json={**body, "segment": "tail"},
                               headers=AUTH).status_code == 422
            r = client.post("/api/gateways/nowhere/assign", json=body, headers=AUTH)
            assert r.status_code == 404 and "no gateway named nowhere" in r.json()["detail"], r.text

            r = client.post("/api/gateways/lab1/assign", json={**body, "segment": "r_thigh", "subject": "s02"},
                            headers=AUTH)
            assert r.status_code == 200, r.text
            wait_until(lambda: any(p.flags & wire.FLAG_FINAL for p in poll()["s01/hip"]), 10,
                       "the old device's FINAL point")
            wait_until(lambda: len(poll().get("s02/r_thigh", [])) >= 2, 10, "points of the new device")
            assert poll()["s02/r_thigh"][0].seq == 0
            sensors = {f"{s['tracker']}/{s['sensor']}": s["device"] for s in listing()[0]["sensors"]}
            assert sensors == {f"{a.mac_text}/0": "s02/r_thigh", f"{b.mac_text}/0": "s01/l_thigh"}
    finally:
        sending.set()
        if sender.is_alive():
            sender.join()
        stop.set()
        thread.join(10)
        gateway.undeclare()
        a.close()
        b.close()
        udp.close()
        points.undeclare()
        watcher.close()
        gateway_session.close()
