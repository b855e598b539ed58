// fieldkit ground station page: the swarm view from /api/stream (Server-Sent Events), drawn
// on a canvas and in tables; commands POSTed to /api/command. No library, nothing fetched
// from the internet: the page works offline.
"use strict";

const $ = (id) => document.getElementById(id);
let view = null;
let lastEvent = 0;
let source = null;
let drawQueued = false;
const STATE_COLORS = {
  TURNEDOFF: "#888", TAKEOFF: "#e67e22", BARRIERWAIT: "#f1c40f", IDLE: "#3498db",
  STOP: "#c0392b", FREE: "#1abc9c", ASKING: "#16a085", JOINING: "#8e44ad",
  JOINED: "#27ae60", LOCK: "#145a32", DEPLOY: "#2980b9",
};

function connect() {
  if (source) source.close();
  source = new EventSource("/api/stream");
  source.onopen = () => { $("link").textContent = "live"; $("link").className = "badge on"; };
  source.onerror = () => {
    // EventSource reconnects by itself; say so meanwhile.
    $("link").textContent = "reconnecting…"; $("link").className = "badge off";
  };
  source.onmessage = (msg) => {
    try { view = JSON.parse(msg.data); } catch (e) { return; }
    // Draw at most once a frame: a burst of views never piles up.
    if (!drawQueued) { drawQueued = true; requestAnimationFrame(render); }
  };
}

function render() {
  drawQueued = false;
  if (!view) return;
  $("clock").textContent = `t = ${view.t.toFixed(1)} s`;
  const alive = view.robots.filter((r) => !r.lost).length;
  $("summary").textContent = `${alive} of ${view.robots.length} robots heard`;
  drawPlot();
  drawRobots();
  drawCommands();
  drawUpdate();
  drawEvents();
  drawTargets();
  for (const b of document.querySelectorAll("#controls button, #btn-wp")) {
    b.disabled = !view.can_command;
    b.title = view.can_command ? "" : "start the ground station with --keys DIR to command";
  }
}

function bounds() {
  const xs = [], ys = [];
  const add = (p) => { if (p && p[0] !== null && p[1] !== null) { xs.push(p[0]); ys.push(p[1]); } };
  for (const r of view.robots) if (r.east !== null) add([r.east, r.north]);
  for (const p of view.geofence) add(p);
  for (const p of view.graph || []) add(p);
  for (const p of view.region) add(p);
  if (!xs.length) { xs.push(-10, 10); ys.push(-10, 10); }
  let x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const pad = Math.max(5, 0.1 * Math.max(x1 - x0, y1 - y0));
  return [x0 - pad, x1 + pad, y0 - pad, y1 + pad];
}

