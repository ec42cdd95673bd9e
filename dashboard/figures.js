/* limbstream dashboard page, skeletons: a figure per subject drawn from its WebSocket pose stream
 * (/ws/pose/<subject>?kind=live|exact, the page's toggle) with the bones of the layout each frame
 * names (state.layouts: GET /api/layouts; a layout file's: the subject's, GET /api/subjects/<subject>).
 * Loaded after app.js, whose helpers ($, api, esc, fmt,
 * COLORS, state) it uses. */
"use strict";

// ------------------------------------------------------------------ skeletons

const TRAIL_S = 5;               // the root's trail on the floor, seconds of frame time
const GRID_M = 0.5, GRID_REACH_M = 2;   // floor grid: spacing, and reach around the view's centre
const PITCH = 0.3;               // the view looks down on the floor by this much (rad)

// The root a frame is drawn at (x, y, z m, floor at 0): the frame's root where it carries one, else
// the pelvis lifted so the lowest joint stands on the floor (frames of a body not tracked).
function placeRoot(f) {
  const root = f.root || [0, 0, 0];
  if (root.some((v) => v !== 0) || (f.contacts || []).length) return root;
  return [0, -Math.min(...Object.values(f.joints).map((p) => p[1])), 0];
}

// World point (m) -> [x px, y px, depth] on a W x H canvas: turned by yaw about the vertical through
// the floor point view ([x, z] m), looked at from slightly above, with a gentle perspective.
function projector(W, H, yaw, view) {
  const scale = H / 2.3, cx = W / 2, ground = H * 0.86;
  const c = Math.cos(yaw), s = Math.sin(yaw), cp = Math.cos(PITCH), sp = Math.sin(PITCH);
  return (p) => {
    const dx = p[0] - view[0], dz = p[2] - view[1];
    const x = dx * c + dz * s;
    const z = -dx * s + dz * c;
    const depth = z * cp + p[1] * sp, up = p[1] * cp - z * sp;
    const k = 1 / (1 - depth * 0.12);
    return [cx + x * scale * k, ground - up * scale * k, depth];
  };
}

function drawGrid(ctx, proj, view) {  // lines on the floor every GRID_M, fixed in the room
  ctx.strokeStyle = COLORS.grid;
  ctx.lineWidth = 1;
  const line = (a, b) => {
    const [p, q] = [proj(a), proj(b)];
    ctx.beginPath();
    ctx.moveTo(p[0], p[1]);
    ctx.lineTo(q[0], q[1]);
    ctx.stroke();
  };
  const [x0, z0] = view, r = GRID_REACH_M;
  for (let x = Math.ceil((x0 - r) / GRID_M) * GRID_M; x <= x0 + r; x += GRID_M) line([x, 0, z0 - r], [x, 0, z0 + r]);
  for (let z = Math.ceil((z0 - r) / GRID_M) * GRID_M; z <= z0 + r; z += GRID_M) line([x0 - r, 0, z], [x0 + r, 0, z]);
}

function drawTrail(ctx, proj, trail) {  // the root's ground positions, oldest first
  if (trail.length < 2) return;
  ctx.strokeStyle = COLORS.accent;
  ctx.lineWidth = 2;
  ctx.globalAlpha = 0.7;
  ctx.beginPath();
  trail.forEach(([, x, z], i) => { const p = proj([x, 0, z]); if (i) ctx.lineTo(p[0], p[1]); else ctx.moveTo(p[0], p[1]); });
  ctx.stroke();
  ctx.globalAlpha = 1;
}

// The planted foot points (wire.CONTACTS names) marked on the floor under their joints: a heel under
// the ankle, a toe under the toe joint (the ankle where the layout has none). Returns the joints marked.
function drawContacts(ctx, proj, world, contacts) {
  const marked = [];
  for (const name of contacts) {
    const [side, point] = name.split("_");
    const joint = point === "toe" && world[`${side}_toe`] ? `${side}_toe` : `${side}_ankle`;
    if (!world[joint] || marked.includes(joint)) continue;
    marked.push(joint);
    const p = proj([world[joint][0], 0, world[joint][2]]);
    ctx.fillStyle = COLORS.warn;
    ctx.beginPath();
    ctx.ellipse(p[0], p[1], 9, 4, 0, 0, 2 * Math.PI);
    ctx.fill();
  }
  return marked;
}

