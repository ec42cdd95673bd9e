/* limbstream dashboard page, joint angles: a plot per subject of the chosen angles over the
 * last seconds, from GET /api/subjects/<s>/joints (the angles of its live frames; OpenSim's
 * names, degrees; the list of angles is the names the messages carry). Loaded after app.js, whose helpers ($, api, esc, fmt, COLORS, state) it uses. */
"use strict";

const JOINTS_EVERY_MS = 500;
const JOINTS_KEY = "limbstream-joints";           // localStorage: the angles chosen
const JOINTS_DEFAULT = ["hip_flexion_r", "hip_flexion_l", "knee_angle_r", "knee_angle_l"];
const JOINT_SHADES = ["", [6, 4], [2, 3], [10, 3, 2, 3]];  // dashes of a side's 1st, 2nd, ... angle

const joints = {
  names: [],                                      // every angle the subjects' messages carry, their order
  chosen: JSON.parse(localStorage.getItem(JOINTS_KEY) || "null") || JOINTS_DEFAULT,
  plots: new Map(),                               // subject -> JointPlot
};

function angleColor(name, k) {  // right: orange, left: blue, neck: grey; dashed further angles of a side
  const side = name.endsWith("_r") ? COLORS.right : name.endsWith("_l") ? COLORS.left : COLORS.mid;
  return [side, JOINT_SHADES[k % JOINT_SHADES.length] || undefined];
}

class JointPlot {
  constructor(subject, container) {
    this.subject = subject;
    const card = document.createElement("figure");
    card.className = "joint-plot";
    card.dataset.subject = subject;
    card.innerHTML = `<figcaption><b>${esc(subject)}</b> <span class="why">waiting…</span></figcaption>` +
      `<div class="chart"></div>`;
    const after = [...container.querySelectorAll(".joint-plot")].find((f) => f.dataset.subject > subject);
    container.insertBefore(card, after || null);  // in the subjects' order, whichever answers first
    this.card = card;
    this.why = card.querySelector(".why");
    this.el = card.querySelector(".chart");
    this.chart = null;
    this.names = [];
  }

  build(names) {  // a chart of these angles (again when the choice changes)
    if (this.chart) this.chart.destroy();
    this.names = names;
    const perSide = { r: 0, l: 0, m: 0 };
    const series = names.map((n) => {
      const side = n.endsWith("_r") ? "r" : n.endsWith("_l") ? "l" : "m";
      const [color, dash] = angleColor(n, perSide[side]++);
      return [n, color, dash];
    });
    this.chart = makeChart(this.el, series, (u, min, max) => [Math.min(-10, min ?? 0), Math.max(30, max ?? 0)]);
    this.card.dataset.series = String(names.length);
  }

  show(body) {
    const names = body.names;
    if (!this.chart || names.join() !== this.names.join()) this.build(names);
    this.chart.setData([body.t, ...names.map((n) => body.angles[n])]);
    const latest = body.latest;
    const points = body.t.length;
    this.card.dataset.points = String(points);
    this.card.dataset.calibration = latest.calibration;
    this.card.dataset.valid = String(latest.valid);
    this.card.classList.toggle("invalid", !latest.valid);
    const facing = latest.facing_deg === null ? "" : `, facing ${fmt(latest.facing_deg, 1)}°`;
    this.why.textContent = latest.valid
      ? `${body.kind} · calibration ${latest.calibration}${facing} · ` +
        names.map((n) => `${n} ${latest.angles[n] === null ? "–" : fmt(latest.angles[n], 1) + "°"}`).join(" · ")
      : `no angles: ${latest.why}`;
  }

  close() {
    if (this.chart) this.chart.destroy();
    this.card.remove();
  }
}

// One checkbox per angle the messages carry, grouped by joint as they order them; angles a later
// subject's messages add (another layout's) join the list.
function buildJointPicker(names) {
  const added = names.filter((n) => !joints.names.includes(n));
  if (!added.length) return;
  joints.names = joints.names.concat(added);
  $("joints-pick").innerHTML = joints.names.map((n) =>
    `<label><input type="checkbox" value="${esc(n)}"${joints.chosen.includes(n) ? " checked" : ""}> ${esc(n)}</label>`
  ).join("");
  $("joints-pick").dataset.names = String(joints.names.length);
}

async function refreshJoints() {
  const subjects = [...state.subjects.keys()].slice(0, MAX_FIGURES);
  const seconds = $("joints-window").value;
  const query = [`seconds=${seconds}`].concat(joints.chosen.map((n) => `angle=${encodeURIComponent(n)}`)).join("&");
  await Promise.all(subjects.map(async (subject) => {
    let body;
    try {
      body = await api(`/api/subjects/${encodeURIComponent(subject)}/joints?${query}`);
    } catch (_) { return; }  // none yet (404), or the service is away: the plot waits
    buildJointPicker(Object.keys(body.latest.angles));
    if (!joints.chosen.length) body = { ...body, names: [], angles: {} };
    let plot = joints.plots.get(subject);
    if (!plot) {
      plot = new JointPlot(subject, $("joints-plots"));
      joints.plots.set(subject, plot);
    }
    plot.show(body);
  }));
  for (const [subject, plot] of joints.plots) {
    if (!state.subjects.has(subject)) { plot.close(); joints.plots.delete(subject); }
  }
  $("joints-empty").hidden = joints.plots.size > 0;
}

function startJoints() {
  $("joints-pick").addEventListener("change", () => {
    joints.chosen = [...document.querySelectorAll("#joints-pick input:checked")].map((i) => i.value);
    localStorage.setItem(JOINTS_KEY, JSON.stringify(joints.chosen));
    refreshJoints();
  });
  $("joints-window").addEventListener("change", refreshJoints);
  new ResizeObserver(() => {
    for (const plot of joints.plots.values()) {
      if (plot.chart) plot.chart.setSize({ width: Math.max(200, plot.el.clientWidth), height: 160 });
    }
  }).observe($("joints-plots"));
  setInterval(refreshJoints, JOINTS_EVERY_MS);
}

startJoints();
