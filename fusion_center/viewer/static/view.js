// uwbnet live view: draws the documents of /events (Server-Sent Events) on a canvas.
// No build step, no dependencies. window.uwbnetView exposes counters for tests and scripts.
"use strict";

const view = {
  scene: { walls: [], bounds: [-5, 5, -5, 5] },
  state: null,
  image: null,
  imageCanvas: null,
  updates: 0,
  reconnects: 0,
  frames: 0,
  rate: 0,
  arrivals: [],
  lastMessage: 0,
  connected: false,
};
window.uwbnetView = view;

const canvas = document.getElementById("canvas");
const ctx = canvas.getContext("2d");
const COLOURS = ["#4fc3f7", "#f06292", "#aed581", "#ffd54f", "#ba68c8", "#4db6ac",
                 "#ff8a65", "#90a4ae", "#dce775", "#7986cb"];
const STATE_COLOUR = { alive: "#3ddc84", nlos: "#ffb347", lost: "#ff4d4d" };
const trackColour = (id) => COLOURS[((id % COLOURS.length) + COLOURS.length) % COLOURS.length];

// --- connection ------------------------------------------------------------------------------

let source = null;
function setConn(state) {
  const el = document.getElementById("conn");
  el.dataset.state = state;
  el.textContent = state;
}

function connect() {
  if (source) source.close();
  source = new EventSource("/events");
  source.onopen = () => { view.connected = true; setConn("live"); };
  source.onerror = () => { view.connected = false; setConn("reconnecting"); };
  source.addEventListener("scene", (e) => { view.scene = JSON.parse(e.data); touch(); });
  source.addEventListener("image", (e) => { setImage(JSON.parse(e.data)); touch(); });
  source.addEventListener("state", (e) => {
    view.state = JSON.parse(e.data);
    view.updates += 1;
    const now = performance.now();
    view.arrivals.push(now);
    while (view.arrivals.length && view.arrivals[0] < now - 2000) view.arrivals.shift();
    touch();
    scheduleDraw();
  });
}

function touch() { view.lastMessage = performance.now(); }

// EventSource retries on its own after an error; a stream that stalls without an error
// (a proxy, a suspended laptop) is reopened here.
setInterval(() => {
  if (view.lastMessage && performance.now() - view.lastMessage > 3000) {
    view.reconnects += 1;
    setConn("reconnecting");
    view.lastMessage = performance.now();
    connect();
  }
}, 1000);

// --- heat map --------------------------------------------------------------------------------

// Perceptual-ish colour map (dark blue -> teal -> yellow) as a 256-entry lookup table.
const LUT = (() => {
  const stops = [[0, [10, 12, 40]], [0.35, [30, 90, 140]], [0.65, [40, 170, 130]], [1, [250, 230, 80]]];
  const out = new Uint8ClampedArray(256 * 3);
  for (let i = 0; i < 256; i++) {
    const v = i / 255;
    let k = 0;
    while (k < stops.length - 2 && v > stops[k + 1][0]) k++;
    const [a, ca] = stops[k], [b, cb] = stops[k + 1];
    const f = (v - a) / (b - a);
    for (let c = 0; c < 3; c++) out[i * 3 + c] = ca[c] + f * (cb[c] - ca[c]);
  }
  return out;
})();

function setImage(doc) {
  const raw = atob(doc.data);
  const n = doc.nx * doc.ny;
  if (raw.length !== n) return;
  const off = view.imageCanvas || document.createElement("canvas");
  off.width = doc.nx;
  off.height = doc.ny;
  const octx = off.getContext("2d");
  const img = octx.createImageData(doc.nx, doc.ny);
  // Row 0 of the image is at y0 (south); canvas row 0 is drawn at the top, so flip rows.
  for (let i = 0; i < doc.ny; i++) {
    const src = i * doc.nx, dst = (doc.ny - 1 - i) * doc.nx;
    for (let j = 0; j < doc.nx; j++) {
      const q = raw.charCodeAt(src + j);
      const p = (dst + j) * 4;
      img.data[p] = LUT[q * 3];
      img.data[p + 1] = LUT[q * 3 + 1];
      img.data[p + 2] = LUT[q * 3 + 2];
      img.data[p + 3] = q < 8 ? 0 : 90 + (q * 165) / 255;
    }
  }
  octx.putImageData(img, 0, 0);
  view.imageCanvas = off;
  view.image = doc;
  document.getElementById("image-label").textContent =
    `heat map: ${doc.method === "eq23" ? "moving-target image, eq. (23)" : doc.method}` +
    `, max ${doc.max.toPrecision(3)}`;
}

// --- drawing ---------------------------------------------------------------------------------

let drawPending = false;
function scheduleDraw() {
  if (!drawPending) { drawPending = true; requestAnimationFrame(draw); }
}

