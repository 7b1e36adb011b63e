// The station page: live views, overlays, clicks to a 3D target, go and stop.
// Plain JavaScript, no build step. Everything it shows comes from the server's JSON: the
// cameras (any number) and the target kind are data, so one page serves every rig.
"use strict";

const VIEW_WIDTH_PX = 640;
const ZOOM_PX = 160;
const MAX_FPS = 20;  // per camera: the views need no more, the camera's time goes to measuring
const COLORS = { predicted: "#4cc3ff", measured: "#5fd38d", target: "#ff5fd2",
  limits: "rgba(230, 200, 76, 0.55)", epipolar: "#ff9f43", click: "#ffffff",
  feature: "#5fd38d", online: "#ff9f43" };

const station = {
  layout: null, role: "watch", views: {}, overlays: {}, state: null,
  clicks: {}, std: {}, first: null, curves: {}, target: null, frames: {}, runRefusal: "",
};
window.microcal = station;  // for tests and the benchmark: frame counts, layout, target

const $ = (id) => document.getElementById(id);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const fmt = (v, d = 2) => (v == null ? "-" : v.map((x) => x.toFixed(d)).join(", "));

async function api(path, body) {
  const init = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) };
  const r = await fetch(path, init);
  const data = await r.json().catch(() => ({ error: `${r.status} ${r.statusText}` }));
  if (!r.ok) throw new Error(data.error || `${r.status}`);
  return data;
}

function say(text) { $("error").textContent = text || ""; }

// full-resolution pixel (origin at the centre of the top-left pixel) <-> canvas pixel
const scaleOf = (v) => v.canvas.width / v.cam.width_px;
const toCanvas = (v, q) => [(q[0] + 0.5) * scaleOf(v), (q[1] + 0.5) * scaleOf(v)];

function buildViews() {
  const tpl = $("view-template");
  for (const cam of station.layout.cameras) {
    const node = tpl.content.firstElementChild.cloneNode(true);
    node.dataset.camera = cam.name;
    node.querySelector(".name").textContent = cam.name;
    node.querySelector(".size").textContent = `${cam.width_px} x ${cam.height_px} px`;
    const canvas = node.querySelector("canvas.live");
    canvas.dataset.camera = cam.name;
    canvas.width = VIEW_WIDTH_PX;
    canvas.height = Math.round(cam.height_px * VIEW_WIDTH_PX / cam.width_px);
    const v = { cam, node, canvas, ctx: canvas.getContext("2d"), bitmap: null, count: 0,
      fps: 0, error: "", zoom: node.querySelector("canvas.zoom") };
    canvas.addEventListener("click", (e) => onClick(v, e));
    v.zoom.addEventListener("click", (e) => onZoomClick(v, e));
    station.views[cam.name] = v;
    station.frames[cam.name] = 0;
    $("views").appendChild(node);
  }
}

function ellipse(ctx, v, e, color, label, row = 0) {
  const s = scaleOf(v);
  const [x, y] = toCanvas(v, [e.x, e.y]);
  ctx.strokeStyle = color; ctx.lineWidth = 1.5;
  ctx.beginPath();
  ctx.ellipse(x, y, Math.max(e.a * s, 0.5), Math.max(e.b * s, 0.5), e.angle, 0, 2 * Math.PI);
  ctx.stroke();
  ctx.beginPath(); ctx.moveTo(x - 7, y); ctx.lineTo(x + 7, y); ctx.moveTo(x, y - 7);
  ctx.lineTo(x, y + 7); ctx.stroke();
  if (label) { ctx.fillStyle = color; ctx.font = "12px sans-serif"; ctx.fillText(label, x + 10, y - 6 + 14 * row); }
}

function polyline(ctx, v, pts, color, dash) {
  if (!pts || pts.length < 2) return;
  ctx.strokeStyle = color; ctx.lineWidth = 1.2; ctx.setLineDash(dash || []);
  ctx.beginPath();
  pts.forEach((q, i) => { const [x, y] = toCanvas(v, q); i ? ctx.lineTo(x, y) : ctx.moveTo(x, y); });
  ctx.stroke(); ctx.setLineDash([]);
}