class Figure {
  constructor(subject, container) {
    this.subject = subject;
    this.frame = null;
    this.dirty = false;
    this.drawn = 0;
    this.yaw = -0.6;
    this.trail = [];             // [t s, x m, z m] of the root, oldest first
    this.view = null;            // [x, z] m: the floor point the view centres on
    this.received = 0;
    this.retry = 500;
    const card = document.createElement("div");
    card.className = "skeleton";
    card.dataset.subject = subject;
    card.innerHTML = `<canvas width="440" height="520"></canvas>` +
      `<div class="cap"><b>${esc(subject)}</b><span>waiting…</span></div>`;
    container.appendChild(card);
    this.card = card;
    this.canvas = card.querySelector("canvas");
    this.caption = card.querySelector(".cap span");
    this.canvas.dataset.frames = "0";
    this.kind = state.kind;
    this.bindDrag();
    this.connect();
  }

  bindDrag() {
    let x0 = null;
    this.canvas.addEventListener("pointerdown", (e) => { x0 = e.clientX; this.canvas.setPointerCapture(e.pointerId); });
    this.canvas.addEventListener("pointermove", (e) => {
      if (x0 === null) return;
      this.yaw += (e.clientX - x0) * 0.01;
      x0 = e.clientX;
      this.dirty = true;
    });
    this.canvas.addEventListener("pointerup", () => { x0 = null; });
  }

  connect() {
    const proto = location.protocol === "https:" ? "wss" : "ws";
    const ws = new WebSocket(`${proto}://${location.host}/ws/pose/${encodeURIComponent(this.subject)}` +
                             `?kind=${this.kind}`);
    this.ws = ws;
    ws.onmessage = (ev) => {
      if (ws !== this.ws) return;                // a stream of the kind before a switch
      this.frame = JSON.parse(ev.data);
      this.received += 1;
      this.dirty = true;
      this.retry = 500;
    };
    ws.onclose = () => {
      if (this.closed || ws !== this.ws) return;
      this.caption.textContent = "reconnecting…";
      setTimeout(() => { if (ws === this.ws && !this.closed) this.connect(); }, this.retry);
      this.retry = Math.min(this.retry * 2, 5000);
    };
  }

  setKind(kind) {  // a new stream of the other kind; the figure holds its frame until one comes
    if (kind === this.kind) return;
    this.kind = kind;
    const old = this.ws;
    this.connect();
    old.close();
  }

  close() {
    this.closed = true;
    this.ws.close();
    this.card.remove();
  }

  remember(t, root) {  // the root's ground positions of the last TRAIL_S seconds (frame time)
    if (this.trail.length && t < this.trail[this.trail.length - 1][0]) this.trail = [];   // time went back: a new take
    this.trail.push([t, root[0], root[2]]);
    while (this.trail[0][0] < t - TRAIL_S) this.trail.shift();
  }

  // A layout file's layout (not among GET /api/layouts' built-ins): the subject's own, as its
  // devices announce it (GET /api/subjects/<subject>: its segments, joints and bones), kept by the
  // figure (another subject's file may use the same name); asked at most once a second.
  subjectLayout(name) {
    if (this.own && this.own.layout === name) return this.own;
    const now = performance.now();
    if (this.asking || now - (this.asked || -Infinity) < 1000) return null;
    this.asking = true;
    this.asked = now;
    api(`/api/subjects/${encodeURIComponent(this.subject)}`)
      .then((s) => { if (s.layout === name && s.bones) this.own = s; })
      .catch(() => { /* asked again on a later frame */ })
      .finally(() => { this.asking = false; this.dirty = true; });
    return null;
  }

