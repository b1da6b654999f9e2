// popvol view: the page. Sends control changes over a websocket (at most one message per
// animation frame), shows the frames the server sends back. Protocol: popvol/viewer/server.py.
"use strict";

const $ = (id) => document.getElementById(id);
const view = {            // the page's state, also read by the browser tests
  socket: null, settings: null, ranges: null, frames: 0, lastFrame: null, errors: [],
  sent: 0,                // "set" messages sent (the server numbers the frames it answers by them)
  sequence: null,         // a sequence's frames (init's "frames"), null for a still scene
  playing: false,
};
window.popvolView = view;

let pending = {};         // settings changed since the last message
let flushScheduled = false;
const SLIDERS = ["sun_azimuth", "sun_elevation", "intensity", "density", "albedo", "g", "exposure"];
const DEG = Math.PI / 180;

// -- connection -------------------------------------------------------------------------------

function connect() {
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  view.socket = ws;
  ws.onopen = () => status("connected, rendering…");
  ws.onclose = () => status("disconnected: is `popvol view` still running? Reload to reconnect.");
  ws.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    if (msg.type === "init") init(msg);
    else if (msg.type === "frame") showFrame(msg);
    else if (msg.type === "saved") $("saved").textContent = `saved ${msg.png} and ${msg.toml}`;
    else if (msg.type === "error") showError(msg.message);
  };
}

function send(obj) {
  if (view.socket && view.socket.readyState === WebSocket.OPEN) {
    view.socket.send(JSON.stringify(obj));
    if (obj.type === "set") view.sent += 1;
  }
}

function flush() {                    // send the pending changes now
  const settings = pending;
  pending = {};
  if (Object.keys(settings).length) send({ type: "set", settings });
}

function change(values) {             // merge into the pending message, send on the next frame
  Object.assign(view.settings, values);
  Object.assign(pending, values);
  if (!flushScheduled) {
    flushScheduled = true;
    requestAnimationFrame(() => {
      flushScheduled = false;
      flush();
    });
  }
  syncControls();
}

// -- messages from the server -----------------------------------------------------------------

function init(msg) {
  view.settings = msg.settings;
  view.ranges = msg.ranges;
  view.cameraFrame = msg.camera_frame;
  $("scene").textContent = `${msg.scene}: ${msg.size[0]}×${msg.size[1]}, ${msg.resolution} cells` +
    ` (drafts ${msg.draft_size[0]}×${msg.draft_size[1]}, ${msg.draft_resolution} cells)`;
  $("view").width = msg.size[0];
  $("view").height = msg.size[1];
  if (!msg.has_sun) {
    for (const id of ["sun_azimuth", "sun_elevation"]) $(id).disabled = true;
    $("sun-controls").title = "this scene has no directional light (intensity scales its point light)";
  }
  if (!msg.has_key) $("intensity").disabled = true;
  view.sequence = msg.frames;
  if (msg.frames) {
    const f = msg.frames, el = $("frame");
    el.min = f.first; el.max = f.last; el.step = f.step;
    const follows = [];
    if (msg.follows.includes("camera_azimuth")) follows.push("camera");
    if (msg.follows.includes("sun_azimuth")) follows.push("sun");
    $("frames-text").textContent = `${f.count} frames (${f.text}) at ${f.fps} fps` +
      (follows.length ? `; the ${follows.join(" and ")} follow${follows.length > 1 ? "" : "s"} the keyframes` : "");
    $("sequence-controls").hidden = false;
  }
  syncControls();
}

function showFrame(msg) {
  view.frames += 1;
  view.lastFrame = msg;
  $("view").src = `data:image/png;base64,${msg.png}`;
  if (msg.version >= view.sent) {     // the answer to the latest message: take what keyframes drive
    let adopted = false;
    for (const k of msg.follows || []) {
      if (!(k in pending)) { view.settings[k] = msg.settings[k]; adopted = true; }
    }
    if (adopted) syncControls();
  }
  const s = msg.seconds;
  const ms = (x) => `${(1000 * x).toFixed(0)} ms`;
  const head = [];
  if (msg.frame !== null && msg.frame !== undefined) head.push(`frame ${msg.frame} of ${view.sequence.text}`);
  head.push(`${msg.level} ${msg.width}×${msg.height}`, `image ${view.frames}`);
  $("readout").textContent =
    `${head.join(" · ")}\n` +
    (msg.frame !== null && msg.frame !== undefined && s.load >= 0.001 ? `loading the frame ${ms(s.load)}\n` : "") +
    `propagation ${msg.propagated ? ms(s.propagate) + ` (${msg.resolution} cells)` : "0 ms (reused)"}\n` +
    `rendering ${ms(s.render)} · encoding ${ms(s.encode)}`;
  status(msg.level === "full" ? "full view" : view.playing ? "playing (drafts)"
         : msg.level === "preview" ? "preview (gathering the last bounce)" : "draft (refines when you stop)");
  if (view.playing && msg.version >= view.playWaitFor) playStep();
}

