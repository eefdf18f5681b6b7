// NeuVision dashboard: draws the frames the server sends on /ws (dashboard/server.py).
// No framework and no build step: canvas 2-D drawing, one file. The server sends a "scene"
// (arena, body, culture layout) when it changes and a "frame" about 30 times a second with
// the newest values and what is new in each stream since this page's last frame.
"use strict";

const RASTER_S = 3.0;       // seconds of run time on the raster
const RATES_S = 20.0;       // ... on the rates plot
const CA_PATH_S = 3.0;      // the Center of Activity's recent path
const TRACE_MAX = 20000;    // frames remembered for window.nv.trace (tests, lag)

const $ = (id) => document.getElementById(id);
const nv = {
  scene: null, source: {}, status: {}, endpoints: {}, replay: null,
  step: -1, t_s: 0, pose: null, ranges: null, contact: false, motor: null,
  trail: [], spikes: [], pulses: [], rates: [], ca: [], bursts: [],
  activity: null, lit: [], sceneVersion: 0,
  notShownBeforeMs: null,  // spikes before this run time were left out of a frame
  stats: {
    received: 0, drawn: 0, fps: 0, drawFps: 0, resets: 0, connected: false, serverDropped: 0,
    rasterSpikes: 0,
    takeMs: 0,  // the page's time taking the server's messages (parsed and stored), in all
    drawMs: 0,  // ... and drawing frames, in all
  },
  trace: [],   // [step, page wall ms when drawn, x, y, run time s]
  dirty: false,
};
window.nv = nv;
const receivedAt = [];
const cpuSamples = [];
const drawnAt = [];

// ------------------------------------------------------------------ connection

let ws = null;
function connect() {
  ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  ws.onopen = () => { nv.stats.connected = true; document.body.classList.remove("stale"); message(""); };
  ws.onclose = () => {
    nv.stats.connected = false;
    const badge = $("source");
    badge.textContent = "dashboard not reachable (it ended with its run?) — retrying";
    badge.className = "badge down";
    // what the page shows is the last it heard, not the run's present: greyed, and said
    document.body.classList.add("stale");
    $("state").textContent = "unknown (no news since the dashboard went)";
    for (const id of ["btn-pause", "btn-resume", "btn-stop"]) $(id).disabled = true;
    setTimeout(connect, 1000);
  };
  ws.onmessage = (event) => {
    const t0 = performance.now();
    const m = JSON.parse(event.data);
    if (m.type === "scene") setScene(m.scene);
    else if (m.type === "frame") takeFrame(m);
    else if (m.type === "reply") showReply(m);
    nv.stats.takeMs += performance.now() - t0;
  };
}

function send(obj) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(obj));
}

function message(text, bad) {
  const el = $("message");
  el.textContent = text;
  el.className = "message" + (bad ? " bad" : "");
}

function showReply(m) {
  if (m.ok) message(`${m.cmd}: done${m.state ? " (" + m.state + ")" : ""}`);
  else message(`${m.cmd}: ${m.reason}`, true);
}

// ------------------------------------------------------------------ data

function setScene(scene) {
  nv.scene = scene;
  nv.sceneVersion += 1;
  $("name").textContent = scene && scene.name ? "· " + scene.name : "";
  nv.dirty = true;
}

function takeFrame(f) {
  const now = performance.now();
  nv.stats.received += 1;
  receivedAt.push(now);
  while (receivedAt.length && receivedAt[0] < now - 2000) receivedAt.shift();
  if (f.reset) {
    nv.trail = []; nv.spikes = []; nv.pulses = []; nv.rates = []; nv.ca = []; nv.bursts = [];
    nv.notShownBeforeMs = null;
    nv.stats.resets += 1;
  }
  // more spikes than a frame carries: the older ones were left out, not silent
  if (f.spikes.capped_before_ms !== undefined) nv.notShownBeforeMs = f.spikes.capped_before_ms;
  nv.source = f.source || {};
  nv.observer = f.observer || {};
  nv.status = f.status || {};
  nv.endpoints = f.endpoints || {};
  nv.replay = f.replay || null;
  nv.step = f.step; nv.t_s = f.t_s;
  nv.pose = f.pose; nv.ranges = f.ranges; nv.contact = f.contact; nv.motor = f.motor;
  for (const p of f.trail) nv.trail.push(p);
  if (f.spikes.n) nv.spikes.push(chunk(f.spikes));
  if (f.pulses.n) nv.pulses.push(chunk(f.pulses));
  for (const r of f.rates) nv.rates.push(r);
  for (const c of f.ca) nv.ca.push(c);
  for (const b of f.bursts) nv.bursts.push(b);
  const tMs = f.t_s * 1000;
  trimBefore(nv.spikes, tMs - RASTER_S * 1000, (c) => c.last);
  trimBefore(nv.pulses, tMs - RASTER_S * 1000, (c) => c.last);
  nv.stats.rasterSpikes = nv.spikes.reduce((n, c) => n + c.t.length, 0);
  trimBefore(nv.rates, f.t_s - RATES_S, (r) => r[0]);
  trimBefore(nv.ca, f.t_s - CA_PATH_S, (c) => c[0]);
  trimBefore(nv.bursts, tMs - RATES_S * 1000, (b) => b[1]);
  nv.activity = f.activity ? bytes(f.activity) : null;
  nv.lit = f.lit || [];
  nv.stats.serverDropped = f.server ? f.server.dropped : 0;
  if (f.server) {  // the dashboard process's CPU share over the last few seconds
    cpuSamples.push([f.server.wall_ms, f.server.cpu_s]);
    while (cpuSamples.length > 2 && cpuSamples[0][0] < f.server.wall_ms - 3000) cpuSamples.shift();
    const [w0, c0] = cpuSamples[0], [w1, c1] = cpuSamples[cpuSamples.length - 1];
    nv.stats.serverCpu = w1 > w0 ? (c1 - c0) / ((w1 - w0) / 1000) : 0;
  }
  nv.dirty = true;
}

