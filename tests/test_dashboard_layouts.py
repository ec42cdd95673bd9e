"""The dashboard with subjects of different body layouts: a ``full`` subject's frames (published
here as an aggregator publishes them) on REST, WebSocket and SSE by the layout's names, its
subject view with the layout's segments, joints and bones, a layout file's frames refused with
the reason where its devices say no layout, and the page drawing every bone of each subject's layout in headless Chromium (writes
tests/artifacts/layouts.png for inspection)."""
from __future__ import annotations

import json
import threading
from dataclasses import replace

import numpy as np
import pytest
from support.dashboard import pose_frame, publish_until
from support.stack import http_json, stack, wait_until  # noqa: F401  (stack is a fixture)

from limbstream import quat, wire
from limbstream.body import FULL, PAPER10, Body, Layout, layout_from_dict, load_layout

T0_US = 1_700_000_000_000_000


def full_frames(n: int, kind: int = wire.KIND_EXACT, first: int = 0) -> wire.PoseFrames:
    """``n`` frames of the ``full`` layout: every segment turning about its own axis, joint
    positions those of a 1.75 m body, the root walking along +Z, the left heel planted."""
    body = Body.from_height(FULL, 1.75)
    seq = np.arange(first, first + n)
    angle = 0.02 * seq[:, None] * (1 + np.arange(len(FULL.segments)))[None, :]
    q = np.stack([np.cos(angle / 2), np.zeros_like(angle), np.sin(angle / 2), np.zeros_like(angle)], axis=-1)
    q = quat.normalize(q)
    root = np.stack([np.zeros(n), np.full(n, 0.93), 0.02 * seq], axis=1)
    return wire.PoseFrames(seq, T0_US + seq * 20_000, kind, np.zeros(n, np.int64), q, body.positions(q), FULL,
                           root, np.full(n, 1))


def layout_of(layout, name: str, segments) -> Layout:
    """A layout file's layout: ``layout``'s ``segments`` (a part of it, by their rows), named ``name``."""
    return layout_from_dict(layout.part(name, segments).to_dict())


def test_a_full_subjects_frames_by_its_layouts_names(client, pub):
    """REST pose, WebSocket and SSE give a full subject's frames with its 15 segments and 20 joints
    by name, the root and contacts; its subject view names the layout with its segments, joints and
    bones (pairs of joints), and its bone lengths from its frames; a paper10 subject keeps its own."""
    frames = full_frames(3)
    payloads = frames.encode()
    publish_until(client, lambda: pub.put(wire.pose_key("fullA"), payloads[0]),
                  lambda: client.get("/api/subjects/fullA/pose").status_code == 200, "fullA frame")
    got = client.get("/api/subjects/fullA/pose").json()
    assert got["layout"] == "full"
    assert list(got["segments"]) == list(FULL.segment_names) and len(got["segments"]) == 15
    assert list(got["joints"]) == list(FULL.joints) and len(got["joints"]) == 20
    assert {"head_top", "l_toe", "r_toe", "l_fingertip", "r_fingertip", "spine"} <= set(got["joints"])
    assert np.allclose(got["joints"]["l_toe"], frames.joints[0, FULL.joint_index["l_toe"]], atol=1e-4)
    assert np.allclose(got["segments"]["r_foot"], frames.q[0, FULL.segment_index["r_foot"]], atol=1e-6)
    assert got["root"] == [0.0, 0.93, 0.0] and got["contacts"] == ["l_heel"]
    one = client.get("/api/subjects/fullA").json()
    assert one["layout"] == "full" and one["segments"] == list(FULL.segment_names) and one["joints"] == list(FULL.joints)
    assert one["bones"] == [[b.origin, b.joint] for b in FULL.bones] and len(one["bones"]) == 19
    assert ["l_ankle", "l_toe"] in one["bones"] and ["spine", "neck_base"] in one["bones"]
    assert ["neck_base", "head_top"] in one["bones"] and ["r_wrist", "r_fingertip"] in one["bones"]
    assert one["missing_segments"] == list(FULL.segment_names)  # no devices of it here
    assert one["bones_m"]["l_foot"] == pytest.approx(Body.from_height(FULL, 1.75).lengths["l_foot"], abs=1e-4)
    assert set(one["bones_m"]) == set(FULL.bone_names)
    listed = next(s for s in client.get("/api/subjects").json() if s["subject"] == "fullA")
    assert listed["layout"] == "full" and listed["pose_refused"] is None

    publish_until(client, lambda: pub.put(wire.pose_key("paperA"), wire.encode_pose(pose_frame(1))),
                  lambda: client.get("/api/subjects/paperA/pose").status_code == 200, "paperA frame")
    paper = client.get("/api/subjects/paperA").json()
    assert paper["layout"] == "paper10" and paper["bones"] == [list(b) for b in (
        (b.origin, b.joint) for b in PAPER10.bones)] and paper["segments"] == list(wire.SEGMENTS)
    assert client.get("/api/subjects/paperA/pose").json()["layout"] == "paper10"

    with client.websocket_connect("/ws/pose/fullA") as ws:
        first = json.loads(ws.receive_text())
        assert first["layout"] == "full" and len(first["joints"]) == 20, first
        pub.put(wire.pose_key("fullA"), payloads[1])
        second = json.loads(ws.receive_text())
    assert second["seq"] == 1 and list(second["segments"]) == list(FULL.segment_names), second
    r = client.get("/sse/pose/fullA", params={"limit": 1})
    events = [json.loads(line[6:]) for line in r.text.splitlines() if line.startswith("data: ")]
    assert [(e["layout"], len(e["segments"]), len(e["joints"])) for e in events] == [("full", 15, 20)], r.text

    layouts = client.get("/api/layouts").json()
    assert set(layouts) == {"paper10", "full"} and layouts["full"]["bones"] == one["bones"]
    assert client.get("/api/skeleton", params={"layout": "full"}).json() == layouts["full"]
    assert client.get("/api/skeleton").json()["joints"] == list(wire.JOINTS)
    assert client.get("/api/skeleton", params={"layout": "suit17"}).status_code == 422


