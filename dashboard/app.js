/* limbstream dashboard page: polls the REST API for device stats and history, draws each
 * subject's skeleton from its WebSocket pose stream (live or exact frames, the page's toggle:
 * /ws/pose/<subject>?kind=live|exact), with the bones of the layout each frame names
 * (GET /api/layouts, fetched once). No build step; uPlot is vendored. */
"use strict";

const MAX_FIGURES = 12;          // skeleton cards (one WebSocket each)
const DEVICES_EVERY_MS = 1000;
const SUBJECTS_EVERY_MS = 2000;
const HISTORY_EVERY_MS = 2000;
const COLORS = { left: "#5aa9ff", right: "#ff8a5b", mid: "#dce3ea", accent: "#3fc1c9",
                 warn: "#f5c451", muted: "#8593a3", grid: "#26303b" };

const KIND_KEY = "limbstream-pose-kind";  // localStorage: the figures' frame kind
const FOLLOW_KEY = "limbstream-follow";   // localStorage: whether the figures' views follow them

const $ = (id) => document.getElementById(id);
const state = {
  devices: [],
  selected: null,
  layouts: null,                // layout name -> {segments, joints, bones} (GET /api/layouts)
  figures: new Map(),           // subject -> Figure
  subjects: new Map(),          // subject -> its latest /api/subjects entry (frame error)
  charts: null,
  kind: localStorage.getItem(KIND_KEY) === "exact" ? "exact" : "live",   // frames the figures draw
  follow: localStorage.getItem(FOLLOW_KEY) !== "off",   // views centred on their subject (else fixed)
};

// ------------------------------------------------------------------ helpers

function fmt(v, digits = 2) {
  if (v === null || v === undefined || Number.isNaN(v)) return "–";
  return Number(v).toFixed(digits);
}

function fmtBig(v) {
  if (v === null || v === undefined) return "–";
  if (Math.abs(v) >= 1e6) return (v / 1e6).toFixed(2) + " M";
  if (Math.abs(v) >= 1e4) return (v / 1e3).toFixed(1) + " k";
  return Number(v).toFixed(v < 100 ? 1 : 0);
}

function fmtDeg(v) {  // 5 -> "5°", 2.5 -> "2.5°" (a setting: no trailing zeros)
  return `${Number(v.toFixed(1))}°`;
}

function median(xs) {
  const s = [...xs].sort((a, b) => a - b);
  const m = s.length >> 1;
  return s.length % 2 ? s[m] : (s[m - 1] + s[m]) / 2;
}

function known(xs) {
  return xs.filter((v) => v !== null && v !== undefined && Number.isFinite(v));
}

// p50 and p99 in the header: median of the p50s, largest p99 (ms)
function showLatency(el, p50s, p99s) {
  const a = known(p50s), b = known(p99s);
  if (!a.length || !b.length) { el.textContent = "–"; el.dataset.p50 = ""; el.dataset.p99 = ""; return; }
  const p50 = median(a), p99 = Math.max(...b);
  el.textContent = `${fmt(p50, 0)} / ${fmt(p99, 0)} ms`;
  el.dataset.p50 = p50;
  el.dataset.p99 = p99;
}