// A loop over the characters: Uint8Array.from(text, mapping) took 20 times as long
// (3.6 against 0.17 ms for 30 kB in Chromium), a frame's spikes being ~40 kB.
function bytes(b64) {
  const text = atob(b64), n = text.length, out = new Uint8Array(n);
  for (let k = 0; k < n; k++) out[k] = text.charCodeAt(k);
  return out;
}

// A stream's events (server: FrameState._events): times in ms (t0 + float32 offsets) and
// channel indices (2 or 4 bytes each: e.i_bytes), as typed arrays; `last` is the newest
// time, for trimming.
function chunk(e) {
  const t = new Float32Array(bytes(e.t).buffer);
  const i = new (e.i_bytes === 2 ? Uint16Array : Uint32Array)(bytes(e.i).buffer);
  let last = -Infinity;
  for (let k = 0; k < t.length; k++) if (t[k] > last) last = t[k];
  return { t0: e.t0, t, i, last: e.t0 + last };
}

function trimBefore(list, limit, key) {
  let n = 0;
  while (n < list.length && key(list[n]) < limit) n++;
  if (n) list.splice(0, n);
}

// ------------------------------------------------------------------ drawing

function frameLoop() {
  if (nv.dirty) {
    nv.dirty = false;
    const t0 = performance.now();
    drawAll();
    const now = performance.now();
    nv.stats.drawMs += now - t0;
    nv.stats.drawn += 1;
    drawnAt.push(now);
    while (drawnAt.length && drawnAt[0] < now - 2000) drawnAt.shift();
    if (nv.pose) {
      nv.trace.push([nv.step, Date.now(), nv.pose[0], nv.pose[1], nv.t_s]);
      if (nv.trace.length > TRACE_MAX) nv.trace.splice(0, nv.trace.length - TRACE_MAX);
    }
  }
  nv.stats.fps = rate(receivedAt);
  nv.stats.drawFps = rate(drawnAt);
  requestAnimationFrame(frameLoop);
}

function rate(times) {
  if (times.length < 2) return 0;
  return (times.length - 1) / ((times[times.length - 1] - times[0]) / 1000);
}

function drawAll() {
  drawHeader();
  drawArena();
  drawCulture();
  drawRaster();
  drawRates();
  drawLoopPanel();
  drawEndpoints();
  $("fps").textContent =
    `${nv.stats.fps.toFixed(1)} frames/s received, ${nv.stats.drawFps.toFixed(1)} drawn; ` +
    `frames the server skipped for this page: ${nv.stats.serverDropped}; ` +
    `the dashboard's process: ${fmt(100 * (nv.stats.serverCpu || 0), 0)} % of a core`;
}

function fmt(x, digits) {
  return x === null || x === undefined || Number.isNaN(x) ? "—" : Number(x).toFixed(digits);
}

