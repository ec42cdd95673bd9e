/* limbstream dashboard page, skeletons: a figure per subject drawn from its WebSocket pose stream
 * (/ws/pose/<subject>?kind=live|exact, the page's toggle) with the bones of the layout each frame
 * names (state.layouts: GET /api/layouts). Loaded after app.js, whose helpers ($, api, esc, fmt,
 * COLORS, state) it uses. */
"use strict";

// ------------------------------------------------------------------ skeletons

class Figure {
  constructor(subject, container) {
    this.subject = subject;
    this.frame = null;
    this.dirty = false;
    this.drawn = 0;
    this.yaw = -0.6;
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

  draw() {
    if (!this.dirty || !this.frame || !state.layouts) return;
    this.dirty = false;
    const f = this.frame;
    const layout = state.layouts[f.layout];
    if (!layout) { this.caption.textContent = `layout ${f.layout} unknown to this page`; return; }
    const ctx = this.canvas.getContext("2d");
    const W = this.canvas.width, H = this.canvas.height;
    ctx.clearRect(0, 0, W, H);
    const scale = H / 2.05, cx = W / 2, cy = H * 0.45;
    const c = Math.cos(this.yaw), s = Math.sin(this.yaw);
    const proj = (p) => {
      const x = p[0] * c + p[2] * s;
      const z = -p[0] * s + p[2] * c;
      const k = 1 / (1 - z * 0.12);               // gentle perspective
      return [cx + x * scale * k, cy - p[1] * scale * k, z];
    };
    // floor: ellipse under the lowest joint
    const ys = Object.values(f.joints).map((p) => p[1]);
    const floor = Math.min(...ys);
    ctx.strokeStyle = COLORS.grid;
    ctx.lineWidth = 1;
    for (let r = 0.25; r <= 0.75; r += 0.25) {
      ctx.beginPath();
      ctx.ellipse(cx, cy - floor * scale, r * scale, r * scale * 0.22, 0, 0, 2 * Math.PI);
      ctx.stroke();
    }
    const P = {};
    for (const [name, p] of Object.entries(f.joints)) P[name] = proj(p);
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

function setKind(kind) {  // the toggle: frames every figure draws, remembered for the next visit
  state.kind = kind;
  localStorage.setItem(KIND_KEY, kind);
  $("skeletons").dataset.kind = kind;
  for (const fig of state.figures.values()) fig.setKind(kind);
}
