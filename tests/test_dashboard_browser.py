"""The web page in headless Chromium against the real stack: router, emulator, aggregator and
dashboard as subprocesses. Writes tests/artifacts/dashboard.png and trackers.png for inspection."""
from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest
from support.stack import PAPER10, ROOT, http_json, stack, wait_until  # noqa: F401  (stack is a fixture)

pytestmark = pytest.mark.browser

CHROMIUM = os.environ.get("LIMBSTREAM_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1, EXCLUDE localhost",
]
ARTIFACTS = ROOT / "tests" / "artifacts"
SUBJECTS = 2
TOKEN = "browser-test-token"

playwright_api = pytest.importorskip("playwright.sync_api")


def require_chromium() -> str:
    if not (Path(CHROMIUM).exists() or shutil.which(CHROMIUM)):
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"Chromium not found at {CHROMIUM} (set LIMBSTREAM_CHROMIUM)")
        pytest.skip(f"Chromium not found at {CHROMIUM} (set LIMBSTREAM_CHROMIUM)")
    return CHROMIUM


ROWS_READY = """(n) => {
  const rows = [...document.querySelectorAll('#devices-body tr.device')];
  return rows.length === n && rows.every(r => Number(r.dataset.rate) > 0 && r.dataset.icr !== '');
}"""

SKELETONS_DRAWN = """(n) => {
  const canvases = [...document.querySelectorAll('.skeleton canvas')];
  if (canvases.length !== n) return false;
  return canvases.every(c => {
    if (Number(c.dataset.frames) < 5) return false;
    const px = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let lit = 0;
    for (let i = 3; i < px.length; i += 4) if (px[i] > 0) lit++;
    return lit > 2000;
  });
}"""

LIVE_CELLS = r"""([sel, bound]) => {
  const cells = [...document.querySelectorAll(sel + ' td.live')];
  return cells.length > 0 && cells.every(c => {
    const [p99, b] = c.textContent.split(' / ');
    return /^\d+(\.\d)?°$/.test(p99) && b === bound;
  });
}"""

FIGURES_OF_KIND = """([kind, after]) => {
  const canvases = [...document.querySelectorAll('.skeleton canvas')];
  return canvases.length > 0 && canvases.every(c => c.dataset.kind === kind && Number(c.dataset.frames) > (after[c.closest('.skeleton').dataset.subject] ?? 0));
}"""

FRAMES_DRAWN = """() => Object.fromEntries([...document.querySelectorAll('.skeleton')]
  .map(s => [s.dataset.subject, Number(s.querySelector('canvas').dataset.frames)]))"""


def latency(page, which: str) -> tuple[float, float, str]:
    """(p50, p99, text) of a header latency: ``exact`` or ``live``."""
    page.wait_for_function(f"() => Number(document.querySelector('#tot-lat-{which}').dataset.p50) > 0",
                           timeout=20_000)
    el = page.query_selector(f"#tot-lat-{which}")
    return float(el.get_attribute("data-p50")), float(el.get_attribute("data-p99")), el.text_content()


def switch_kind(page, kind: str) -> None:
    """Click the figures' toggle; every figure then draws new frames of that kind."""
    drawn = page.evaluate(FRAMES_DRAWN)
    page.click(f"#kind-toggle label:has(input[value={kind}])")
    page.wait_for_function(FIGURES_OF_KIND, arg=[kind, drawn], timeout=15_000)
    assert page.get_attribute("#skeletons", "data-kind") == kind