function drawHeader() {
  const src = nv.source, st = nv.status, badge = $("source");
  if (src.kind === "live") {
    const obs = nv.observer || {};
    const where = obs.hub_alive ? `hub ${src.hub}`
      : obs.connected || !obs.reason ? `waiting for a hub at ${src.hub}`
      : `waiting for a hub at ${src.hub}: ${obs.reason}`;
    const bad = Object.values(obs.dropped || {}).reduce((a, b) => a + b, 0);
    // a link to the hub that went silent, left and joined again (docs/dashboard.md)
    const rejoined = obs.rejoins ? ` · joined again ${obs.rejoins}×` : "";
    badge.textContent = `live · session ${src.session} · ${where}` + (bad ? ` · ${bad} bad messages` : "") + rejoined;
    badge.className = "badge live";
  } else if (src.kind === "replay") {
    badge.textContent = `replay · ${src.run_dir}`;
    badge.className = "badge replay";
  }
  // a stop takes effect after the current step: the hub says why meanwhile
  const stopping = !!(st.extra && st.extra.stop_reason) && st.state !== "stopped";
  // the final status says how the run ended: completed, stopped, interrupted or fault
  const ended = st.state === "stopped" && st.extra && st.extra.outcome;
  const why = ended && st.extra.reason ? ` (${st.extra.reason})` : "";
  $("state").textContent = stopping ? `stopping (${st.extra.stop_reason})`
    : ended ? `ended: ${st.extra.outcome}${why.length > 90 ? why.slice(0, 88) + "…)" : why}`
    : st.state || (src.kind === "live" ? "waiting for the hub" : "—");
  $("state").title = ended ? `${st.extra.outcome}${why}` : "";
  $("step").textContent = nv.step >= 0 ? nv.step : "—";
  const n = (st.extra && st.extra.n_steps) || (nv.scene && nv.scene.n_steps);
  $("n-steps").textContent = n ? ` / ${n}` : "";
  $("t").textContent = fmt(nv.t_s, 2);
  const live = src.kind === "live", replay = src.kind === "replay";
  $("live-controls").hidden = !live;
  $("replay-controls").hidden = !replay;
  if (live) {
    const may = src.controls !== false;  // an observer's certificate: read-only
    $("btn-pause").disabled = !may || stopping || st.state !== "running";
    $("btn-resume").disabled = !may || stopping || st.state !== "paused";
    $("btn-stop").disabled = !may || stopping || !["running", "paused", "waiting"].includes(st.state);
    $("live-controls").title = may ? "" : "read-only: this dashboard has an observer's certificate";
  }
  if (replay && nv.replay) {
    const r = nv.replay;
    $("btn-play").textContent = r.playing ? "Pause" : "Play";
    const speed = $("speed");
    if (speed.dataset.speeds !== String(r.speeds)) {
      speed.dataset.speeds = String(r.speeds);
      speed.innerHTML = r.speeds.map((x) => `<option value="${x}">${x}×</option>`).join("");
    }
    if (document.activeElement !== speed) speed.value = String(r.speed);
    const slider = $("slider");
    slider.max = r.duration_s;
    if (!sliding) slider.value = r.t_s;
    $("replay-time").textContent = `${fmt(sliding ? slider.value : r.t_s, 2)} / ${fmt(r.duration_s, 2)} s`;
  }
}

// A canvas sized to its element on screen (crisp on any display); returns its 2-D context.
function canvas2d(id) {
  const c = $(id);
  const ratio = window.devicePixelRatio || 1;
  const w = Math.round(c.clientWidth * ratio), h = Math.round(c.clientHeight * ratio);
  if (w > 0 && h > 0 && (c.width !== w || c.height !== h)) { c.width = w; c.height = h; }
  const ctx = c.getContext("2d");
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, c.width, c.height);
  return [ctx, c.width, c.height, ratio];
}

// world (m) -> canvas pixels, y up, fitting [xmin, xmax] x [ymin, ymax] with a margin
function fitter(bounds, w, h, margin) {
  const [x0, x1, y0, y1] = bounds;
  const s = Math.min((w - 2 * margin) / (x1 - x0), (h - 2 * margin) / (y1 - y0));
  const ox = (w - s * (x1 - x0)) / 2, oy = (h - s * (y1 - y0)) / 2;
  return { s, x: (x) => ox + (x - x0) * s, y: (y) => h - oy - (y - y0) * s };
}

function arenaBounds() {
  const a = nv.scene && nv.scene.arena;
  if (a && a.shape === "circle") return [-a.radius_m, a.radius_m, -a.radius_m, a.radius_m];
  if (a) return [-a.width_m / 2, a.width_m / 2, -a.height_m / 2, a.height_m / 2];
  // no world known: fit the trail, at least half a metre across
  let b = [Infinity, -Infinity, Infinity, -Infinity];
  for (const p of nv.trail.concat(nv.pose ? [nv.pose] : [])) {
    b = [Math.min(b[0], p[0]), Math.max(b[1], p[0]), Math.min(b[2], p[1]), Math.max(b[3], p[1])];
  }
  if (!Number.isFinite(b[0])) return [-0.5, 0.5, -0.5, 0.5];
  const cx = (b[0] + b[1]) / 2, cy = (b[2] + b[3]) / 2;
  const half = Math.max(b[1] - b[0], b[3] - b[2], 0.5) / 2 + 0.05;
  return [cx - half, cx + half, cy - half, cy + half];
}