function draw(v) {
  const { ctx, canvas } = v;
  if (v.bitmap) ctx.drawImage(v.bitmap, 0, 0, canvas.width, canvas.height);
  const o = station.overlays[v.cam.name] || {};
  for (const edge of o.limits || []) polyline(ctx, v, edge, COLORS.limits);
  polyline(ctx, v, station.curves[v.cam.name], COLORS.epipolar, [6, 4]);
  if (o.predicted) ellipse(ctx, v, o.predicted, COLORS.predicted, "calibration");
  if (o.measured) ellipse(ctx, v, o.measured, COLORS.measured, "measured", 1);
  if (o.target && station.target) ellipse(ctx, v, o.target, COLORS.target, "target", 2);
  const c = station.clicks[v.cam.name];
  if (c) {
    const [x, y] = toCanvas(v, c);
    ctx.strokeStyle = COLORS.click; ctx.lineWidth = 1.5;
    ctx.beginPath(); ctx.arc(x, y, 5, 0, 2 * Math.PI); ctx.stroke();
  }
  const snap = station.target && (station.target.snapped || {})[v.cam.name];
  if (snap && snap.how !== "click") {  // where the click was taken to be: a diamond
    const [x, y] = toCanvas(v, snap.q_px);
    const color = snap.how === "feature" ? COLORS.feature : COLORS.online;
    ctx.strokeStyle = color; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(x, y - 7); ctx.lineTo(x + 7, y); ctx.lineTo(x, y + 7); ctx.lineTo(x - 7, y);
    ctx.closePath(); ctx.stroke();
    ctx.fillStyle = color; ctx.font = "12px sans-serif"; ctx.textAlign = "right";
    ctx.fillText(snap.how === "feature" ? "target found" : "on the line", x - 10, y + 18);
    ctx.textAlign = "left";
  }
}

// Two requests in flight per camera: the server prepares the next frame while the browser
// decodes this one; a frame older than the one shown is dropped.
async function frameLoop(v, lane) {
  const url = `/api/frame/${encodeURIComponent(v.cam.name)}?w=${VIEW_WIDTH_PX}`;
  const error = v.node.querySelector(".camera-error");
  for (;;) {
    const seq = (v.asked = (v.asked || 0) + 1);
    const started = performance.now();
    try {
      const r = await fetch(url, { cache: "no-store" });
      if (!r.ok) {
        const data = await r.json().catch(() => ({ error: `${r.status}` }));
        error.textContent = data.error;
        await sleep(500);
        continue;
      }
      const bitmap = await createImageBitmap(await r.blob());
      if (seq < (v.shown || 0)) { bitmap.close(); continue; }
      if (v.bitmap) v.bitmap.close();
      v.bitmap = bitmap;
      v.shown = seq;
      v.count += 1;
      station.frames[v.cam.name] += 1;
      error.textContent = "";
      draw(v);
      await sleep(Math.max(0, 2000 / MAX_FPS - (performance.now() - started)));  // two lanes
    } catch (err) {
      error.textContent = `no answer from the station (${err.message})`;
      await sleep(1000 + 100 * lane);
    }
  }
}

async function zoomLoop(v) {
  const ctx = v.zoom.getContext("2d");
  for (;;) {
    await sleep(500);
    const o = station.overlays[v.cam.name] || {};
    const click = station.clicks[v.cam.name];
    const centre = click || (o.predicted && [o.predicted.x, o.predicted.y]);
    if (!centre) continue;
    v.node.querySelector(".zoom-what").textContent = click ? "the click" : "the tip the calibration predicts";
    try {
      const r = await fetch(`/api/zoom/${encodeURIComponent(v.cam.name)}?x=${Math.round(centre[0])}` +
        `&y=${Math.round(centre[1])}&size=${ZOOM_PX}`, { cache: "no-store" });
      if (r.ok) {
        ctx.drawImage(await createImageBitmap(await r.blob()), 0, 0, ZOOM_PX, ZOOM_PX);
        const corner = (c, size) => Math.min(Math.max(Math.round(c) - ZOOM_PX / 2, 0), Math.max(size - ZOOM_PX, 0));
        v.zoomCorner = [corner(centre[0], v.cam.width_px), corner(centre[1], v.cam.height_px)];
      }
    } catch (err) { /* the live view says it */ }
  }
}

function showRole(role) {
  station.role = role;
  const badge = $("role");
  badge.className = `badge ${role}`;
  badge.textContent = role === "control" ? "this browser controls" : "watching: another browser controls";
  for (const id of ["go", "measure", "clear", "run-start", "run-cancel", "run-resume", "focal-set"]) {
    if (role !== "control") $(id).disabled = true;
  }
  if (role === "control") {
    for (const id of ["measure", "clear", "run-start", "run-resume", "focal-set"]) $(id).disabled = false;
    updateGo();
  }
}