function showError(message) {
  view.errors.push(message);
  if (view.playing) setPlaying(false);  // a frame that failed would stall the loop: stop there
  const box = $("error");
  box.textContent = message;
  box.hidden = false;
  clearTimeout(showError.timer);
  showError.timer = setTimeout(() => { box.hidden = true; }, 8000);
}

function status(text) { $("status").textContent = text; }

// -- sliders ----------------------------------------------------------------------------------

function sliderValue(id) {
  const el = $(id);
  const v = parseFloat(el.value);
  return el.dataset.log ? Math.pow(10, v) : v;
}

function syncControls() {
  const s = view.settings;
  if (!s) return;
  for (const id of SLIDERS) {
    const el = $(id);
    let v = s[id];
    if (v === null || v === undefined) {
      $(`${id}-out`).textContent = id.startsWith("sun") ? "–" : "scene's";
      continue;
    }
    if (id === "sun_azimuth") v = ((v + 540) % 360) - 180;
    if (document.activeElement !== el) el.value = el.dataset.log ? Math.log10(Math.max(v, 1e-2)) : v;
    $(`${id}-out`).textContent = el.dataset.log ? v.toPrecision(3) : v.toFixed({ exposure: 1, albedo: 3, g: 3 }[id] ?? 2);
  }
  if (view.sequence && s.frame !== null && s.frame !== undefined) {
    if (document.activeElement !== $("frame")) $("frame").value = s.frame;
    $("frame-out").textContent = s.frame;
  }
  drawSky();
}

for (const id of SLIDERS) {
  $(id).addEventListener("input", () => change({ [id]: sliderValue(id) }));
}

// -- sequence: the frame slider and play -------------------------------------------------------

function snapFrame(v) {               // the member of the sequence's frames nearest to v
  let best = null, bestD = Infinity;
  for (const [a, b, step] of view.sequence.runs) {
    const c = Math.min(b, Math.max(a, a + Math.round((v - a) / step) * step));
    if (Math.abs(c - v) < bestD) { best = c; bestD = Math.abs(c - v); }
  }
  return best;
}

function nextFrame(f) {               // the frame after f, the first after the last (looping)
  for (const [a, b, step] of view.sequence.runs) {
    if (f < a) return a;
    if (f < b) return Math.min(b, a + (Math.floor((f - a) / step) + 1) * step);
  }
  return view.sequence.first;
}

let playTimer = null;
view.playWaitFor = 0;                 // the message whose frame the next step waits for
view.lastStep = 0;

function setPlaying(on) {
  view.playing = on;
  const b = $("play");
  b.textContent = on ? "❚❚ Pause" : "▶ Play";
  b.setAttribute("aria-pressed", String(on));
  clearTimeout(playTimer);
  if (on) playStep(); else status("paused (the full view follows)");
}

// One step: the next frame is asked for once the previous one has arrived (so the server never
// holds a stale frame), and never sooner than 1/fps after the previous step.
function playStep() {
  clearTimeout(playTimer);
  const wait = Math.max(0, view.lastStep + 1000 / view.sequence.fps - performance.now());
  playTimer = setTimeout(() => {
    if (!view.playing || !view.settings) return;
    view.lastStep = performance.now();
    const frame = nextFrame(view.settings.frame);
    Object.assign(view.settings, { frame });
    Object.assign(pending, { frame });
    flush();
    view.playWaitFor = view.sent;
    syncControls();
  }, wait);
}

$("play").addEventListener("click", () => { if (view.sequence) setPlaying(!view.playing); });
$("frame").addEventListener("input", () => {
  if (view.playing) setPlaying(false);   // scrubbing takes over from play
  const f = snapFrame(parseFloat($("frame").value));
  $("frame").value = f;
  change({ frame: f });
});

// -- sun: drag on the sky hemisphere, seen from above (+x right, +z down) -----------------------