function drawArena() {
  const [ctx, w, h, ratio] = canvas2d("arena");
  const scene = nv.scene || {};
  const f = fitter(arenaBounds(), w, h, 12 * ratio);
  const a = scene.arena;
  ctx.lineWidth = 2 * ratio;
  ctx.strokeStyle = "#333";
  if (a && a.shape === "circle") {
    ctx.beginPath(); ctx.arc(f.x(0), f.y(0), a.radius_m * f.s, 0, 2 * Math.PI); ctx.stroke();
  } else if (a) {
    ctx.strokeRect(f.x(-a.width_m / 2), f.y(a.height_m / 2), a.width_m * f.s, a.height_m * f.s);
  }
  ctx.fillStyle = "#b9bec6"; ctx.strokeStyle = "#7d848e"; ctx.lineWidth = ratio;
  for (const ob of scene.obstacles || []) {
    ctx.beginPath();
    if (ob.shape === "circle") ctx.arc(f.x(ob.center_m[0]), f.y(ob.center_m[1]), ob.radius_m * f.s, 0, 2 * Math.PI);
    else ob.vertices_m.forEach((v, k) => (k ? ctx.lineTo(f.x(v[0]), f.y(v[1])) : ctx.moveTo(f.x(v[0]), f.y(v[1]))));
    ctx.closePath(); ctx.fill(); ctx.stroke();
  }
  $("arena-note").textContent = a ? "" : "the run's world is not known here: drawn around the trail";
  // trail
  if (nv.trail.length > 1) {
    ctx.strokeStyle = "rgba(31, 119, 180, 0.55)"; ctx.lineWidth = 1.5 * ratio;
    ctx.beginPath();
    nv.trail.forEach((p, k) => (k ? ctx.lineTo(f.x(p[0]), f.y(p[1])) : ctx.moveTo(f.x(p[0]), f.y(p[1]))));
    if (nv.pose) ctx.lineTo(f.x(nv.pose[0]), f.y(nv.pose[1]));
    ctx.stroke();
  }
  const body = scene.body;
  if (!nv.pose) return;
  const [x, y, th] = nv.pose;
  const radius = body ? body.radius_m : 0.035;
  // range finders
  if (body && nv.ranges) {
    const c = Math.cos(th), s = Math.sin(th);
    body.sensor_angles_rad.forEach((ang, k) => {
      const off = body.sensor_offsets_m[k];
      const ox = x + c * off[0] - s * off[1], oy = y + s * off[0] + c * off[1];
      const r = nv.ranges[k], hit = r < body.max_range_m - 1e-9;
      ctx.strokeStyle = hit ? "#d62728" : "rgba(214, 39, 40, 0.35)";
      ctx.lineWidth = (hit ? 1.6 : 1) * ratio;
      ctx.setLineDash(hit ? [] : [3 * ratio, 3 * ratio]);
      ctx.beginPath();
      ctx.moveTo(f.x(ox), f.y(oy));
      ctx.lineTo(f.x(ox + r * Math.cos(th + ang)), f.y(oy + r * Math.sin(th + ang)));
      ctx.stroke();
    });
    ctx.setLineDash([]);
  }
  // the robot
  ctx.fillStyle = nv.contact ? "#f6c6c6" : "#ffffff";
  ctx.strokeStyle = "#1f77b4"; ctx.lineWidth = 2 * ratio;
  ctx.beginPath(); ctx.arc(f.x(x), f.y(y), Math.max(radius * f.s, 3 * ratio), 0, 2 * Math.PI);
  ctx.fill(); ctx.stroke();
  ctx.beginPath(); ctx.moveTo(f.x(x), f.y(y));
  ctx.lineTo(f.x(x + radius * Math.cos(th)), f.y(y + radius * Math.sin(th))); ctx.stroke();
}

function heat(level) {  // 0-255 -> dark grey, red, orange, yellow, white
  const t = level / 255;
  const r = Math.round(60 + 195 * Math.min(1, t * 2));
  const g = Math.round(60 + 195 * Math.max(0, Math.min(1, t * 2 - 0.6)));
  const b = Math.round(60 + 195 * Math.max(0, t * 3 - 2));
  return `rgb(${r},${g},${b})`;
}
const HEAT = Array.from({ length: 256 }, (_, level) => heat(level));  // its 256 styles