@pytest.mark.slow
def test_page_shows_live_devices_skeletons_and_control(stack):  # noqa: F811
    chromium = require_chromium()
    stack.router()
    stack.start("clock", "clock", "--connect", stack.endpoint)
    stack.emulator(SUBJECTS, 1.0, "--clock-offset-ms", "2000", "--clock-drift-ppm", "100")
    stack.aggregator()
    url = stack.dashboard(env={"LIMBSTREAM_API_TOKEN": TOKEN, "LIMBSTREAM_MODE": "production"})
    n_devices = SUBJECTS * 10
    wait_until(lambda: sum(1 for d in http_json(url + "/api/devices")[1] if d["msgs_per_s"]) == n_devices,
               60, f"{n_devices} devices with a data rate", interval=0.2, on_fail=stack.logs)

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    errors = []
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1440, "height": 1000})
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(url + "/")
            page.wait_for_function(ROWS_READY, arg=n_devices, timeout=30_000)
            page.wait_for_function(SKELETONS_DRAWN, arg=SUBJECTS, timeout=30_000)
            rows = page.eval_on_selector_all(
                "#devices-body tr.device",
                "rs => rs.map(r => [r.dataset.device, Number(r.dataset.rate), Number(r.dataset.icr), r.dataset.online])")
            devices = {d["device"] for d in http_json(url + "/api/devices")[1]}
            assert {r[0] for r in rows} == devices and len(devices) == n_devices, (rows, devices)
            for device, rate, icr, online in rows:
                assert rate > 0 and 0 < icr <= 1 and online == "true", (device, rate, icr, online)
            # perfect sensors: nothing to calibrate, no device shown calibrated or refused
            assert page.eval_on_selector_all("#devices-body tr.device", "rs => rs.filter(r => "
                                             "r.dataset.calibrated !== 'false' || r.querySelector('.cal')).length") == 0
            assert page.text_content("#tot-online") == f"{n_devices} / {n_devices}"
            # the aggregator's own load, as it reports it in its stats
            page.wait_for_function("() => document.querySelector('#tot-agg').dataset.load > 0", timeout=10_000)
            load = float(page.get_attribute("#tot-agg", "data-load"))
            assert 0 < load < 1 and " % · " in page.text_content("#tot-agg"), page.text_content("#tot-agg")
            # each device's clock column: synced, its offset estimate; each subject's frame error
            page.wait_for_function("""(n) => [...document.querySelectorAll('#devices-body td.clock[data-synced="true"]')]
                .filter(c => / ms$/.test(c.textContent)).length === n""", arg=n_devices, timeout=20_000)
            page.wait_for_function("(n) => document.querySelectorAll('#devices-body .frame-err').length === n",
                                   arg=SUBJECTS, timeout=20_000)
            # charts got data for the selected device
            page.wait_for_function("() => document.querySelectorAll('#chart-icr .u-over').length === 1", timeout=10_000)

            # live column: each device's live p99 and its live-rule bound (off: the default)
            page.wait_for_function(LIVE_CELLS, arg=["#devices-body", "off"], timeout=20_000)
            assert "bound" in page.get_attribute("#devices th[title*='live']", "title")
            # header: exact-frame and live-frame latency; live frames come far sooner
            exact50, exact99, exact_text = latency(page, "exact")
            live50, live99, live_text = latency(page, "live")
            assert exact_text.endswith(" ms") and live_text.endswith(" ms"), (exact_text, live_text)
            assert 0 < exact50 <= exact99 and 0 < live50 <= live99, (exact_text, live_text)
            assert live50 < exact50, (live_text, exact_text)
            # the figures draw live frames by default; the toggle switches them and is remembered
            assert page.get_attribute("#skeletons", "data-kind") == "live"
            assert page.is_checked("#kind-toggle input[value=live]")
            page.wait_for_function(FIGURES_OF_KIND, arg=["live", {}], timeout=15_000)
            switch_kind(page, "exact")
            assert page.evaluate("() => localStorage.getItem('limbstream-pose-kind')") == "exact"
            page.reload()
            page.wait_for_function(SKELETONS_DRAWN, arg=SUBJECTS, timeout=30_000)
            page.wait_for_function(FIGURES_OF_KIND, arg=["exact", {}], timeout=15_000)
            assert page.is_checked("#kind-toggle input[value=exact]")
            switch_kind(page, "live")
            page.wait_for_function(ROWS_READY, arg=n_devices, timeout=30_000)

            # threshold control: the inputs show what the selected devices run now, not the defaults
            page.select_option("#ctl-target", "subject:s01")
            running = {d["threshold"] for d in http_json(url + "/api/devices")[1] if d["subject"] == "s01"}
            assert page.get_attribute("#ctl-threshold", "placeholder") == f"now {running.pop():g}" and not running
            # a wrong token is refused, the right one is confirmed by every device
            page.fill("#ctl-threshold", "0.02")
            page.fill("#ctl-live_bound_deg", "5")
            page.fill("#ctl-token", "wrong")
            page.click("#ctl-apply")
            page.wait_for_function("() => /403/.test(document.querySelector('#ctl-result').textContent)",
                                   timeout=10_000)
            page.fill("#ctl-token", TOKEN)
            page.click("#ctl-apply")
            page.wait_for_function("() => /confirmed|\\d+\\/10/.test(document.querySelector('#ctl-result').textContent)",
                                   timeout=20_000)
            outcome = page.text_content("#ctl-result")
            assert "confirmed by 10/10" in outcome, (outcome, stack.logs())
            assert "threshold 0.02" in outcome and "live bound deg 5" in outcome, outcome
            wait_until(lambda: all(d["threshold"] == 0.02 for d in http_json(url + "/api/devices")[1]
                                   if d["subject"] == "s01"), 20, "aggregator reporting the new threshold",
                       interval=0.2, on_fail=stack.logs)
            page.wait_for_function("""() => [...document.querySelectorAll('#devices-body tr[data-device^="s01/"]')]
                .every(r => r.lastElementChild.textContent === '0.0200')""", timeout=10_000)
            # the live column shows the new bound of s01's devices; s02's stay off
            page.wait_for_function(LIVE_CELLS, arg=['#devices-body tr[data-device^="s01/"]', "5°"], timeout=20_000)
            page.wait_for_function(LIVE_CELLS, arg=['#devices-body tr[data-device^="s02/"]', "off"], timeout=5_000)
            # ... and the control form shows the new values for s01, s02's own for s02
            page.wait_for_function("() => document.querySelector('#ctl-live_bound_deg').placeholder === 'now 5'",
                                   timeout=10_000)
            assert page.get_attribute("#ctl-threshold", "placeholder") == "now 0.02"
            page.select_option("#ctl-target", "subject:s02")
            assert page.get_attribute("#ctl-live_bound_deg", "placeholder") == "now 0"
            page.screenshot(path=str(ARTIFACTS / "dashboard.png"), full_page=True)
        finally:
            browser.close()
    assert not errors, errors
    assert (ARTIFACTS / "dashboard.png").stat().st_size > 20_000


