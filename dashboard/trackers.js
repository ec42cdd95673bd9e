/* limbstream dashboard page, trackers: the gateways' sensors and the device each feeds
 * (GET /api/gateways), reassigned from the page. Loaded after app.js, whose helpers it uses. */
"use strict";

// ------------------------------------------------------------------ trackers (gateways' sensors)

const GATEWAYS_EVERY_MS = 2000;

async function refreshGateways() {
  if (document.activeElement && document.activeElement.closest("#trackers-body")) return;  // the user is choosing
  let gateways;
  try { gateways = await api("/api/gateways"); } catch (_) { return; }
  const rows = [];
  for (const g of gateways) {
    for (const s of g.sensors) {
      const name = `${s.tracker}/${s.sensor}`;
      const choices = g.segments.map((seg) => `${g.subject}/${seg}`);
      if (s.device && !choices.includes(s.device)) choices.unshift(s.device);
      const options = [`<option value="">— none —</option>`].concat(choices.map((d) =>
        `<option value="${esc(d)}"${d === s.device ? " selected" : ""}>${esc(d)}</option>`));
      rows.push(`<tr class="sensor" data-gateway="${esc(g.gateway)}" data-tracker="${esc(s.tracker)}"
          data-sensor="${s.sensor}" data-device="${esc(s.device || "")}" data-online="${s.online}">
        <td>${esc(g.gateway)}</td><td>${esc(name)}</td><td>${s.online ? "online" : "offline"}</td>
        <td class="num">${s.position ?? "–"}</td>
        <td><select class="assign" aria-label="device of ${esc(name)}">${options.join("")}</select></td>
        <td class="why">${esc(s.why || "")}</td></tr>`);
    }
  }
  $("trackers-body").innerHTML = rows.length ? rows.join("")
    : `<tr class="empty-row"><td colspan="6">${gateways.length ? "No sensor has reported yet." : "No gateway answered."}</td></tr>`;
}

async function assignSensor(select) {
  const tr = select.closest("tr.sensor");
  const name = `${tr.dataset.tracker}/${tr.dataset.sensor}`;
  const [subject, segment] = select.value ? select.value.split("/") : [null, null];
  const result = $("trk-result");
  try {
    await api(`/api/gateways/${encodeURIComponent(tr.dataset.gateway)}/assign`, {
      method: "POST",
      headers: { "Content-Type": "application/json", Authorization: `Bearer ${$("ctl-token").value.trim()}` },
      body: JSON.stringify({ tracker: tr.dataset.tracker, sensor: Number(tr.dataset.sensor), subject, segment }),
    });
    result.className = "result ok";
    result.textContent = `${name} -> ${select.value || "none"}`;
  } catch (e) {
    result.className = "result err";
    result.textContent = `${name}: ${e.message}`;
  }
  select.blur();
  await refreshGateways();
}