function drawCulture() {
  const [ctx, w, h, ratio] = canvas2d("culture");
  const cul = nv.scene && nv.scene.culture;
  if (!cul) { $("culture-note").textContent = "waiting for the culture's description"; return; }
  const xs = cul.x_um, ys = cul.y_um, n = xs.length;
  let b = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const span = Math.max(b[1] - b[0], b[3] - b[2], 1);
  b = [b[0] - span * 0.03, b[1] + span * 0.03, b[2] - span * 0.03, b[3] + span * 0.03];
  const f = fitter(b, w, h, 8 * ratio);
  const dot = Math.max(1.2 * ratio, Math.min(8 * ratio, 0.42 * f.s * span / Math.sqrt(n)));
  const act = nv.activity;
  for (let k = 0; k < n; k++) {
    ctx.fillStyle = HEAT[act ? act[k] : 0];
    const px = f.x(xs[k]), py = f.y(ys[k]);
    if (cul.cell_type && cul.cell_type[k] === 1) ctx.fillRect(px - dot * 0.8, py - dot * 0.8, dot * 1.6, dot * 1.6);
    else { ctx.beginPath(); ctx.arc(px, py, dot, 0, 2 * Math.PI); ctx.fill(); }
  }
  ctx.strokeStyle = "#17a34a"; ctx.lineWidth = 2 * ratio;
  for (const k of nv.lit) {
    ctx.beginPath(); ctx.arc(f.x(xs[k]), f.y(ys[k]), dot + 3 * ratio, 0, 2 * Math.PI); ctx.stroke();
  }
  if (nv.ca.length) {
    ctx.strokeStyle = "rgba(214, 51, 108, 0.6)"; ctx.lineWidth = 1.5 * ratio;
    ctx.beginPath();
    nv.ca.forEach((c, k) => (k ? ctx.lineTo(f.x(c[1]), f.y(c[2])) : ctx.moveTo(f.x(c[1]), f.y(c[2]))));
    ctx.stroke();
    const c = nv.ca[nv.ca.length - 1], r = 6 * ratio;
    ctx.strokeStyle = "#d6336c"; ctx.lineWidth = 3 * ratio;
    ctx.beginPath();
    ctx.moveTo(f.x(c[1]) - r, f.y(c[2])); ctx.lineTo(f.x(c[1]) + r, f.y(c[2]));
    ctx.moveTo(f.x(c[1]), f.y(c[2]) - r); ctx.lineTo(f.x(c[1]), f.y(c[2]) + r);
    ctx.stroke();
  }
  $("culture-note").textContent = `${n} channels (${cul.kind}); forward is up`;
}

function timeAxis(ctx, w, h, ratio, t0, t1, x, stepS) {
  ctx.fillStyle = "#6b7380"; ctx.strokeStyle = "#eceef1"; ctx.lineWidth = ratio;
  ctx.font = `${11 * ratio}px system-ui, sans-serif`;
  for (let t = Math.ceil(t0 / stepS) * stepS; t <= t1; t += stepS) {
    ctx.beginPath(); ctx.moveTo(x(t), 0); ctx.lineTo(x(t), h - 14 * ratio); ctx.stroke();
    ctx.fillText(`${t.toFixed(stepS < 1 ? 1 : 0)} s`, x(t) + 2 * ratio, h - 3 * ratio);
  }
}

// The raster's spikes and pulses are drawn once each, into a ring of columns: one per
// device pixel of the raster's width, a column's run time modulo RASTER_S, its pixels kept
// in an ImageData. A frame writes only what came since the last one (a few pixels a spike)
// and copies the ring onto the raster in two pieces; the ring is drawn again whole after a
// reset (a new run, a jump in a replay), a new scene or a new size. Drawing all of the last
// 3 s (~20,000 spikes) each frame took longer than a frame's period on a slow machine.
const ring = { canvas: document.createElement("canvas"), key: "", cleared: 0, image: null };
// excitatory and inhibitory spikes (the rates' curves too; the legend's are dashboard.css's)
const PULSE_RGBA = [23, 163, 74, 0.28], SPIKE_RGB = [[192, 57, 43], [46, 111, 216]];

function drawRaster() {
  const [ctx, w, h, ratio] = canvas2d("raster");
  const cul = nv.scene && nv.scene.culture;
  const t1 = nv.t_s, t0 = t1 - RASTER_S;
  const top = 12 * ratio, bottom = h - 16 * ratio;
  const x = (t) => ((t - t0) / RASTER_S) * w;
  timeAxis(ctx, w, h, ratio, t0, t1, x, 0.5);
  if (!cul || w < 2 || bottom <= top) return;
  const n = cul.channel.length, rowH = (bottom - top) / n;
  if (nv.notShownBeforeMs !== null && nv.notShownBeforeMs / 1000 > t0) {
    const e = x(nv.notShownBeforeMs / 1000);
    ctx.fillStyle = "rgba(107, 115, 128, 0.18)";
    ctx.fillRect(0, top, e, bottom - top);
    ctx.fillStyle = "#6b7380"; ctx.font = `${11 * ratio}px system-ui, sans-serif`;
    ctx.fillText("spikes not shown", 4 * ratio, top + 12 * ratio);
  }
  shadeBursts(ctx, x, top, bottom, w, ratio);
  ctx.fillStyle = "#e0a800"; ctx.font = `${11 * ratio}px system-ui, sans-serif`;
  for (const b of nv.bursts) {
    const m = x((b[3] + b[4]) / 2000);
    if (m >= 0 && m <= w) ctx.fillText("▼", m - 4 * ratio, top - 1 * ratio);
  }
  const rh = Math.ceil(bottom - top), head = updateRing(cul, w, rh, rowH, ratio);
  ctx.drawImage(ring.canvas, head, 0, w - head, rh, 0, top, w - head, rh);
  if (head > 0) ctx.drawImage(ring.canvas, 0, 0, head, rh, w - head, top, head, rh);
}