HEADING_CELLS = """() => {
  const cells = [...document.querySelectorAll('#devices-body tr.device td.heading')];
  return cells.length === 10 && cells.every(c => c.dataset.offset !== undefined && Number.isFinite(Number(c.dataset.offset))
    && Number(c.dataset.confidence) >= 0 && Number(c.dataset.confidence) <= 1 && /°/.test(c.textContent))
    && Number.isFinite(Number(document.querySelector('#devices-body .subject-row .joint-err')?.dataset.value));
}"""


def test_page_shows_each_devices_calibration_and_heading_correction(stack):  # noqa: F811
    """Sensors strapped at up to 90 deg, their headings drifting: the aggregator calibrates every
    device from its stream's calibration script and the page marks each row calibrated, shows
    each device's heading correction and confidence and the subject's joint error; the Calibrate
    button counts down and asks for a calibration, which a moving subject gets refused, with the
    reason shown."""
    chromium = require_chromium()
    stack.router()
    stack.emulator(1, 1.0, "--mounting-deg", "90", "--heading-deg", "180", "--yaw-drift-dps", "0.1")
    stack.aggregator("--calibrate-on-start", "--heading-correction", "joints")
    url = stack.dashboard(env={"LIMBSTREAM_API_TOKEN": TOKEN})
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            page.goto(url + "/")
            page.wait_for_function("""() => [...document.querySelectorAll('#devices-body tr.device')]
                .filter(r => r.dataset.calibrated === 'true' && r.querySelector('.cal.ok')).length === 10""",
                                   timeout=60_000)
            assert "calibrated" in page.get_attribute("#devices-body tr.device .cal.ok", "title")
            page.wait_for_function(HEADING_CELLS, timeout=30_000)
            assert "changing" in page.get_attribute("#devices-body tr.device td.heading", "title")
            assert "whichever way" in page.get_attribute("#devices-body .joint-err", "title")
            page.fill("#ctl-token", TOKEN)
            page.select_option("#ctl-target", "subject:s01")
            page.select_option("#cal-pose", "rest")
            page.click("#cal-go")
            page.wait_for_function("() => /get into the rest pose/.test(document.querySelector('#cal-result').textContent)",
                                   timeout=5_000)
            page.wait_for_function("() => /409/.test(document.querySelector('#cal-result').textContent)",
                                   timeout=30_000)
            assert "not still" in page.text_content("#cal-result"), page.text_content("#cal-result")
        finally:
            browser.close()