function esc(s) {
  return String(s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
}

async function api(path, options = {}) {
  const res = await fetch(path, options);
  let body = null;
  try { body = await res.json(); } catch (_) { /* empty or non-JSON body */ }
  if (!res.ok) {
    let detail = body && body.detail;
    if (Array.isArray(detail)) detail = detail.map((d) => `${(d.loc || []).slice(1).join(".")}: ${d.msg}`).join("; ");
    const err = new Error(`${res.status} ${detail || res.statusText}`);
    err.status = res.status;
    throw err;
  }
  return body;
}

function setStatus(kind, text) {
  const el = $("status");
  el.className = `pill pill-${kind}`;
  el.textContent = text;
}

// ------------------------------------------------------------------ devices table

async function refreshDevices() {
  try {
    state.devices = await api("/api/devices");
  } catch (e) {
    setStatus("bad", "service unreachable");
    return;
  }
  const live = state.devices.filter((d) => !d.stale);
  if (!state.devices.length) setStatus("wait", "no devices yet");
  else if (!live.length) setStatus("wait", "stats stale");
  else setStatus("ok", "live");
  renderTotals();
  renderTable();
  syncSelects();
}

function renderTotals() {
  const ds = state.devices;
  const subjects = new Set(ds.map((d) => d.subject));
  const online = ds.filter((d) => d.online).length;
  const sum = (k) => ds.reduce((a, d) => a + (d[k] || 0), 0);
  const mean = (k) => {
    const xs = ds.map((d) => d[k]).filter((v) => v !== null && v !== undefined);
    return xs.length ? xs.reduce((a, b) => a + b, 0) / xs.length : null;
  };
  $("tot-subjects").textContent = subjects.size;
  $("tot-online").textContent = `${online} / ${ds.length}`;
  $("tot-rate").textContent = fmtBig(sum("msgs_per_s"));
  $("tot-bytes").textContent = fmtBig(sum("bytes_per_s"));
  $("tot-icr").textContent = fmt(mean("icr"), 3);
  const aad = mean("aad_deg");
  $("tot-aad").textContent = aad === null ? "–" : `${fmt(aad, 2)}°`;
  const fresh = ds.filter((d) => !d.stale);
  showLatency($("tot-lat-live"), fresh.map((d) => d.live_latency_p50_ms), fresh.map((d) => d.live_latency_p99_ms));
}

function renderExactLatency() {  // from /api/subjects: measured by the dashboard per subject
  const ss = [...state.subjects.values()];
  showLatency($("tot-lat-exact"), ss.map((s) => s.exact_latency_p50_ms), ss.map((s) => s.exact_latency_p99_ms));
}

function liveCell(d) {  // the live bound's figure (against the device's own orientation) / the bound
  const known = (v) => v !== null && v !== undefined;
  const own = known(d.live_own_max_deg);  // (a truth tap without own orientations: the true-body figure, uncoloured)
  const shown = own ? d.live_own_max_deg : d.live_p99_deg;
  const text = known(shown) ? `${fmt(shown, 1)}°` : "–";
  const b = d.live_bound_deg;
  const bound = b === null || b === undefined ? "–" : (b === 0 || b >= 180 ? "off" : fmtDeg(b));
  const over = own && b > 0 && b < 180 && d.live_own_max_deg > b + 0.01 ? " bad" : "";
  const tip = (own ? `live bound's figure: max ${fmt(d.live_own_max_deg)}°, p99 ${fmt(d.live_own_p99_deg)}° against ` +
    "the device's own orientation; " : "") +
    `against the true body (with fusion and calibration errors): p99 ${fmt(d.live_p99_deg)}°, ` +
    `mean ${fmt(d.live_err_deg)}°, max ${fmt(d.live_max_deg)}° (60 s); live bound ${bound}; ` +
    `live latency p50 ${fmt(d.live_latency_p50_ms, 1)} ms, p99 ${fmt(d.live_latency_p99_ms, 1)} ms`;
  return `<td class="num live${over}" title="${esc(tip)}">${text} / ${bound}</td>`;
}

function renderTable() {
  const body = $("devices-body");
  if (!state.devices.length) {
    body.innerHTML = '<tr class="empty-row"><td colspan="14">Waiting for device statistics…</td></tr>';
    return;
  }
  const maxRate = Math.max(1, ...state.devices.map((d) => d.msgs_per_s || 0));
  const rows = [];
  let subject = null;
  for (const d of state.devices) {
    if (d.subject !== subject) {
      subject = d.subject;
      const n = state.devices.filter((x) => x.subject === subject);
      const s = state.subjects.get(subject);
      rows.push(`<tr class="subject-row" data-subject="${esc(subject)}"><td colspan="14">${esc(subject)} · ` +
        `${n.filter((x) => x.online).length}/${n.length} online${subjectErrors(s)}${headingStopped(s)}</td></tr>`);
    }
    const dot = d.stale ? (d.alive ? "on" : "stale") : (d.online ? "on" : "off");
    const stateText = d.online ? "online" : (d.stale && !d.alive ? "no data" : "offline");
    // calibration (sensor model on): calibrated, or refused with its reason
    const cal = d.calibrated
      ? ` <span class="cal ok" title="calibrated ${fmt(d.calibration_age_s, 0)} s ago, heading drift ${fmt(d.heading_drift_dps, 3)} deg/s compensated">cal</span>`
      : (d.calibration_refused ? ` <span class="cal bad" title="${esc(d.calibration_refused)}">uncal</span>` : "");
    // raw sensors: the device's fusion filter, its gyro bias estimate, rest and bad raw samples
    const bad = Object.entries(d.raw_faults || {}).filter(([, n]) => n).map(([k, n]) => `${k} ${n}`).join(", ");
    const fusion = d.fusion
      ? ` <span class="fusion" data-fusion="${esc(d.fusion)}" title="VQF ${esc(d.fusion)} on the device: gyro bias ${fmt(d.gyro_bias_dps, 3)} deg/s${d.at_rest ? ", at rest" : ""}${bad ? `; bad raw samples: ${esc(bad)}` : ""}">${esc(d.fusion)} ${fmt(d.gyro_bias_dps, 2)}°/s</span>`
      : "";
    const width = Math.round(36 * (d.msgs_per_s || 0) / maxRate);
    const sel = d.device === state.selected ? " selected" : "";
    rows.push(
      `<tr class="device${sel}" data-device="${esc(d.device)}" data-online="${d.online}" data-calibrated="${!!d.calibrated}" ` +
      `data-rate="${d.msgs_per_s ?? ""}" data-icr="${d.icr ?? ""}">` +
      `<td>${esc(d.segment)}</td>` +
      `<td><span class="dot ${dot}"></span>${stateText}${cal}${fusion}</td>` +
      `<td class="num"><span class="bar" style="width:${width}px"></span>${fmt(d.msgs_per_s, 1)}</td>` +
      `<td class="num">${fmtBig(d.bytes_per_s)}</td>` +
      `<td class="num">${fmt(d.icr, 3)}</td>` +
      `<td class="num">${fmt(d.aad_deg)}</td>` +
      `<td class="num">${fmt(d.p99_deg)}</td>` +
      liveCell(d) +
      `<td class="num">${fmt(d.watermark_lag_s)}</td>` +
      `<td class="num${d.gaps ? " warn" : ""}">${d.gaps ?? "–"}</td>` +
      `<td class="num${d.dropped ? " bad" : ""}">${d.dropped ?? "–"}</td>` +
      headingCell(d) +
      clockCell(d) +
      `<td class="num">${d.threshold === null || d.threshold === undefined ? "–" : Number(d.threshold).toPrecision(3)}</td>` +
      `</tr>`);
  }
  body.innerHTML = rows.join("");
}

function subjectErrors(s) {  // the subject's frame error and joint error against the truth (60 s)
  const known = (v) => v !== null && v !== undefined;
  const frame = s && known(s.frame_aad_deg)
    ? ` · <span class="frame-err" title="frame error: mean angle between each segment of the exact frames and the truth at the frame's reference instant, after one turn about the vertical fitted at calibration: it also shows the whole body's heading drifting (60 s)">frame error ${fmt(s.frame_aad_deg)}°</span>` : "";
  const joint = s && known(s.joint_aad_deg)
    ? ` · <span class="joint-err" data-value="${s.joint_aad_deg}" title="joint error: mean angle between the estimated and the true relative orientation of each pair of adjacent segments (knees, elbows, hips, shoulders, neck): posture, whichever way the subject faces (60 s)">joint error ${fmt(s.joint_aad_deg)}°</span>` : "";
  return frame + joint;
}

function headingStopped(s) {  // a subject whose heading correction stopped: the joints its rest pose contradicts
  const shares = s && s.heading_contradicted ? Object.entries(s.heading_contradicted) : [];
  if (!shares.length) return "";
  const joints = shares.map(([j]) => j).join(", ");
  const verb = shares.length > 1 ? "contradict their" : "contradicts its";
  const tip = "its rest pose is not what it says: these joints bend about another axis than a hinge's, or lie out of " +
    "range at any heading; share of the last minute's samples: " +
    shares.map(([j, v]) => `${j} ${Math.round(100 * v)}%`).join(", ") + ". Without correction the headings drift as " +
    "the sensors do (docs/evaluation.md, 'Heading without resets')";
  return ` · <span class="heading-stopped warn" title="${esc(tip)}">heading correction stopped: ${esc(joints)} ${verb} ` +
    "rest pose</span>";
}

function headingCell(d) {  // heading correction: offset applied now · confidence; rate in the tip
  if (d.heading_offset_deg === null || d.heading_offset_deg === undefined) return '<td class="num heading">–</td>';
  const sign = d.heading_offset_deg > 0 ? "+" : "";
  const tip = `heading correction ${fmt(d.heading_offset_deg, 2)}° applied now, changing ${fmt(d.heading_rate_dpm, 2)}°/min; ` +
    `confidence ${fmt(d.heading_confidence, 2)} (1: known within a degree or two, 1/2: within 5°)`;
  const low = d.heading_confidence < 0.5 ? " warn" : "";
  return `<td class="num heading${low}" data-offset="${d.heading_offset_deg}" data-confidence="${d.heading_confidence}" ` +
    `title="${esc(tip)}">${sign}${fmt(d.heading_offset_deg, 1)}° · ${fmt(d.heading_confidence, 2)}</td>`;
}

function clockCell(d) {  // the device's own clock offset estimate and whether it is synced
  if (d.synced === null || d.synced === undefined) return '<td class="num clock">–</td>';
  const rtt = d.sync_rtt_ms === null || d.sync_rtt_ms === undefined ? "" : `, round trip ${fmt(d.sync_rtt_ms)} ms`;
  if (d.clock_offset_ms === null || d.clock_offset_ms === undefined) {
    return `<td class="num clock warn" data-synced="false" title="not synchronised to the time service">no sync</td>`;
  }
  const sign = d.clock_offset_ms > 0 ? "+" : "";
  const text = `${sign}${fmt(d.clock_offset_ms, 1)} ms`;
  return d.synced
    ? `<td class="num clock" data-synced="true" title="clock minus the common time base${rtt}">${text}</td>`
    : `<td class="num clock warn" data-synced="false" title="unsynced: last estimate${rtt}">${text} ⚠</td>`;
}

function syncSelects() {
  const ids = state.devices.map((d) => d.device);
  if (!state.selected && ids.length) selectDevice(ids[0]);
  fillSelect($("chart-device"), ids.map((id) => [id, id]), state.selected);
  const subjects = [...new Set(state.devices.map((d) => d.subject))];
  const targets = subjects.map((s) => [`subject:${s}`, `all devices of ${s}`]).concat(ids.map((id) => [id, id]));
  fillSelect($("ctl-target"), targets, null);
  showCurrent();
}

// Each tunable input shows, as its placeholder, what the selected devices run now (their stats):
// one value, or the range when they differ; the contract's default only before any stats.
function showCurrent() {
  const target = $("ctl-target").value;
  const devices = target.startsWith("subject:")
    ? state.devices.filter((d) => d.subject === target.slice(8))
    : state.devices.filter((d) => d.device === target);
  for (const t of state.tunables || []) {
    const values = devices.map((d) => d[t.name]).filter((v) => typeof v === "number");
    const input = $(`ctl-${t.name}`);
    if (!values.length) {
      input.placeholder = `default ${t.default}`;
      continue;
    }
    const lo = Math.min(...values), hi = Math.max(...values);
    input.placeholder = lo === hi ? `now ${lo}` : `now ${lo} to ${hi}`;
  }
}

function fillSelect(select, options, value) {
  const key = options.map((o) => o[0]).join("|");
  if (select.dataset.key !== key) {
    const keep = value ?? select.value;
    select.innerHTML = options.map(([v, label]) => `<option value="${esc(v)}">${esc(label)}</option>`).join("");
    select.dataset.key = key;
    if (keep && options.some((o) => o[0] === keep)) select.value = keep;
  } else if (value) {
    select.value = value;
  }
}

function selectDevice(id) {
  state.selected = id;
  $("chart-device").value = id;
  for (const tr of document.querySelectorAll("#devices-body tr.device")) {
    tr.classList.toggle("selected", tr.dataset.device === id);
  }
  refreshHistory();
}

// ------------------------------------------------------------------ charts

function makeChart(el, series, yRange) {
  const axis = { stroke: COLORS.muted, grid: { stroke: COLORS.grid, width: 1 }, ticks: { stroke: COLORS.grid } };
  const opts = {
    width: Math.max(200, el.clientWidth),
    height: 160,
    cursor: { drag: { x: false, y: false } },
    legend: { live: false },
    scales: { x: { time: true }, y: yRange ? { range: yRange } : {} },
    axes: [axis, { ...axis, size: 48 }],
    series: [{}].concat(series.map(([label, color, dash]) => ({
      label, stroke: color, width: 1.6, dash, points: { show: false }, spanGaps: true,
      value: (u, v) => (v === null ? "–" : v.toFixed(3)),
    }))),
  };
  return new uPlot(opts, [[]].concat(series.map(() => [])), el);
}

function initCharts() {
  state.charts = {
    rate: makeChart($("chart-rate"), [["msgs/s", COLORS.accent]],
      (u, min, max) => [0, Math.max(1, (max || 0) * 1.25)]),
    icr: makeChart($("chart-icr"), [["ICR", COLORS.left]],
      (u, min, max) => [0, Math.max(0.05, (max || 0) * 1.2)]),
    err: makeChart($("chart-err"), [["AAD", COLORS.accent], ["p99", COLORS.warn, [4, 3]], ["live", COLORS.right],
                                    ["live p99", COLORS.right, [4, 3]]],
      (u, min, max) => [0, Math.max(1, (max || 0) * 1.1)]),
    heading: makeChart($("chart-heading"), [["offset", COLORS.left]],
      (u, min, max) => [Math.min(-1, (min || 0) * 1.1), Math.max(1, (max || 0) * 1.1)]),
  };
  new ResizeObserver(() => {
    for (const [name, chart] of Object.entries(state.charts)) {
      const el = $(`chart-${name}`);
      chart.setSize({ width: Math.max(200, el.clientWidth), height: 160 });
    }
  }).observe($("chart-rate").parentElement.parentElement);
}

async function refreshHistory() {
  const id = state.selected;
  if (!id || !state.charts) return;
  let h;
  try {
    h = await api(`/api/devices/${id}/history?seconds=${$("chart-window").value}`);
  } catch (_) { return; }
  if (id !== state.selected) return;
  state.charts.rate.setData([h.t, h.msgs_per_s]);
  state.charts.icr.setData([h.t, h.icr]);
  state.charts.err.setData([h.t, h.aad_deg, h.p99_deg, h.live_err_deg, h.live_p99_deg]);
  state.charts.heading.setData([h.t, h.heading_offset_deg]);
}

async function refreshAggregators() {
  let aggs;
  try { aggs = (await api("/api/aggregators")).filter((a) => !a.stale); } catch (_) { return; }
  const el = $("tot-agg");
  if (!aggs.length) { el.textContent = "–"; el.className = ""; return; }
  const busiest = aggs.reduce((a, b) => ((b.load ?? 0) > (a.load ?? 0) ? b : a));
  el.textContent = `${fmt(100 * (busiest.load ?? NaN), 0)} % · ${fmt(busiest.late_pct, 2)} %`;
  el.className = busiest.load >= 1 ? "bad" : (busiest.load >= 0.8 || busiest.late_pct >= 1 ? "warn" : "");
  el.dataset.load = busiest.load ?? "";
}

async function refreshParts() {  // restart counts when `limbstream up` runs the system
  let health;
  try { health = await api("/health"); } catch (_) { return; }
  const parts = Object.entries(health.parts || {});
  $("tot-parts-box").hidden = !parts.length;
  const total = parts.reduce((n, [, p]) => n + p.restarts, 0);
  const el = $("tot-parts");
  el.textContent = total ? parts.filter(([, p]) => p.restarts).map(([name, p]) => `${name} ${p.restarts}`).join(" · ") : "0";
  el.className = parts.some(([, p]) => p.state !== "running") ? "bad" : (total ? "warn" : "");
  el.dataset.restarts = total;
}

// ------------------------------------------------------------------ control

// One input per device tunable, as the contract declares them (GET /api/tunables).
function buildTunables(tunables) {
  state.tunables = tunables;
  $("ctl-tunables").innerHTML = tunables.map((t) =>
    `<label title="${esc(t.help)}">${esc(t.name.replace(/_/g, " "))}${t.unit ? ` (${esc(t.unit)})` : ""}` +
    `<input id="ctl-${esc(t.name)}" type="number" min="${t.low}" max="${t.high}" ` +
    `step="${t.type === "int" ? 1 : "any"}" placeholder="default ${t.default}"></label>`).join("");
}

async function applyConfig(ev) {
  ev.preventDefault();
  const result = $("ctl-result");
  const token = $("ctl-token").value.trim();
  sessionStorage.setItem("limbstream-token", token);
  const body = {};
  for (const t of state.tunables || []) {
    const text = $(`ctl-${t.name}`).value.trim();
    if (text !== "") body[t.name] = Number(text);
  }
  if (!Object.keys(body).length) {
    result.className = "result err";
    result.textContent = `Enter some of: ${(state.tunables || []).map((t) => t.name).join(", ")}.`;
    return;
  }
  const target = $("ctl-target").value;
  const ids = target.startsWith("subject:")
    ? state.devices.filter((d) => d.subject === target.slice(8)).map((d) => d.device)
    : [target];
  $("ctl-apply").disabled = true;
  result.className = "result";
  result.textContent = `applying to ${ids.length} device(s)…`;
  const outcomes = await Promise.all(ids.map((id) => api(`/api/devices/${id}/config`, {
    method: "PUT",
    headers: { "Content-Type": "application/json", Authorization: `Bearer ${token}` },
    body: JSON.stringify(body),
  }).then((r) => ({ ok: true, r }), (e) => ({ ok: false, e }))));
  $("ctl-apply").disabled = false;
  const good = outcomes.filter((o) => o.ok);
  const bad = outcomes.filter((o) => !o.ok);
  if (!bad.length) {
    const c = good[0].r;
    result.className = "result ok";
    const values = (state.tunables || []).map((t) => `${t.name.replace(/_/g, " ")} ${c[t.name]}`).join(", ");
    result.textContent = `confirmed by ${good.length}/${ids.length}: ${values}`;
  } else {
    result.className = "result err";
    result.textContent = `${good.length}/${ids.length} confirmed; ${bad[0].e.message}`;
  }
}

// A countdown to get into the pose, then POST /api/subjects/{s}/calibrate (the API token above).
const CAL_COUNTDOWN_S = 3;

async function calibrate() {
  const target = $("ctl-target").value;
  const subject = target.startsWith("subject:") ? target.slice(8) : target.split("/")[0];
  const pose = $("cal-pose").value;
  const result = $("cal-result");
  const token = $("ctl-token").value.trim();
  $("cal-go").disabled = true;
  result.className = "result";
  for (let left = CAL_COUNTDOWN_S; left > 0; left--) {
    result.textContent = `${subject}: get into the ${pose} pose, ${left}…`;
    await new Promise((done) => setTimeout(done, 1000));
  }
  result.textContent = `${subject}: hold the ${pose} pose still…`;
  try {
    const r = await api(`/api/subjects/${encodeURIComponent(subject)}/calibrate`, {
      method: "POST",
      headers: { "Content-Type": "application/json", Authorization: `Bearer ${token}` },
      body: JSON.stringify({ pose }),
    });
    result.className = "result ok";
    result.textContent = `${subject}: ${Object.keys(r.devices).length} devices calibrated (${pose})`;
  } catch (e) {
    result.className = "result err";
    result.textContent = `${subject}: ${e.message}`;
  } finally {
    $("cal-go").disabled = false;
  }
}

// ------------------------------------------------------------------ start

async function start() {
  $("ctl-token").value = sessionStorage.getItem("limbstream-token") || "";
  $("control").addEventListener("submit", applyConfig);
  $("ctl-target").addEventListener("change", showCurrent);
  $("cal-go").addEventListener("click", calibrate);
  $("trackers-body").addEventListener("change", (e) => { if (e.target.matches("select.assign")) assignSensor(e.target); });
  $("chart-device").addEventListener("change", (e) => selectDevice(e.target.value));
  $("chart-window").addEventListener("change", refreshHistory);
  for (const input of document.querySelectorAll('input[name="pose-kind"]')) {
    input.checked = input.value === state.kind;
    input.addEventListener("change", () => { if (input.checked) setKind(input.value); });
  }
  $("skeletons").dataset.kind = state.kind;
  $("follow").checked = state.follow;
  $("follow").addEventListener("change", (e) => setFollow(e.target.checked));
  $("devices-body").addEventListener("click", (e) => {
    const tr = e.target.closest("tr.device");
    if (tr) selectDevice(tr.dataset.device);
  });
  initCharts();
  try { buildTunables(await api("/api/tunables")); } catch (_) { /* the form says so on submit */ }
  try { state.layouts = await api("/api/layouts"); } catch (_) { /* retried below */ }
  await refreshDevices();
  await refreshSubjects();
  await refreshAggregators();
  await refreshParts();
  setInterval(refreshDevices, DEVICES_EVERY_MS);
  setInterval(refreshSubjects, SUBJECTS_EVERY_MS);
  setInterval(refreshAggregators, SUBJECTS_EVERY_MS);
  setInterval(refreshParts, SUBJECTS_EVERY_MS);
  setInterval(refreshHistory, HISTORY_EVERY_MS);
  refreshGateways();
  setInterval(refreshGateways, GATEWAYS_EVERY_MS);
  setInterval(async () => {
    if (!state.layouts) { try { state.layouts = await api("/api/layouts"); } catch (_) { /* next time */ } }
  }, 3000);
  requestAnimationFrame(animate);
}

document.addEventListener("DOMContentLoaded", start);  // after figures.js and trackers.js