// Bring the ring up to nv.t_s; returns its oldest column (the newest is the one before it).
function updateRing(cul, w, rh, rowH, ratio) {
  const colMs = (RASTER_S * 1000) / w, now = Math.floor((nv.t_s * 1000) / colMs);
  const rc = ring.canvas.getContext("2d");
  const key = `${w}x${rh}:${cul.channel.length}:${nv.stats.resets}:${nv.sceneVersion}`;
  let dirtyFrom = now + 1;  // the columns written (absolute numbers), to copy to the canvas
  if (ring.key !== key) {  // start again: every spike and pulse kept is drawn anew
    ring.key = key;
    ring.canvas.width = w; ring.canvas.height = rh;
    ring.image = rc.createImageData(w, rh);
    ring.cleared = now;
    dirtyFrom = now - w + 1;
    for (const c of nv.spikes) c.drawn = false;
    for (const c of nv.pulses) c.drawn = false;
  } else if (now > ring.cleared) {  // the columns time entered since: their old contents go
    dirtyFrom = Math.max(ring.cleared + 1, now - w + 1);
    clearColumns(ring.image, dirtyFrom, now);
    ring.cleared = now;
  }
  const d = ring.image.data, oldest = now - w + 1;
  const dotW = Math.max(1, Math.round(1.2 * ratio)), least = Math.max(1, Math.round(ratio));
  const paint = (chunks, keep, rgba) => {
    const [r, g, b, a] = rgba;
    for (const c of chunks) {
      for (let k = 0; k < c.t.length; k++) {
        const col = Math.floor((c.t0 + c.t[k]) / colMs), i = c.i[k];
        if (col < oldest || col > now || !keep(i)) continue;
        if (col < dirtyFrom) dirtyFrom = col;
        const x0 = col % w, x1 = Math.min(x0 + Math.min(dotW, now - col + 1), w);
        const y0 = Math.floor(i * rowH);
        const y1 = Math.min(Math.max(Math.ceil((i + 1) * rowH), y0 + least), rh);
        for (let y = y0; y < y1; y++) {
          for (let x = x0; x < x1; x++) {
            const p = 4 * (y * w + x);
            if (a >= 1) { d[p] = r; d[p + 1] = g; d[p + 2] = b; d[p + 3] = 255; continue; }
            const under = d[p + 3] / 255, out = a + under * (1 - a);  // a over what is there
            d[p] = (r * a + d[p] * under * (1 - a)) / out;
            d[p + 1] = (g * a + d[p + 1] * under * (1 - a)) / out;
            d[p + 2] = (b * a + d[p + 2] * under * (1 - a)) / out;
            d[p + 3] = out * 255;
          }
        }
      }
    }
  };
  const pulses = nv.pulses.filter((c) => !c.drawn), spikes = nv.spikes.filter((c) => !c.drawn);
  const types = cul.cell_type, inhibitory = (i) => !!types && types[i] === 1;
  // pulses under the spikes, light: a closed loop stimulates its sites every step
  paint(pulses, () => true, PULSE_RGBA);
  paint(spikes, (i) => !inhibitory(i), [...SPIKE_RGB[0], 1]);
  paint(spikes, inhibitory, [...SPIKE_RGB[1], 1]);
  for (const c of pulses) c.drawn = true;
  for (const c of spikes) c.drawn = true;
  for (const [x, n] of ringSpans(dirtyFrom, now, w)) rc.putImageData(ring.image, 0, 0, x, 0, n, rh);
  return (now + 1) % w;
}

// The ring's columns [from, to] (absolute numbers) as at most two spans [x, width] of it.
function ringSpans(from, to, w) {
  const count = to - from + 1;
  if (count <= 0) return [];
  if (count >= w) return [[0, w]];
  const x = ((from % w) + w) % w;
  return x + count <= w ? [[x, count]] : [[x, w - x], [0, x + count - w]];
}

function clearColumns(image, from, to) {
  const d = image.data, w = image.width;
  for (const [x, n] of ringSpans(from, to, w)) {
    for (let y = 0; y < image.height; y++) d.fill(0, 4 * (y * w + x), 4 * (y * w + x + n));
  }
}