let transform = null;
function drawPlot() {
  const c = $("plot"), g = c.getContext("2d");
  const [x0, x1, y0, y1] = bounds();
  const s = Math.min(c.width / (x1 - x0), c.height / (y1 - y0));
  const ox = (c.width - s * (x1 - x0)) / 2, oy = (c.height - s * (y1 - y0)) / 2;
  const px = (e) => ox + (e - x0) * s, py = (n) => c.height - oy - (n - y0) * s;
  transform = { x0, y0, s, ox, oy, h: c.height };
  g.clearRect(0, 0, c.width, c.height);
  // grid: 10 m (or coarser) lines
  let step = 10; while ((x1 - x0) / step > 20) step *= 5;
  g.strokeStyle = "#eee"; g.lineWidth = 1;
  for (let e = Math.ceil(x0 / step) * step; e < x1; e += step) { g.beginPath(); g.moveTo(px(e), 0); g.lineTo(px(e), c.height); g.stroke(); }
  for (let n = Math.ceil(y0 / step) * step; n < y1; n += step) { g.beginPath(); g.moveTo(0, py(n)); g.lineTo(c.width, py(n)); g.stroke(); }
  g.fillStyle = "#999"; g.fillText(`grid ${step} m`, 4, c.height - 4);
  const poly = (pts, stroke, fill, dash) => {
    if (!pts || pts.length < 2) return;
    g.beginPath(); g.setLineDash(dash || []);
    pts.forEach((p, i) => (i ? g.lineTo(px(p[0]), py(p[1])) : g.moveTo(px(p[0]), py(p[1]))));
    g.closePath();
    if (fill) { g.fillStyle = fill; g.fill(); }
    g.strokeStyle = stroke; g.lineWidth = 2; g.stroke(); g.setLineDash([]);
  };
  poly(view.region, "rgba(46,134,222,.8)", "rgba(46,134,222,.15)");
  poly(view.geofence, "#c00", null, [6, 4]);
  for (const p of view.hotspots) { g.fillStyle = "#2e86de"; g.fillRect(px(p[0]) - 3, py(p[1]) - 3, 6, 6); }
  for (const p of view.graph || []) {
    g.strokeStyle = "#9b59b6"; g.lineWidth = 1.5;
    g.beginPath(); g.arc(px(p[0]), py(p[1]), 5, 0, 2 * Math.PI); g.stroke();
  }
  for (const r of view.robots) {
    if (r.east === null) continue;
    const x = px(r.east), y = py(r.north);
    g.globalAlpha = r.lost ? 0.35 : 1;
    g.fillStyle = STATE_COLORS[r.state] || "#555";
    g.beginPath(); g.arc(x, y, 6, 0, 2 * Math.PI); g.fill();
    if (r.suspect) { g.strokeStyle = "#c00"; g.lineWidth = 2; g.stroke(); }
    g.fillStyle = "#222"; g.fillText(String(r.id), x + 8, y + 4);
    g.globalAlpha = 1;
  }
}

function cell(tr, i, text, cls) {
  const td = tr.children[i];
  if (td.textContent !== text) td.textContent = text;
  td.className = cls || "";
}

function drawRobots() {
  const body = $("robots").tBodies[0];
  const rows = new Map([...body.rows].map((tr) => [tr.dataset.id, tr]));
  const seen = new Set();
  view.robots.forEach((r, k) => {
    const key = String(r.id);
    seen.add(key);
    let tr = rows.get(key);
    if (!tr) {
      tr = document.createElement("tr"); tr.dataset.id = key;
      for (let i = 0; i < 9; i++) tr.appendChild(document.createElement("td"));
    }
    if (body.rows[k] !== tr) body.insertBefore(tr, body.rows[k] || null);
    tr.className = (r.lost ? "lost " : "") + (r.suspect ? "suspect" : "");
    tr.title = r.suspect ? `reports ${r.suspect}` : "";
    const state = r.state || (r.script === "failed" ? "script failed" : "—");
    cell(tr, 0, key);
    cell(tr, 1, r.profile || "—");
    cell(tr, 2, state);
    cell(tr, 3, r.battery === null ? "—" : `${r.battery} %`);
    cell(tr, 4, r.alt === null ? "—" : r.alt.toFixed(1));
    cell(tr, 5, r.age === null ? "—" : `${r.age.toFixed(1)} s ago`);
    cell(tr, 6, r.link === null ? (r.lost ? "lost" : "relayed") : `${Math.round(r.link * 100)} %`);
    cell(tr, 7, r.version === null ? "—" : `v${r.version}${r.phase && r.phase !== "running" ? " " + r.phase : ""}`);
    cell(tr, 8, r.acked ? `#${r.acked}` : "—");
  });
  for (const [key, tr] of rows) if (!seen.has(key)) tr.remove();
}

function drawCommands() {
  const body = $("commands").tBodies[0];
  const html = view.commands.slice().reverse().map((c) => {
    const cls = c.done ? "ok" : "wait";
    const waiting = c.done ? "—" : (c.missing.length ? c.missing.join(", ") : "…") + (c.expired ? " (timed out)" : "");
    return `<tr data-seq="${c.seq}"><td>${esc(c.text)}</td><td class="${cls}">${c.acked.join(", ") || "none"}</td><td>${esc(waiting)}</td></tr>`;
  }).join("");
  if (body.innerHTML !== html) body.innerHTML = html;
}