const sky = $("sky");

function skyGeometry() {
  const r = sky.width / 2 - 16;
  return { cx: sky.width / 2, cy: sky.height / 2, r };
}

function drawSky() {
  const ctx = sky.getContext("2d");
  const { cx, cy, r } = skyGeometry();
  const s = view.settings;
  ctx.clearRect(0, 0, sky.width, sky.height);
  ctx.fillStyle = "#243a5a";
  ctx.beginPath(); ctx.arc(cx, cy, r, 0, 2 * Math.PI); ctx.fill();
  ctx.strokeStyle = "#456";
  for (const el of [30, 60]) { ctx.beginPath(); ctx.arc(cx, cy, r * (90 - el) / 90, 0, 2 * Math.PI); ctx.stroke(); }
  ctx.fillStyle = "#9ab"; ctx.font = "10px sans-serif";
  ctx.fillText("+x", cx + r + 2, cy + 3); ctx.fillText("+z", cx - 5, cy + r + 12);
  if (!s) return;
  if (view.cameraFrame) {             // where the camera is, on the horizon
    const [e1, e2, u] = view.cameraFrame;
    const a = s.camera_azimuth * DEG, e = s.camera_elevation * DEG;
    const d = [0, 1, 2].map((i) => Math.cos(e) * (Math.cos(a) * e1[i] + Math.sin(a) * e2[i]) + Math.sin(e) * u[i]);
    const az = Math.atan2(d[0], d[2]);
    ctx.fillStyle = "#ccc";
    ctx.fillRect(cx + r * Math.sin(az) - 3, cy + r * Math.cos(az) - 3, 6, 6);
  }
  if (s.sun_azimuth === null) return;
  const rr = r * Math.min(1.1, (90 - s.sun_elevation) / 90);
  const az = s.sun_azimuth * DEG;
  ctx.fillStyle = s.sun_elevation >= 0 ? "#ffd75a" : "#a08a40";
  ctx.beginPath(); ctx.arc(cx + rr * Math.sin(az), cy + rr * Math.cos(az), 7, 0, 2 * Math.PI); ctx.fill();
}

function sunFromPointer(ev) {
  const rect = sky.getBoundingClientRect();
  const { cx, cy, r } = skyGeometry();
  const x = (ev.clientX - rect.left) * sky.width / rect.width - cx;
  const y = (ev.clientY - rect.top) * sky.height / rect.height - cy;
  const rr = Math.min(1, Math.hypot(x, y) / r);
  change({ sun_azimuth: Math.atan2(x, y) / DEG, sun_elevation: 90 * (1 - rr) });
}

sky.addEventListener("pointerdown", (ev) => {
  if (!view.settings || view.settings.sun_azimuth === null) return;
  sky.setPointerCapture(ev.pointerId);
  sunFromPointer(ev);
});
sky.addEventListener("pointermove", (ev) => { if (sky.hasPointerCapture(ev.pointerId)) sunFromPointer(ev); });

// -- camera: drag to orbit, wheel to zoom ------------------------------------------------------

const img = $("view");
let last = null;
img.addEventListener("pointerdown", (ev) => {
  img.setPointerCapture(ev.pointerId);
  img.classList.add("dragging");
  last = [ev.clientX, ev.clientY];
});
img.addEventListener("pointermove", (ev) => {
  if (!last || !view.settings || !img.hasPointerCapture(ev.pointerId)) return;
  const dx = ev.clientX - last[0], dy = ev.clientY - last[1];
  last = [ev.clientX, ev.clientY];
  const s = view.settings;
  const el = Math.max(-89, Math.min(89, s.camera_elevation + 0.4 * dy));
  let az = s.camera_azimuth - 0.4 * dx;
  if (az > 360) az -= 360;
  if (az < -360) az += 360;
  change({ camera_azimuth: az, camera_elevation: el });
});
img.addEventListener("pointerup", (ev) => { last = null; img.classList.remove("dragging"); });
img.addEventListener("wheel", (ev) => {
  ev.preventDefault();
  if (!view.settings) return;
  const [lo, hi] = view.ranges.camera_distance;
  const d = view.settings.camera_distance * Math.exp(0.0015 * ev.deltaY);
  change({ camera_distance: Math.max(lo, Math.min(hi, d)) });
}, { passive: false });

$("save").addEventListener("click", () => {
  $("saved").textContent = "saving…";
  send({ type: "save" });
});

connect();