// Network bursts [start_ms, end_ms, n, core_start_ms, core_end_ms]: the extent (first to last
// participating spike) pale, the core (the threshold held) strong. In a closed loop a
// stimulated channel bursts for seconds and the extent with it (docs/analysis.md).
// A core is often a few ms: at least 3 px wide, so that it shows at any zoom.
function shadeBursts(ctx, x, top, bottom, w, ratio) {
  // Network bursts seen under way (the burst observer's early marks, docs/analysis.md):
  // hatched from their start to the last time they were seen under way (to now for the one
  // under way now), long before the complete ones are reported.
  const ex = nv.status.extra || {};
  const marks = (ex.recent_network_bursts_under_way || []).map((u) => [u[0], u[1]]);
  if (typeof ex.network_burst_under_way_ms === "number" && marks.length) {
    marks[marks.length - 1][1] = Math.max(marks[marks.length - 1][1], nv.t_s * 1000);
  }
  ctx.fillStyle = "rgba(224, 168, 0, 0.30)";
  for (const [from, to] of marks) {
    const a = Math.max(x(from / 1000), 0), e = Math.min(x(Math.max(to, from + 5) / 1000), w);
    for (let xi = a; xi < e; xi += 4 * ratio) ctx.fillRect(xi, top, 2 * ratio, bottom - top);
  }
  const shades = [[0, 1, "rgba(224, 168, 0, 0.10)", ratio], [3, 4, "rgba(224, 168, 0, 0.45)", 3 * ratio]];
  for (const [from, to, colour, least] of shades) {
    ctx.fillStyle = colour;
    for (const b of nv.bursts) {
      const a = x(b[from] / 1000), e = x(b[to] / 1000);
      if (e < 0 || a > w) continue;
      ctx.fillRect(a, top, Math.max(e - a, least), bottom - top);
    }
  }
}

function drawRates() {
  const [ctx, w, h, ratio] = canvas2d("rates");
  const t1 = Math.max(nv.t_s, RATES_S), t0 = t1 - RATES_S;
  const top = 8 * ratio, bottom = h - 16 * ratio, left = 40 * ratio;
  const x = (t) => left + ((t - t0) / RATES_S) * (w - left);
  timeAxis(ctx, w, h, ratio, t0, t1, x, 2);
  let peak = 5;
  for (const r of nv.rates) for (let k = 1; k < 4; k++) if (r[k] !== null && r[k] > peak) peak = r[k];
  const y = (v) => bottom - (v / peak) * (bottom - top);
  shadeBursts(ctx, x, top, bottom, w, ratio);
  ctx.fillStyle = "#6b7380"; ctx.font = `${11 * ratio}px system-ui, sans-serif`;
  ctx.fillText(`${peak.toFixed(0)} Hz`, 2 * ratio, top + 10 * ratio);
  ctx.fillText("0", 2 * ratio, bottom);
  const colours = [null, "#222", ...SPIKE_RGB.map((c) => `rgb(${c.join(",")})`)];
  for (let k = 1; k < 4; k++) {
    ctx.strokeStyle = colours[k]; ctx.lineWidth = 1.4 * ratio;
    ctx.beginPath();
    let prev = null;  // a gap in the bins (windows the page did not get) breaks the line
    for (const r of nv.rates) {
      if (r[k] === null) continue;
      if (prev !== null && r[0] - prev < 0.075) ctx.lineTo(x(r[0]), y(r[k]));
      else ctx.moveTo(x(r[0]), y(r[k]));
      prev = r[0];
    }
    ctx.stroke();
  }
}

function byRole(obj) {
  if (!obj || !Object.keys(obj).length) return "0";
  return Object.entries(obj).map(([k, v]) => `${k} ${typeof v === "object" ? JSON.stringify(v) : v}`).join(", ");
}