function updateGo() {
  const t = station.target;
  $("go").disabled = station.role !== "control" || !t || !!t.refusal ||
    (station.state && station.state.activity !== "idle");
}

// A click in a view (q in full-resolution px, its standard deviation std px). A first click
// draws its epipolar line in the other views; a click in another view gives the 3D target.
// With `refine` (a click in the zoom, at full resolution) it replaces that view's click.
async function clickAt(v, q, std, refine) {
  if (station.role !== "control") { say("this browser watches; another one controls the station"); return; }
  const name = v.cam.name;
  say("");
  try {
    const fresh = !station.first || (!refine && (station.first === name || station.clicks[name]));
    if (fresh || (refine && station.first === name && Object.keys(station.clicks).length === 1)) {
      station.first = name; station.clicks = { [name]: q }; station.std = { [name]: std };
      station.target = null;
      $("target-text").textContent = `clicked in ${name}; now click on the epipolar line in another view`;
      $("refusal").textContent = ""; $("snap-text").textContent = "";
    } else {
      station.clicks[name] = q; station.std[name] = std;
    }
    if (oneCamera()) {
      await askTarget();
    } else {
      if (station.first === name) {
        station.curves = (await api("/api/epipolar", { camera: name, x_px: station.clicks[name][0],
          y_px: station.clicks[name][1] })).curves;
      }
      if (Object.keys(station.clicks).length >= 2) await askTarget();
    }
  } catch (err) { say(err.message); }
  updateGo();
  for (const w of Object.values(station.views)) draw(w);
}

const oneCamera = () => station.layout && station.layout.click_to_target === "focal plane";

// The target of the clicks: the server takes a second view's click onto the first's epipolar
// line (or onto the target found along it) and says which; one camera: the focal plane.
async function askTarget() {
  const body = { clicks: station.clicks, std_px: station.std, first: station.first };
  if (oneCamera()) body.offset_um = parseFloat($("offset").value) || 0;
  const t = await api("/api/target", body);
  station.target = t;
  $("target-text").textContent = `x, y, z = ${fmt(t.target_um, 1)} µm (± ${fmt(t.std_um, 1)})`;
  $("refusal").textContent = t.refusal ? `refused: ${t.refusal}` : "";
  const words = Object.entries(t.snapped || {}).map(([n, s]) => (s.how === "feature" ?
    `${n}: on the target found ${s.line_px.toFixed(1)} px from the line (the click moved ${s.moved_px.toFixed(1)} px)` :
    s.how === "line" ? `${n}: the click projected onto the line (moved ${s.moved_px.toFixed(1)} px; no target found near it)` :
    `${n}: the click as it is (the line does not cross this view)`));
  if (oneCamera()) words.push(`on the focal plane ${(parseFloat($("offset").value) || 0).toFixed(1)} µm along the axis`);
  $("snap-text").textContent = words.join("; ");
}

function showFocal(f) {
  if (!f) return;
  $("focal-text").textContent = `focal plane: ${f.depth_um.toFixed(1)} µm from the camera ` +
    `(± ${f.depth_std_um.toFixed(2)}), through ${f.source}`;
}

function onClick(v, e) {
  const r = v.canvas.getBoundingClientRect();
  const k = v.cam.width_px / r.width;
  // one displayed pixel holds k camera pixels: the click is anywhere in it
  clickAt(v, [(e.clientX - r.left) * k - 0.5, (e.clientY - r.top) * k - 0.5], 0.5 * k, false);
}

// The zoom shows camera pixels one to one from its corner (as the server cuts it).
function onZoomClick(v, e) {
  if (!v.zoomCorner) return;
  const r = v.zoom.getBoundingClientRect();
  const k = ZOOM_PX / r.width;
  const q = [v.zoomCorner[0] + (e.clientX - r.left) * k - 0.5, v.zoomCorner[1] + (e.clientY - r.top) * k - 0.5];
  clickAt(v, q, 0.5, true);
}