def test_trackers_panel_assigns_a_sensor(stack):  # noqa: F811
    """A SlimeVR gateway with two simulated trackers: the Trackers panel lists both sensors, one
    without a segment and why; choosing a segment in its select assigns it (the device comes
    online), choosing a segment fed by the other sensor is refused with the gateway's sentence,
    choosing none unassigns it."""
    import threading

    from support.slimevr import free_udp_port, stream

    from limbstream.device_emulator.slimevr_tracker import Tracker
    chromium = require_chromium()
    stack.router()
    port = free_udp_port()
    stack.start("gateway", "gateway", "slimevr", "--connect", stack.endpoint, "--udp", f"127.0.0.1:{port}",
                "--no-sync", "--name", "lab1", "-v")
    url = stack.dashboard(env={"LIMBSTREAM_API_TOKEN": TOKEN})
    a = Tracker(("127.0.0.1", port), bytes([2, 0, 0, 0, 3, 1]), {0: 0})   # no body position
    b = Tracker(("127.0.0.1", port), bytes([2, 0, 0, 0, 3, 2]), {0: 7})   # left thigh
    stop = threading.Event()
    sender = threading.Thread(target=stream, args=([a, b], {a.mac_text: [0], b.mac_text: [0]}, 60.0),
                              kwargs={"stop": stop})
    errors = []
    try:
        a.connect(30)
        b.connect(30)
        sender.start()
        row = f'#trackers-body tr.sensor[data-tracker="{a.mac_text}"]'
        with playwright_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page()
                page.on("pageerror", lambda exc: errors.append(str(exc)))
                page.goto(url + "/")
                page.wait_for_function("() => document.querySelectorAll('#trackers-body tr.sensor').length === 2",
                                       timeout=20_000)
                assert page.get_attribute(row, "data-device") == ""
                assert page.text_content(f"{row} td.why") == "no body position and no --assign"
                assert page.get_attribute(f'#trackers-body tr.sensor[data-tracker="{b.mac_text}"]',
                                          "data-device") == "s01/l_thigh"
                page.fill("#ctl-token", TOKEN)
                page.select_option(f"{row} select.assign", "s01/hip")
                page.wait_for_function(f"""() => document.querySelector('{row}')?.dataset.device === 's01/hip'""",
                                       timeout=10_000)
                assert "-> s01/hip" in page.text_content("#trk-result")
                ARTIFACTS.mkdir(parents=True, exist_ok=True)
                page.locator("#trackers").screenshot(path=str(ARTIFACTS / "trackers.png"))
                wait_until(lambda: any(d["device"] == "s01/hip" and d["alive"] for d in http_json(url + "/api/devices")[1]),
                           20, "the assigned sensor's device online", on_fail=stack.logs)
                page.select_option(f"{row} select.assign", "s01/l_thigh")
                page.wait_for_function("() => /409/.test(document.querySelector('#trk-result').textContent)",
                                       timeout=10_000)
                assert f"s01/l_thigh is fed by {b.mac_text}/0" in page.text_content("#trk-result")
                page.wait_for_function(f"""() => document.querySelector('{row} select.assign')?.value === 's01/hip'""",
                                       timeout=10_000)
                page.select_option(f"{row} select.assign", "")
                page.wait_for_function(f"""() => document.querySelector('{row} td.why')?.textContent
                    === 'unassigned at run time'""", timeout=10_000)
                wait_until(lambda: not any(d["device"] == "s01/hip" and d["alive"]
                                           for d in http_json(url + "/api/devices")[1]),
                           20, "the unassigned sensor's device offline", on_fail=stack.logs)
            finally:
                browser.close()
    finally:
        stop.set()
        if sender.is_alive():
            sender.join()
        a.close()
        b.close()
    assert not errors, errors


JOINT_PLOT = """([subject, valid, series, points]) => {
  const fig = document.querySelector(`.joint-plot[data-subject="${subject}"]`);
  return !!fig && fig.dataset.valid === valid && (series === null || fig.dataset.series === series)
    && Number(fig.dataset.points) >= points;
}"""

PLOT_INK = """([subject, color]) => {
  const c = document.querySelector(`.joint-plot[data-subject="${subject}"] canvas`);
  const px = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  const want = [1, 3, 5].map((k) => parseInt(color.slice(k, k + 2), 16));
  let lit = 0;
  for (let i = 0; i < px.length; i += 4) {
    if (px[i + 3] > 128 && want.every((v, k) => Math.abs(px[i + k] - v) < 40)) lit++;
  }
  return lit;
}"""
"""Pixels of a subject's plot drawn in a colour (#rrggbb): its curves' ink (axes and grid have others)."""