function drawLoopPanel() {
  const st = nv.status, ex = st.extra || {}, scene = nv.scene || {};
  const period = ex.period_ms || scene.period_ms;
  const rows = [
    ["mode", st.mode || scene.mode || "—"],
    ["period", period ? `${period} ms` : "—"],
  ];
  if (nv.source.kind === "replay") {
    const t = ex.timing || {};
    rows.push(["outcome", ex.outcome || "—"]);
    rows.push(["steps recorded", ex.n_steps ?? "—"]);
    rows.push(["x real time (run)", fmt(t.x_realtime, 1)]);
    rows.push(["late steps (run)", t.late_steps ?? "—"]);
    if (t.lateness_ms_p99 !== undefined) rows.push(["lateness p99 / max", `${fmt(t.lateness_ms_p99, 2)} / ${fmt(t.lateness_ms_max, 2)} ms`]);
  } else {
    rows.push(["steps/s", fmt(st.steps_per_s, 0)]);
    rows.push(["x real time", period && st.steps_per_s ? fmt((st.steps_per_s * period) / 1000, 2) : "—"]);
    rows.push(["wall time", st.wall_s !== undefined ? `${fmt(st.wall_s, 1)} s` : "—"]);
    if (ex.lateness_ms !== undefined) rows.push(["lateness now / max", `${fmt(ex.lateness_ms, 2)} / ${fmt(ex.lateness_ms_max, 2)} ms`]);
    rows.push(["late steps", ex.late_steps ?? "—"]);
  }
  rows.push(["late replies", byRole(st.late)]);
  rows.push(["missing replies", byRole(st.missing)]);
  rows.push(["dropped messages", byRole(st.dropped)]);
  if (ex.network_bursts !== undefined) {
    const now = typeof ex.network_burst_under_way_ms === "number" ? " (one under way)" : "";
    rows.push(["bursts online", `${ex.single_channel_bursts} single-channel, ${ex.network_bursts} network${now}`]);
  }
  if (nv.source.kind === "live") {
    rows.push(["alive", (st.alive || []).join(", ") || "—"]);
    rows.push(["motor (L, R)", nv.motor ? `${fmt(nv.motor[0], 3)}, ${fmt(nv.motor[1], 3)} m/s` : "—"]);
  }
  $("loop-panel").innerHTML = rows.map(([k, v]) => `<tr><td>${k}</td><td>${escapeHtml(String(v))}</td></tr>`).join("");
}

function drawEndpoints() {
  const parts = [];
  for (const role of ["body", "culture"]) {
    const e = nv.endpoints[role];
    if (!e) continue;
    const c = e.counters || {};
    const alive = e.alive === null || e.alive === undefined ? "" :
      e.alive ? ' <span class="ok">● alive</span>' : ' <span class="bad">● not answering</span>';
    const dropped = c.dropped && typeof c.dropped === "object" ? c.dropped : {};
    const nDropped = Object.values(dropped).reduce((a, b) => a + b, 0);
    const replay = nv.source.kind === "replay";
    const rows = [
      replay ? ["counters", "at the run's end"] :
        ["state", c.run ? `in run ${String(c.run).slice(0, 8)}…` : e.alive === false ? "—" : "idle"],
      ["steps", c.steps ?? "—"],
      ["dropped", nDropped ? `${nDropped} (${byRole(dropped)})` : "0"],
      ["holds", c.holds ?? 0],
      ["reply round trip", roundTrip(role)],
      ["busy / CPU", c.busy_s !== undefined ? `${fmt(c.busy_s, 2)} / ${fmt(c.cpu_s, 2)} s` : "—"],
    ];
    parts.push(
      `<div class="endpoint"><div class="head">${role}/${escapeHtml(String(e.id))} · ${escapeHtml(String(e.kind || ""))}${alive}</div>` +
      `<table>${rows.map(([k, v]) => `<tr><td>${k}</td><td>${escapeHtml(String(v))}</td></tr>`).join("")}</table></div>`);
  }
  $("endpoints-panel").innerHTML = parts.join("") || '<div class="note">no endpoint seen yet</div>';
}

function roundTrip(role) {  // the hub's latest, from the input's put to the reply's arrival
  const rtt = nv.source.kind === "live" ? ((nv.status.extra || {}).round_trip_ms || {})[role] : undefined;
  return rtt === undefined ? "—" : `${fmt(rtt, 2)} ms`;
}

function escapeHtml(s) {
  return s.replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
}

// ------------------------------------------------------------------ controls

let stopArmed = null;
$("btn-pause").onclick = () => send({ cmd: "pause" });
$("btn-resume").onclick = () => send({ cmd: "resume" });
$("btn-stop").onclick = () => {
  const btn = $("btn-stop");
  if (stopArmed) {
    clearTimeout(stopArmed); stopArmed = null;
    btn.classList.remove("armed"); btn.textContent = "Stop";
    send({ cmd: "stop" });
    return;
  }
  btn.classList.add("armed"); btn.textContent = "Stop the run?";
  stopArmed = setTimeout(() => { stopArmed = null; btn.classList.remove("armed"); btn.textContent = "Stop"; }, 4000);
};
$("btn-play").onclick = () => send({ cmd: nv.replay && nv.replay.playing ? "pause" : "play" });
$("speed").onchange = (e) => send({ cmd: "speed", x: Number(e.target.value) });
let sliding = false;
$("slider").oninput = () => { sliding = true; nv.dirty = true; };
$("slider").onchange = (e) => { sliding = false; send({ cmd: "seek", t_s: Number(e.target.value) }); };

connect();
requestAnimationFrame(frameLoop);