function drawUpdate() {
  const versions = {};
  for (const r of view.robots) {
    if (r.version === null) continue;
    const key = `v${r.version} ${r.phase}`;
    (versions[key] = versions[key] || []).push(r.id);
  }
  const parts = Object.entries(versions).map(([k, ids]) => `${esc(k)}: robots ${ids.join(", ")}`);
  for (const [v, why] of Object.entries(view.bad_versions)) parts.push(`<b>v${esc(v)} rolled back</b>: ${esc(why)}`);
  const html = parts.length ? parts.join("<br>") : "no version heard (the swarm's keys show it)";
  if ($("update").innerHTML !== html) $("update").innerHTML = html;
}

function drawEvents() {
  const list = $("events");
  for (const e of view.events) {
    if (e.n <= lastEvent) continue;
    lastEvent = e.n;
    const li = document.createElement("li");
    li.className = e.level; li.textContent = `[${e.t.toFixed(1)} s] ${e.text}`;
    list.appendChild(li);
    while (list.children.length > 300) list.firstChild.remove();
    list.scrollTop = list.scrollHeight;
  }
}

function drawTargets() {
  const sel = $("target");
  const ids = view.robots.filter((r) => !r.lost).map((r) => String(r.id));
  const have = [...sel.options].slice(1).map((o) => o.value);
  if (have.join() === ids.join()) return;
  const keep = sel.value;
  while (sel.options.length > 1) sel.remove(1);
  for (const id of ids) { const o = document.createElement("option"); o.value = id; o.textContent = `robot ${id}`; sel.appendChild(o); }
  sel.value = ids.includes(keep) ? keep : "";
}

function esc(s) { return String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]); }

async function send(code, params) {
  const to = $("target").value === "" ? null : Number($("target").value);
  $("error").textContent = "";
  try {
    const r = await fetch("/api/command", {
      method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ code, params, to }),
    });
    const answer = await r.json();
    if (!r.ok) $("error").textContent = `not sent: ${answer.error}`;
  } catch (e) {
    $("error").textContent = `not sent: the ground station does not answer (${e})`;
  }
}

function confirmThen(text, action) {
  $("modal-text").textContent = text;
  $("modal").hidden = false;
  $("modal-yes").onclick = () => { $("modal").hidden = true; action(); };
  $("modal-no").onclick = () => { $("modal").hidden = true; };
}

for (const b of document.querySelectorAll("#controls button")) {
  b.addEventListener("click", () => {
    const code = Number(b.dataset.code);
    if (b.dataset.danger) {
      const who = $("target").value === "" ? "every robot" : `robot ${$("target").value}`;
      confirmThen(`${b.dataset.danger}: ${who}?`, () => send(code, []));
    } else {
      send(code, []);
    }
  });
}

$("wp").addEventListener("submit", (ev) => {
  ev.preventDefault();
  send(16, [Number($("wp-id").value), Number($("wp-lat").value), Number($("wp-lon").value), Number($("wp-alt").value)]);
});

$("plot").addEventListener("click", (ev) => {
  if (!transform || !view || !view.origin) return;
  const rect = $("plot").getBoundingClientRect();
  const cx = (ev.clientX - rect.left) * ($("plot").width / rect.width);
  const cy = (ev.clientY - rect.top) * ($("plot").height / rect.height);
  const east = transform.x0 + (cx - transform.ox) / transform.s;
  const north = transform.y0 + (transform.h - transform.oy - cy) / transform.s;
  const [lat0, lon0] = view.origin;
  $("wp-lat").value = (lat0 + north / 111320).toFixed(7);
  $("wp-lon").value = (lon0 + east / (111320 * Math.cos((lat0 * Math.PI) / 180))).toFixed(7);
});

connect();