function showState(s) {
  station.state = s;
  $("activity").textContent = s.activity + (s.halted ? " (stopped)" : "");
  $("joints").textContent = fmt(s.joints_um, 1);
  $("predicted").textContent = `${fmt(s.predicted_um, 1)}`;
  $("measured").textContent = fmt(s.measured_um, 2);
  $("message").textContent = s.message;
  const errors = Object.entries(s.camera_errors).map(([n, m]) => (m.startsWith(`${n}:`) ? m : `${n}: ${m}`));
  const lines = [...new Set([s.error, ...errors].filter(Boolean))];
  if (lines.length) say(lines.join("; "));
  for (const [n, value] of Object.entries(s.sharpness)) {
    const v = station.views[n];
    if (v) v.node.querySelector(".sharpness").value = value;
  }
  const a = s.arrival;
  if (a) {
    let text = `${a.mode} loop, ${a.status}: measured ${fmt(a.measured_um, 2)} µm, residual ` +
      `${a.residual_um.toFixed(2)} µm after ${a.iterations} corrections in ${a.took_s.toFixed(1)} s`;
    if (a.truth_error_um != null) text += `; by truth ${a.truth_error_um.toFixed(2)} µm from the target`;
    $("arrival").textContent = text;
    $("arrival").className = "";
  }
  showRun(s.run);
  if (s.focal_plane) showFocal(s.focal_plane);
  if (s.health && (s.health.checks || []).length !== ((station.layout.health || {}).checks || []).length) {
    station.layout.health = { ...s.health, report: station.layout.health.report };
    showHealth(station.layout.health);
  }
  if (s.role !== station.role) showRole(s.role);
  if (s.role === "watch" && !s.controlled) {  // the controller went away: take over
    api("/api/claim", {}).then((c) => showRole(c.role)).catch(() => {});
  }
  updateGo();
}

async function pollLoop() {
  let n = 0;
  for (;;) {
    try {
      showState(await api("/api/state"));
      if (n % 2 === 0) station.overlays = await api("/api/overlays");
    } catch (err) { say(`no answer from the station (${err.message})`); }
    n += 1;
    await sleep(250);
  }
}

function fpsLoop() {
  setInterval(() => {
    for (const v of Object.values(station.views)) {
      v.fps = v.count; v.count = 0;
      v.node.querySelector(".fps").textContent = `${v.fps} frames/s`;
    }
  }, 1000);
}

// A run of the page (camera calibration, acquisition, check): its bar, stage and end in words.
function showRun(r) {
  station.run = r;
  const running = !!r && r.status === "running";
  $("run-cancel").disabled = !running || station.role !== "control";
  $("run-start").disabled = running || station.role !== "control" ||
    (station.state && station.state.activity !== "idle");
  if (!r) return;
  const bar = $("run-bar");
  bar.hidden = false;
  bar.max = Math.max(r.total, 1); bar.value = r.done;
  const what = { acquire: "acquisition", check: "check", cameras: "cameras' calibration" }[r.kind];
  const count = r.total ? ` ${r.done} / ${r.total}` : "";
  $("run-status").textContent = (running ? `${what}: running, ${r.stage}${count}` :
    `${what}: ${r.status}${count ? ` at${count}` : ""}`) + ` (${r.took_s.toFixed(0)} s)`;
  // a refused start stays in words until the next start: the last run's state comes after it
  $("run-message").textContent = station.runRefusal || r.message || "";
  $("run-message").className = station.runRefusal || r.status === "failed" ||
    r.status === "stopped" ? "failed" : r.status === "done" ? "done" : "";
  const resumable = r.kind === "acquire" && !running && !!r.resume;
  $("run-resume").hidden = !resumable;
  $("run-resume").disabled = !resumable || station.role !== "control";
}

async function startRun(body) {
  say("");
  station.runRefusal = "";
  try { await api("/api/run", body); } catch (err) {
    station.runRefusal = err.message;
    $("run-message").textContent = err.message; $("run-message").className = "failed";
  }
}