def test_a_layout_files_frames_are_counted_and_the_subject_says_why(client, pub):
    """Frames of a layout file's layout (layout byte 255) of a subject whose devices say no layout
    (none answers here): counted as undecodable (``pose_layout``) and the subject's view says why;
    its first readable frame clears that."""
    from support import ROOT
    suit = load_layout(ROOT / "examples" / "layouts" / "suit17.toml")
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(suit.segments), 1)).astype(np.float32)
    payload = wire.encode_pose(wire.PoseFrame(0, T0_US, wire.KIND_EXACT, 0, q, layout=suit))
    assert payload[16] == wire.OTHER_LAYOUT
    publish_until(client, lambda: pub.put(wire.pose_key("suitB"), payload),
                  lambda: any(s["subject"] == "suitB" for s in client.get("/api/subjects").json()), "suitB refused")
    assert 'limbstream_dashboard_errors_total{reason="pose_layout"}' in client.get("/metrics").text
    view = client.get("/api/subjects/suitB").json()
    assert view["pose"] is None and "layout file" in view["pose_refused"], view
    assert client.get("/api/subjects/suitB/pose").status_code == 404
    publish_until(client, lambda: pub.put(wire.pose_key("suitB"), full_frames(1).encode()[0]),
                  lambda: client.get("/api/subjects/suitB/pose").status_code == 200, "suitB readable frame")
    assert client.get("/api/subjects/suitB").json()["pose_refused"] is None


def test_watch_renders_a_full_frame_by_its_layouts_names():
    """``limbstream watch``'s view of a full frame: its layout named, a rotation per segment of its
    15 (the feet, hands, chest and head among them), its joints by their names (the top of the head
    is ``head_top``), and the missing segments among its own."""
    import dataclasses

    from limbstream.cli.watch import render
    frames = full_frames(1)
    text = render("fullW", frames[0], 50.0)
    head, rows, joints = text.splitlines()[0], text.splitlines()[2:5], text.splitlines()[-1]
    assert head.startswith("fullW  exact #0") and head.endswith("frames/s  full"), head
    cells = [c.split()[0] for row in rows for c in row.split("°") if c.strip()]
    assert cells == list(FULL.segment_names), cells
    top = frames.joints[0, FULL.joint_index["head_top"]]
    assert f"head_top ({top[0]:+.2f},{top[1]:+.2f},{top[2]:+.2f})" in joints and "l_ankle" in joints, joints
    missing = dataclasses.replace(frames[0], flags=wire.FRAME_MISSING)
    devices = {s: True for s in FULL.segment_names if s not in ("l_foot", "chest")}
    assert render("fullW", missing, 50.0, devices).splitlines()[0].endswith("MISSING (no device: chest, l_foot)")


# ----------------------------------------------------------------------------- the page

DRAWN = """([subject, frames]) => {
  const c = document.querySelector(`.skeleton[data-subject="${subject}"] canvas`);
  return !!c && Number(c.dataset.frames) >= frames
    ? {layout: c.dataset.layout, bones: Number(c.dataset.bones), joints: Number(c.dataset.joints),
       caption: c.closest('.skeleton').querySelector('.cap span').textContent} : null;
}"""

