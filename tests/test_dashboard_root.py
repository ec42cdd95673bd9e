"""The page shows the body moving through the room (headless Chromium): each figure stands at its
frame's root over a floor grid, with the root's last 5 s as a trail and the planted foot points
marked from the frame's contacts; ``follow`` keeps the view on the subject, or leaves it where it
was while the subject walks on (writes tests/artifacts/root.png for inspection)."""
from __future__ import annotations

import threading

import numpy as np
import pytest
from support.stack import http_json, stack, wait_until  # noqa: F401  (stack is a fixture)

from limbstream import quat, wire
from limbstream.body import FULL, Body

T0_US = 1_700_000_000_000_000
STEP_US = 200_000          # frame time per frame: 25 frames span the trail's 5 s
LEFT_HEEL, RIGHT_FOOT = 0b0001, 0b1100   # wire.CONTACTS bits: l_heel; r_heel and r_toe


def walking_frame(seq: int) -> bytes:
    """A full frame at rest pose, its root walking 0.03 m a frame along +X and +Z at pelvis height,
    the left heel planted for 10 frames, then the right foot for 10."""
    body = Body.from_height(FULL, 1.75)
    q = quat.normalize(np.tile([1.0, 0.0, 0.0, 0.0], (1, len(FULL.segments), 1)))
    root = np.array([[0.03 * seq, 0.93, 0.03 * seq]])
    contacts = np.array([LEFT_HEEL if seq // 10 % 2 == 0 else RIGHT_FOOT])
    return wire.PoseFrames(np.array([seq]), np.array([T0_US + seq * STEP_US]), wire.KIND_LIVE, np.zeros(1, np.int64),
                           q, body.positions(q), FULL, root, contacts).encode()[0]


SHOWN = """(subject) => {
  const c = document.querySelector(`.skeleton[data-subject="${subject}"] canvas`);
  if (!c || !c.dataset.root) return null;
  const d = c.dataset;
  return {root: d.root.split(",").map(Number), view: d.view.split(",").map(Number), trail: Number(d.trail),
          contacts: d.contacts, planted: d.planted, follow: d.follow, frames: Number(d.frames)};
}"""


@pytest.mark.browser
def test_the_page_walks_the_figure_over_the_floor(stack):  # noqa: F811
    """A subject whose root moves and whose contacts change: the canvas shows the frame's root, a
    trail of at most the last 5 s of root positions, the planted joints of each contact set (left
    heel: the left ankle; right heel and toe: the right ankle and toe); following (the default)
    the view centres on the root; unfollowed the view stays put while the root moves on; followed
    again it catches up."""
    from test_dashboard_browser import ARTIFACTS, CHROMIUM_ARGS, playwright_api, require_chromium

    from limbstream import zconfig
    chromium = require_chromium()
    stack.router()
    url = stack.dashboard()
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    stop = threading.Event()

    def publish():
        seq = 0
        while not stop.is_set():
            session.put(wire.pose_key("walker"), walking_frame(seq))
            seq += 1
            stop.wait(0.04)

    sender = threading.Thread(target=publish)
    sender.start()
    errors: list[str] = []
    try:
        wait_until(lambda: "walker" in {s["subject"] for s in http_json(url + "/api/subjects")[1]}, 30,
                   "the walker", on_fail=stack.logs)
        with playwright_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page()
                page.on("pageerror", lambda exc: errors.append(str(exc)))
                page.goto(url + "/")
                shown = lambda: page.evaluate(SHOWN, "walker")  # noqa: E731

                def where(pred, what):
                    return wait_until(lambda: (s := shown()) and pred(s) and s, 30, what)

                first = where(lambda s: s["frames"] >= 3, "the figure drawn")
                assert first["follow"] == "true" and page.is_checked("#follow")
                assert first["root"][1] == pytest.approx(0.93) and first["root"][0] == pytest.approx(first["root"][2])
                left = where(lambda s: s["contacts"] == "l_heel", "left heel planted")
                assert left["planted"] == "l_ankle", left
                right = where(lambda s: s["contacts"] == "r_heel,r_toe", "right foot planted")
                assert right["planted"] == "r_ankle,r_toe", right
                walked = where(lambda s: s["root"][0] > 1.0, "a metre walked")
                assert walked["view"] == pytest.approx([walked["root"][0], walked["root"][2]], abs=1e-3), walked
                assert 2 <= walked["trail"] <= 5e6 / STEP_US + 1, walked   # the last 5 s of frame time only

                page.uncheck("#follow")
                stayed = where(lambda s: s["follow"] == "false", "follow off")
                on = where(lambda s: s["root"][0] > stayed["root"][0] + 0.3, "walked on, unfollowed")
                assert on["view"] == stayed["view"], (stayed, on)
                assert on["view"][0] < on["root"][0] - 0.3, on
                ARTIFACTS.mkdir(parents=True, exist_ok=True)
                page.locator(".skeleton[data-subject=walker]").screenshot(path=str(ARTIFACTS / "root.png"))

                page.check("#follow")
                back = where(lambda s: s["follow"] == "true" and s["frames"] > on["frames"] + 2, "follow on")
                assert back["view"] == pytest.approx([back["root"][0], back["root"][2]], abs=1e-3), back
            finally:
                browser.close()
    finally:
        stop.set()
        sender.join()
        session.close()
    assert not errors, errors