// The calibration's health: when it was made, its checks as a plot of the offset (µm).
function showHealth(h) {
  if (!h) return;
  const rms = h.validation_rms_um != null ? `, validation RMS ${h.validation_rms_um.toFixed(2)} µm` : "";
  $("health-made").textContent = `made ${h.created || "(date unknown)"}${rms}`;
  $("health-report").hidden = !h.report;
  const checks = h.checks || [];
  if (h.history_error) { $("health-check").textContent = h.history_error; $("health-check").className = "bad"; }
  if (!checks.length) return;
  const last = checks[checks.length - 1];
  $("health-check").textContent = `${checks.length} check(s); last: ${last.verdict}` +
    (last.created ? ` on ${last.created}` : "") + (last.flag ? " (flagged)" : "");
  $("health-check").className = last.verdict === "valid" ? "good" : "bad";
  const canvas = $("health-plot"), ctx = canvas.getContext("2d");
  const size = checks.map((c) => Math.hypot(...(c.offset_um || [0, 0, 0])));
  const top = Math.max(...size, 1e-9) * 1.15;
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#9aa3ad"; ctx.font = "10px sans-serif"; ctx.fillText(`offset, max ${top.toFixed(2)} µm`, 4, 10);
  size.forEach((v, i) => {
    const x = 8 + (canvas.width - 16) * (checks.length > 1 ? i / (checks.length - 1) : 0.5);
    const y = canvas.height - 6 - (canvas.height - 20) * v / top;
    ctx.fillStyle = checks[i].verdict === "valid" ? "#5fd38d" : "#ff6b6b";
    ctx.beginPath(); ctx.arc(x, y, 3, 0, 2 * Math.PI); ctx.fill();
  });
}

async function main() {
  $("offset").addEventListener("change", async () => {
    if (station.role === "control" && Object.keys(station.clicks).length === 1 && oneCamera()) {
      try { await askTarget(); } catch (err) { say(err.message); }
      updateGo();
    }
  });
  $("focal-set").addEventListener("click", async () => {
    try {
      showFocal(await api("/api/focal-plane", {}));
      if (Object.keys(station.clicks).length === 1) await askTarget();
    } catch (err) { say(err.message); }
    updateGo();
  });
  $("stop").addEventListener("click", async () => {
    try { await api("/api/stop", {}); $("message").textContent = "stop sent"; } catch (err) { say(err.message); }
  });
  $("go").addEventListener("click", async () => {
    const t = station.target;
    if (!t) return;
    say("");
    $("arrival").textContent = "moving ..."; $("arrival").className = "muted";
    try {
      await api("/api/go", { target_um: t.target_um, mode: $("mode").value,
        tolerance_um: parseFloat($("tolerance").value) });
    } catch (err) { say(err.message); $("arrival").textContent = "-"; }
  });
  $("measure").addEventListener("click", async () => {
    try { await api("/api/measure", {}); } catch (err) { say(err.message); }
  });
  $("run-start").addEventListener("click", () => {
    const kind = $("run-kind").value, name = $("run-name").value.trim();
    const body = { kind };
    if (name) body.name = name;
    if (kind === "acquire") body.poses = parseInt($("run-poses").value, 10);
    const frames = $("run-frames").value.trim();
    if (frames) body.frames = parseInt(frames, 10);
    startRun(body);
  });
  $("run-cancel").addEventListener("click", async () => {
    try { await api("/api/run/cancel", {}); } catch (err) { say(err.message); }
  });
  $("run-resume").addEventListener("click", () => {
    const r = station.run;
    if (r && r.out) startRun({ kind: "acquire", name: r.out.split("/").pop(), resume: true });
  });
  const posesFor = () => { $("run-poses").disabled = $("run-kind").value !== "acquire"; };
  $("run-kind").addEventListener("change", posesFor);
  posesFor();
  $("clear").addEventListener("click", () => {
    station.clicks = {}; station.std = {}; station.first = null; station.curves = {}; station.target = null;
    $("target-text").textContent = "no target: click in a view"; $("refusal").textContent = "";
    $("snap-text").textContent = "";
    updateGo();
  });
  try {
    station.layout = await api("/api/layout");
  } catch (err) { say(err.message); return; }
  $("rig").textContent = `${station.layout.rig}; ${station.layout.manipulator}, target ` +
    `${station.layout.target.spec}`;
  if (oneCamera()) {
    $("hint").textContent = "One camera: click where the tip should go; the target lies on the " +
      "camera's focal plane, moved by the offset along its axis.";
    $("focal").hidden = false;
    showFocal(station.layout.focal_plane);
  }
  buildViews();
  showHealth(station.layout.health);
  const claim = await api("/api/claim", {}).catch((err) => { say(err.message); return { role: "watch" }; });
  showRole(claim.role);
  fpsLoop();
  pollLoop();
  for (const v of Object.values(station.views)) { frameLoop(v, 0); frameLoop(v, 1); zoomLoop(v); }
}

main();