def test_page_plots_each_subjects_joint_angles(stack):  # noqa: F811
    """Two subjects: s01's devices send their segments' own orientations, and the page plots its
    knees and hips over the last seconds; s02's sensors are strapped on and not calibrated, and its
    plot says why instead of numbers. Choosing another angle adds its series, and is remembered."""
    chromium = require_chromium()
    stack.router()
    stack.emulator(1)
    stack.start("emulate-s02", "emulate", "--connect", stack.endpoint, "--subjects", "1", "--first-subject", "2",
                *PAPER10, "--mounting-deg", "90", "--heading-deg", "180")
    stack.aggregator()
    url = stack.dashboard()
    wait_until(lambda: all(http_json(f"{url}/api/subjects/{s}/joints")[0] == 200 for s in ("s01", "s02")), 60,
               "both subjects' joint angles", interval=0.2, on_fail=stack.logs)
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    errors = []
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1440, "height": 1000})
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(url + "/")
            page.wait_for_function(JOINT_PLOT, arg=["s01", "true", "4", 100], timeout=30_000)
            picked = page.eval_on_selector_all("#joints-pick input:checked", "xs => xs.map(x => x.value)")
            assert picked == ["hip_flexion_r", "knee_angle_r", "hip_flexion_l", "knee_angle_l"], picked
            colors = page.evaluate("[COLORS.right, COLORS.left]")
            for color in colors:  # both sides' curves are drawn (they lengthen as the seconds come)
                wait_until(lambda c=color: page.evaluate(PLOT_INK, ["s01", c]) > 300, 30, f"s01's {color} curves drawn",
                           interval=0.2)
            caption = page.text_content('.joint-plot[data-subject="s01"] .why')
            assert "calibration segments" in caption and re.search(r"knee_angle_r -?\d+\.\d°", caption), caption
            page.wait_for_function(JOINT_PLOT, arg=["s02", "false", None, 1], timeout=30_000)
            assert page.get_attribute('.joint-plot[data-subject="s02"]', "data-calibration") == "uncalibrated"
            assert "not calibrated" in page.text_content('.joint-plot[data-subject="s02"] .why')
            assert [page.evaluate(PLOT_INK, ["s02", color]) for color in colors] == [0, 0]  # no curves
            page.check("#joints-pick input[value=elbow_flex_r]")
            page.wait_for_function(JOINT_PLOT, arg=["s01", "true", "5", 100], timeout=10_000)
            page.locator("#joints").screenshot(path=str(ARTIFACTS / "joints.png"))
            page.reload()
            page.wait_for_function(JOINT_PLOT, arg=["s01", "true", "5", 100], timeout=30_000)
            assert page.is_checked("#joints-pick input[value=elbow_flex_r]")
        finally:
            browser.close()
    assert not errors, errors
    assert (ARTIFACTS / "joints.png").stat().st_size > 10_000


LIVE_CELL = """(d) => { const t = document.createElement('tr'); t.innerHTML = liveCell(d); const c = t.firstChild;
  return [c.textContent, c.classList.contains('bad'), c.title]; }"""


def test_the_live_column_colours_only_the_bound_figure(stack):  # noqa: F811
    """The live column shows and colours the live error against the device's own orientation
    (what the bound holds); the error against the true body, which holds the sensor's fusion and
    calibration errors too, may exceed the bound without colouring it, and is in the tooltip."""
    chromium = require_chromium()
    stack.router()
    url = stack.dashboard()
    base = {"live_bound_deg": 5.0, "live_p99_deg": 5.6, "live_err_deg": 1.2, "live_max_deg": 6.95,
            "live_own_p99_deg": 4.8, "live_latency_p50_ms": 10.0, "live_latency_p99_ms": 20.0}
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            page.goto(url + "/")
            within = page.evaluate(LIVE_CELL, base | {"live_own_max_deg": 4.99})
            beyond = page.evaluate(LIVE_CELL, base | {"live_own_max_deg": 5.4})
            old_tap = page.evaluate(LIVE_CELL, base | {"live_own_max_deg": None})
        finally:
            browser.close()
    assert within[:2] == ["5.0° / 5°", False], within
    assert "6.95" in within[2] and "true body" in within[2] and "own orientation" in within[2], within
    assert beyond[:2] == ["5.4° / 5°", True], beyond
    assert old_tap[:2] == ["5.6° / 5°", False], old_tap  # no own orientations: the true-body p99, uncoloured
