"""The page says when a subject's heading correction stopped (headless Chromium, a real router and
dashboard): the aggregator's stats name the joints whose constraints the subject's motion
contradicts (``heading_contradicted``, limbstream.heading.contradiction), and the subject's row
says so in one line; a subject beside it, still corrected, says nothing of it."""
from __future__ import annotations

import threading
import time

import pytest
from support.dashboard import device_stats
from support.stack import http_json, stack, wait_until  # noqa: F401  (stack is a fixture)

from limbstream import wire

CONTRADICTED = {"hip_l": 0.83, "hip_r": 0.9}
"""The joints the aggregator found contradicted, each with its share of the last minute."""

ROW = """(subject) => document.querySelector(`#devices-body tr.subject-row[data-subject="${subject}"]`)?.textContent"""


@pytest.mark.browser
def test_the_subject_row_says_its_heading_correction_stopped(stack):  # noqa: F811
    from test_dashboard_browser import CHROMIUM_ARGS, playwright_api, require_chromium

    from limbstream import zconfig
    chromium = require_chromium()
    stack.router()
    url = stack.dashboard()
    session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
    stop = threading.Event()

    def publish():  # the aggregator's stats of both subjects, as it sends them every second
        while not stop.is_set():
            for subject, contradicted in (("wrong", CONTRADICTED), ("good", None)):
                devices = [device_stats(subject, segment) for segment in ("hip", "l_thigh")]
                session.put(wire.stats_key(subject), wire.encode_stats(subject, time.time(), devices,
                                                                       {"heading_contradicted": contradicted}))
            stop.wait(0.5)

    sender = threading.Thread(target=publish)
    sender.start()
    errors: list[str] = []
    try:
        wait_until(lambda: {"wrong", "good"} <= {s["subject"] for s in http_json(url + "/api/subjects")[1]}, 30,
                   "both subjects", on_fail=stack.logs)
        with playwright_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page()
                page.on("pageerror", lambda exc: errors.append(str(exc)))
                page.goto(url + "/")
                wrong = wait_until(lambda: (t := page.evaluate(ROW, "wrong")) and "stopped" in t and t, 30,
                                   "the stopped subject's row")
                assert "heading correction stopped: hip_l, hip_r contradict their rest pose" in wrong, wrong
                tip = page.get_attribute('tr.subject-row[data-subject="wrong"] .heading-stopped', "title")
                assert "hip_l 83%" in tip and "hip_r 90%" in tip, tip
                good = wait_until(lambda: page.evaluate(ROW, "good"), 30, "the corrected subject's row")
                assert "online" in good and "heading correction" not in good, good
            finally:
                browser.close()
    finally:
        stop.set()
        sender.join()
        session.close()
    assert not errors, errors