let lastTables = -Infinity;  // the first draw fills the tables at once
function draw() {
  drawPending = false;
  view.frames += 1;
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = "#111418";
  ctx.fillRect(0, 0, w, h);
  const [x0, x1, y0, y1] = view.scene.bounds;
  const s = Math.min((w - 40) / (x1 - x0), (h - 40) / (y1 - y0));
  const ox = (w - s * (x1 - x0)) / 2, oy = (h - s * (y1 - y0)) / 2;
  const X = (x) => ox + (x - x0) * s;
  const Y = (y) => h - oy - (y - y0) * s;

  // grid, 1 m
  ctx.strokeStyle = "#1d232b";
  ctx.lineWidth = 1;
  ctx.beginPath();
  for (let x = Math.ceil(x0); x <= x1; x++) { ctx.moveTo(X(x), Y(y0)); ctx.lineTo(X(x), Y(y1)); }
  for (let y = Math.ceil(y0); y <= y1; y++) { ctx.moveTo(X(x0), Y(y)); ctx.lineTo(X(x1), Y(y)); }
  ctx.stroke();

  const im = view.image;
  if (im && view.imageCanvas && document.getElementById("show-image").checked) {
    ctx.imageSmoothingEnabled = true;
    const left = X(im.x0 - im.dx / 2), top = Y(im.y0 + (im.ny - 0.5) * im.dy);
    ctx.drawImage(view.imageCanvas, left, top, im.nx * im.dx * s, im.ny * im.dy * s);
  }

  ctx.strokeStyle = "#c8ccd4";
  ctx.lineWidth = 3;
  ctx.beginPath();
  for (const [ax, ay, bx, by] of view.scene.walls) { ctx.moveTo(X(ax), Y(ay)); ctx.lineTo(X(bx), Y(by)); }
  ctx.stroke();

  const st = view.state;
  if (st) {
    for (const n of st.nodes) {
      if (!n.pose) continue;
      const px = X(n.pose[0]), py = Y(n.pose[1]);
      const col = STATE_COLOUR[n.state] || "#888";
      if (n.boresight !== null) {
        ctx.strokeStyle = col;
        ctx.lineWidth = 1.5;
        ctx.beginPath();
        ctx.moveTo(px, py);
        ctx.lineTo(px + 18 * Math.cos(n.boresight), py - 18 * Math.sin(n.boresight));
        ctx.stroke();
      }
      ctx.fillStyle = col;
      ctx.fillRect(px - 5, py - 5, 10, 10);
      if (n.state === "lost") {
        ctx.strokeStyle = col;
        ctx.lineWidth = 2;
        ctx.beginPath();
        ctx.moveTo(px - 8, py - 8); ctx.lineTo(px + 8, py + 8);
        ctx.moveTo(px + 8, py - 8); ctx.lineTo(px - 8, py + 8);
        ctx.stroke();
      }
      ctx.fillStyle = "#aab";
      ctx.font = "11px system-ui";
      ctx.fillText(n.id, px + 7, py + 14);
    }
    for (const t of st.tracks) {
      const col = trackColour(t.id);
      ctx.strokeStyle = col;
      ctx.lineWidth = 2;
      ctx.globalAlpha = 0.7;
      ctx.beginPath();
      t.tail.forEach(([x, y], i) => (i ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
      ctx.stroke();
      ctx.globalAlpha = 1;
      ctx.fillStyle = col;
      ctx.beginPath();
      ctx.arc(X(t.x), Y(t.y), 7, 0, 2 * Math.PI);
      ctx.fill();
      ctx.fillStyle = "#fff";
      ctx.font = "bold 12px system-ui";
      ctx.fillText(String(t.id), X(t.x) + 9, Y(t.y) - 9);
    }
    const now = performance.now();
    if (now - lastTables > 400) { lastTables = now; tables(st); }
  }
}
window.addEventListener("resize", scheduleDraw);

// --- tables (at most 2.5 Hz: DOM work is the expensive part with 100 nodes) -------------------

const fmt = (v, d) => (v === null || v === undefined ? "-" : Number(v).toFixed(d));

function tables(st) {
  view.rate = view.arrivals.length > 1
    ? (view.arrivals.length - 1) / ((view.arrivals[view.arrivals.length - 1] - view.arrivals[0]) / 1000)
    : 0;
  document.getElementById("rate").textContent = `${view.rate.toFixed(1)} Hz`;
  // Network time is wall-clock time in a deployment (shown as such), scenario seconds otherwise.
  document.getElementById("clock").textContent = st.t > 1e9
    ? new Date(st.t * 1000).toISOString().slice(11, 22) + " UTC"
    : `t = ${fmt(st.t, 2)} s`;
  const lost = st.nodes.filter((n) => n.state === "lost").length;
  document.getElementById("summary").textContent =
    `${st.tracks.length} tracks, ${st.nodes.length} nodes (${lost} lost)` +
    (st.counters && st.counters.method ? `, fusion ${st.counters.method}` : "");
  const tb = document.querySelector("#tracks tbody");
  tb.replaceChildren(...st.tracks.map((t) => row(
    [t.id, fmt(t.x, 2), fmt(t.y, 2), fmt(Math.hypot(t.vx, t.vy), 2)], { track: t.id })));
  const nb = document.querySelector("#nodes tbody");
  nb.replaceChildren(...st.nodes.map((n) => row(
    [n.id, n.state, fmt(n.rate, 1), fmt(n.drops, 0), fmt(n.late, 0), fmt(n.latency_ms, 1),
     n.cpu === null ? "-" : (100 * n.cpu).toFixed(1)], { node: n.id, state: n.state })));
}

function row(cells, data) {
  const tr = document.createElement("tr");
  for (const [k, v] of Object.entries(data)) tr.dataset[k] = v;
  for (const c of cells) {
    const td = document.createElement("td");
    td.textContent = c;
    tr.appendChild(td);
  }
  return tr;
}

connect();