  draw() {
    if (!this.dirty || !this.frame || !state.layouts) return;
    this.dirty = false;
    const f = this.frame;
    const layout = state.layouts[f.layout] || this.subjectLayout(f.layout);
    if (!layout) { this.caption.textContent = `layout ${f.layout} unknown to this page`; return; }
    const root = placeRoot(f);
    this.remember(f.t, root);
    if (state.follow || !this.view) this.view = [root[0], root[2]];
    const ctx = this.canvas.getContext("2d");
    const W = this.canvas.width, H = this.canvas.height;
    ctx.clearRect(0, 0, W, H);
    const proj = projector(W, H, this.yaw, this.view);
    drawGrid(ctx, proj, this.view);
    drawTrail(ctx, proj, this.trail);
    const world = {};
    for (const [name, p] of Object.entries(f.joints)) world[name] = [p[0] + root[0], p[1] + root[1], p[2] + root[2]];
    const planted = drawContacts(ctx, proj, world, f.contacts || []);
    const P = {};
    for (const [name, p] of Object.entries(world)) P[name] = proj(p);
    const side = (n) => (n.startsWith("l_") ? COLORS.left : n.startsWith("r_") ? COLORS.right : COLORS.mid);
    const bones = layout.bones
      .filter(([a, b]) => P[a] && P[b])
      .map(([a, b]) => [a, b, (P[a][2] + P[b][2]) / 2])
      .sort((u, v) => u[2] - v[2]);                 // far first
    ctx.lineCap = "round";
    for (const [a, b, z] of bones) {
      ctx.globalAlpha = 0.55 + 0.45 * Math.max(0, Math.min(1, 0.5 + z));
      ctx.strokeStyle = side(b);
      ctx.lineWidth = 7;
      ctx.beginPath();
      ctx.moveTo(P[a][0], P[a][1]);
      ctx.lineTo(P[b][0], P[b][1]);
      ctx.stroke();
    }
    ctx.globalAlpha = 1;
    const isHead = (name) => name === "head" || name === "head_top";   // paper10's / full's top of the head
    for (const [name, p] of Object.entries(P)) {
      ctx.fillStyle = isHead(name) ? COLORS.mid : "#0f1419";
      ctx.strokeStyle = side(name);
      ctx.lineWidth = 2.5;
      ctx.beginPath();
      ctx.arc(p[0], p[1], isHead(name) ? 14 : 5, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
    }
    this.drawn += 1;
    this.canvas.dataset.frames = String(this.drawn);
    this.canvas.dataset.kind = f.kind;        // of the frame drawn last
    this.canvas.dataset.layout = f.layout;    // and its layout, bones and joints drawn
    this.canvas.dataset.bones = String(bones.length);
    this.canvas.dataset.joints = String(Object.keys(P).length);
    this.canvas.dataset.root = (f.root || [0, 0, 0]).join(",");    // as the frame carries it (m)
    this.canvas.dataset.contacts = (f.contacts || []).join(",");
    this.canvas.dataset.planted = planted.join(",");              // the joints marked on the floor
    this.canvas.dataset.trail = String(this.trail.length);
    this.canvas.dataset.follow = String(state.follow);
    this.canvas.dataset.view = this.view.map((v) => v.toFixed(3)).join(",");   // floor point at the centre (x,z m)
    this.card.classList.toggle("flag-missing", f.missing || f.gap);
    const flags = f.missing ? " · missing" : f.gap ? " · gap" : "";
    const subject = state.subjects.get(this.subject);   // its layout and dimensions
    const height = subject && subject.height_m ? ` · ${fmt(subject.height_m, 2)} m` : "";
    this.caption.textContent = `${f.kind} #${f.seq} · ${f.layout}${height}${flags}`;
    this.caption.title = subject && subject.bones_m
      ? `bone lengths, m: ${Object.entries(subject.bones_m).map(([b, m]) => `${b} ${fmt(m, 3)}`).join(", ")}` : "";
  }
}

async function refreshSubjects() {
  let subjects;
  try { subjects = await api("/api/subjects"); } catch (_) { return; }
  state.subjects = new Map(subjects.map((s) => [s.subject, s]));
  renderExactLatency();
  const container = $("skeletons");
  const withPose = subjects.filter((s) => s.pose).slice(0, MAX_FIGURES);
  for (const s of withPose) {
    if (!state.figures.has(s.subject)) state.figures.set(s.subject, new Figure(s.subject, container));
  }
  // subjects whose frames this service cannot read (a layout file's): why, instead of a figure
  const refused = subjects.filter((s) => !s.pose && s.pose_refused);
  $("skeletons-refused").innerHTML = refused.map((s) =>
    `<li data-subject="${esc(s.subject)}"><b>${esc(s.subject)}</b>: ${esc(s.pose_refused)}</li>`).join("");
  $("skeletons-empty").hidden = state.figures.size > 0 || refused.length > 0;
}

function animate() {
  for (const fig of state.figures.values()) fig.draw();
  requestAnimationFrame(animate);
}

function setFollow(on) {  // the toggle: views keep their subject centred, or stay where they are
  state.follow = on;
  localStorage.setItem(FOLLOW_KEY, on ? "on" : "off");
  $("skeletons").dataset.follow = String(on);
  for (const fig of state.figures.values()) fig.dirty = true;
}

function setKind(kind) {  // the toggle: frames every figure draws, remembered for the next visit
  state.kind = kind;
  localStorage.setItem(KIND_KEY, kind);
  $("skeletons").dataset.kind = kind;
  for (const fig of state.figures.values()) fig.setKind(kind);
}