INK_BELOW = """([subject, color, fromY]) => {
  const c = document.querySelector(`.skeleton[data-subject="${subject}"] canvas`);
  const px = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  const want = [1, 3, 5].map((k) => parseInt(color.slice(k, k + 2), 16));
  let lit = 0;
  for (let y = Math.floor(fromY * c.height); y < c.height; y++) for (let x = 0; x < c.width; x++) {
    const i = 4 * (y * c.width + x);
    if (px[i + 3] > 128 && want.every((v, k) => Math.abs(px[i + k] - v) < 40)) lit++;
  }
  return lit;
}"""
"""Pixels of a subject's figure in a colour (#rrggbb) below a fraction of its height."""


@pytest.mark.browser
def test_the_page_draws_each_subjects_layout(stack):  # noqa: F811
    """A full subject, a paper10 subject and a subject of a layout file's layout on one page: each
    figure draws its own layout's bones (19 lines for full's 15 segments, the hands and feet
    included; 14 for paper10; the file's, which the page takes from the subject's view, as its
    device announces it) and every joint, and its caption names the layout; the full figure has
    ink of a foot below the ankles."""
    from test_dashboard_browser import ARTIFACTS, CHROMIUM_ARGS, playwright_api, require_chromium

    from limbstream import zconfig
    chromium = require_chromium()
    stack.router()
    url = stack.dashboard()
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    stop = threading.Event()
    legs = layout_of(FULL, "legs7", ("hip", "l_thigh", "l_shank", "l_foot", "r_thigh", "r_shank", "r_foot"))
    status = wire.DeviceStatus("legsP/hip", wire.DeviceConfig(), 1, 0, 0, body=Body.default(legs))
    key = wire.config_key("legsP", "hip")
    device = session.declare_queryable(key, lambda query: query.reply(key, wire.encode_status(status)))
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (len(legs.segments), 1)).astype(np.float32)
    legs_frame = wire.PoseFrame(0, T0_US, wire.KIND_LIVE, 0, identity, Body.default(legs).positions(identity), legs)

    def publish():
        seq = 0
        while not stop.is_set():
            session.put(wire.pose_key("fullP"), full_frames(1, wire.KIND_LIVE, seq).encode()[0])
            session.put(wire.pose_key("paperP"), wire.encode_pose(pose_frame(seq, wire.KIND_LIVE)))
            session.put(wire.pose_key("legsP"), wire.encode_pose(replace(legs_frame, seq=seq, t_us=T0_US + 20_000 * seq)))
            seq += 1
            stop.wait(0.04)

    sender = threading.Thread(target=publish)
    sender.start()
    errors = []
    try:
        wait_until(lambda: {s["subject"] for s in http_json(url + "/api/subjects")[1]} >= {"fullP", "paperP"}, 30,
                   "both subjects", on_fail=stack.logs)
        with playwright_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page()
                page.on("pageerror", lambda exc: errors.append(str(exc)))
                page.goto(url + "/")
                full = page.wait_for_function(DRAWN, arg=["fullP", 5], timeout=30_000).json_value()
                paper = page.wait_for_function(DRAWN, arg=["paperP", 5], timeout=30_000).json_value()
                assert (full["layout"], full["bones"], full["joints"]) == ("full", len(FULL.bones), 20), full
                assert (paper["layout"], paper["bones"], paper["joints"]) == ("paper10", len(wire.BONES), 15), paper
                assert " · full" in full["caption"] and " · paper10" in paper["caption"], (full, paper)
                mine = page.wait_for_function(DRAWN, arg=["legsP", 5], timeout=30_000).json_value()
                assert (mine["layout"], mine["bones"], mine["joints"]) == ("legs7", len(legs.bones), len(legs.joints))
                assert " · legs7" in mine["caption"], mine
                colors = page.evaluate("[COLORS.left, COLORS.right]")
                # the feet: the lowest tenth of the figure holds both sides' foot bones (toes below the ankles)
                assert all(page.evaluate(INK_BELOW, ["fullP", c, 0.82]) > 30 for c in colors)
                ARTIFACTS.mkdir(parents=True, exist_ok=True)
                page.locator("#skeletons").screenshot(path=str(ARTIFACTS / "layouts.png"))
            finally:
                browser.close()
    finally:
        stop.set()
        sender.join()
        device.undeclare()
        session.close()
    assert not errors, errors
