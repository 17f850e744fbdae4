// pednav web viewer: plain JavaScript, no build step. Talks to the API of the server that serves it
// (same origin) with the bearer token the user signs in with (kept in this browser's localStorage).
"use strict";

const MODE_COLOURS = { zupt: "#d62728", pdr: "#1f77b4", idle: "#7f7f7f" };
const BEHAVIOUR_COLOURS = { stand: "#9e9e9e", walk: "#2ca02c", run: "#ff7f0e", other: "#9467bd" };
const LIVE_POLL_MS = 2000;
const LIST_POLL_MS = 10000;

const state = { token: localStorage.getItem("pednav_token") || "", config: null, sessions: [], selected: null,
                map: null, mapKind: null, layers: [], liveTimer: null, listTimer: null, fitted: null };

const $ = (id) => document.getElementById(id);

function say(text, isError) {
  const el = $("status");
  el.textContent = text || "";
  el.className = isError ? "error" : "";
}

async function api(path) {
  const r = await fetch(path, { headers: { Authorization: "Bearer " + state.token } });
  if (r.status === 401) {
    signOut("Sign-in refused: the token is wrong, expired or revoked.");
    throw new Error("401");
  }
  if (!r.ok) {
    let detail = r.statusText;
    try { detail = (await r.json()).detail || detail; } catch (e) { /* not JSON */ }
    throw new Error("HTTP " + r.status + ": " + detail);
  }
  return r.json();
}

function signOut(message) {
  localStorage.removeItem("pednav_token");
  state.token = "";
  clearInterval(state.liveTimer);
  clearInterval(state.listTimer);
  $("main").hidden = true;
  $("signin").hidden = false;
  $("signout").hidden = true;
  $("who").textContent = "";
  document.body.dataset.state = "signed-out";
  say(message || "Signed out.", Boolean(message));
}

async function signIn(token, remember) {
  state.token = token.trim();
  if (!state.token) { say("Give a token.", true); return; }
  try {
    const me = await api("/v1/users/me");
    if (remember) localStorage.setItem("pednav_token", state.token);
    $("who").textContent = "signed in as " + me.name;
    $("signin").hidden = true;
    $("signout").hidden = false;
    $("main").hidden = false;
    say("");
    await loadSessions();
    clearInterval(state.listTimer);
    state.listTimer = setInterval(() => loadSessions().catch(() => {}), LIST_POLL_MS);
    const wanted = Number(new URLSearchParams(location.search).get("session"));
    const pick = state.sessions.find((s) => s.id === wanted) || state.sessions[state.sessions.length - 1];
    if (pick) await select(pick.id);
    else { document.body.dataset.state = "ready"; say("No sessions yet: stream one (pednav replay FILE --server ...)."); }
  } catch (e) {
    if (e.message !== "401") say(String(e.message || e), true);
  }
}

async function loadSessions() {
  state.sessions = await api("/v1/sessions?limit=1000");
  const ul = $("sessions");
  ul.textContent = "";
  for (const s of state.sessions.slice().reverse()) {
    const li = document.createElement("li");
    li.dataset.id = s.id;
    li.className = state.selected === s.id ? "selected" : "";
    const when = s.created_at.slice(0, 16).replace("T", " ");
    li.innerHTML = "<b></b> <small></small><br><small></small>";
    li.children[0].textContent = "Session " + s.id;
    li.children[1].textContent = s.status === "open" ? "open" : "";
    li.children[3].textContent = when + " UTC, " + s.device_kind + ", " + s.n_positions + " positions" +
      (s.latitude_deg !== null ? ", anchored" : "");
    li.addEventListener("click", () => select(s.id));
    ul.appendChild(li);
  }
}

async function select(id) {
  state.selected = id;
  state.fitted = null;
  for (const li of $("sessions").children) li.className = Number(li.dataset.id) === id ? "selected" : "";
  clearInterval(state.liveTimer);
  await refresh();
  const s = state.sessions.find((x) => x.id === id);
  if (s && s.status === "open") {
    state.liveTimer = setInterval(() => refresh().catch((e) => say(String(e.message || e), true)), LIVE_POLL_MS);
  }
}

async function refresh() {
  const id = state.selected;
  document.body.dataset.state = "loading";
  const [sess, traj, tl, profiles] = await Promise.all([
    api("/v1/sessions/" + id), api("/v1/sessions/" + id + "/trajectory"), api("/v1/sessions/" + id + "/timeline"),
    api("/v1/profiles"),
  ]);
  if (id !== state.selected) return;
  const i = state.sessions.findIndex((x) => x.id === id);
  if (i >= 0 && JSON.stringify(state.sessions[i]) !== JSON.stringify(sess)) {
    state.sessions[i] = sess;
    await loadSessions();  // its line in the list (positions, status) follows the live session
  }
  if (sess.status !== "open") clearInterval(state.liveTimer);
  $("live").hidden = sess.status !== "open";
  $("session-title").textContent = "Session " + id + " (" + sess.device_kind + ", " + traj.positions.length + " positions)";
  $("north-note").textContent = northNote(traj);
  drawMap(traj);
  drawTimelines(traj, tl);
  drawEnergy(tl.energy);
  drawProfile(profiles);
  document.body.dataset.state = "ready";
  document.body.dataset.session = String(id);
  say("");
}

function northNote(traj) {
  if (traj.north === "true") return "north: true (declination " + traj.declination_deg.toFixed(2) + "\u00b0 applied)";
  if (traj.north === "magnetic") return "north: magnetic (no anchor)";
  return "north: the sensor's initial heading";
}

// ------------------------------------------------------------------------------------------------ map
function wantTiles(traj) {
  return Boolean(traj.anchor && state.config && state.config.tile_url && navigator.onLine);
}

function newMap(kind) {
  if (state.map) { state.map.remove(); state.map = null; }
  const opts = kind === "grid" ? { crs: L.CRS.Simple, minZoom: -6, maxZoom: 6, zoomSnap: 0.25 } : { maxZoom: 22 };
  state.map = L.map("map", opts);
  state.mapKind = kind;
  L.control.scale({ imperial: false }).addTo(state.map);
  state.fitted = null;
  if (kind === "tiles") {
    const layer = L.tileLayer(state.config.tile_url, { maxZoom: 22, maxNativeZoom: 19,
                                                      attribution: state.config.tile_attribution });
    layer.on("tileerror", () => {  // offline after all: the metric grid instead
      if (state.mapKind === "tiles") { state.offline = true; say("Map tiles unreachable: showing a metric grid."); refresh(); }
    });
    layer.addTo(state.map);
  }
}

function niceStep(span) {
  const raw = span / 8;
  const p = Math.pow(10, Math.floor(Math.log10(Math.max(raw, 1e-3))));
  for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
  return 10 * p;
}

function drawGrid(minN, maxN, minE, maxE) {
  const span = Math.max(maxN - minN, maxE - minE, 10);
  const step = niceStep(span);
  const pad = step;
  const n0 = Math.floor((minN - pad) / step) * step, n1 = Math.ceil((maxN + pad) / step) * step;
  const e0 = Math.floor((minE - pad) / step) * step, e1 = Math.ceil((maxE + pad) / step) * step;
  const style = { color: "#ccc", weight: 1, interactive: false, className: "pednav-grid" };
  for (let n = n0; n <= n1 + 1e-9; n += step) {
    state.layers.push(L.polyline([[n, e0], [n, e1]], style).addTo(state.map));
    state.layers.push(L.marker([n, e0], { icon: L.divIcon({ className: "grid-label", html: n.toFixed(0) + " m N" }),
                                          interactive: false }).addTo(state.map));
  }
  for (let e = e0; e <= e1 + 1e-9; e += step) {
    state.layers.push(L.polyline([[n0, e], [n1, e]], style).addTo(state.map));
    state.layers.push(L.marker([n0, e], { icon: L.divIcon({ className: "grid-label", html: e.toFixed(0) + " m E" }),
                                          interactive: false }).addTo(state.map));
  }
}

function drawMap(traj) {
  const kind = wantTiles(traj) && !state.offline ? "tiles" : "grid";
  if (!state.map || state.mapKind !== kind) newMap(kind);
  for (const l of state.layers) l.remove();
  state.layers = [];
  const pos = traj.positions;
  const pt = kind === "tiles" ? (p) => [p.latitude_deg, p.longitude_deg] : (p) => [p.north, p.east];
  const pts = pos.map(pt);
  if (kind === "grid") {
    const ns = pos.map((p) => p.north), es = pos.map((p) => p.east);
    drawGrid(Math.min(0, ...ns), Math.max(0, ...ns), Math.min(0, ...es), Math.max(0, ...es));
  }
  if (pts.length) {
    state.layers.push(L.polyline(pts, { color: "#333", weight: 2, opacity: 0.7, className: "pednav-track" }).addTo(state.map));
    pos.forEach((p, k) => {
      state.layers.push(L.circleMarker(pts[k], { radius: 3, weight: 1, color: MODE_COLOURS[p.mode] || "#000",
                                                 fillOpacity: 0.9, className: "pednav-step pednav-mode-" + p.mode })
        .bindTooltip("t=" + ((p.t_ns - pos[0].t_ns) / 1e9).toFixed(1) + " s, " + p.behaviour + "/" + p.mode)
        .addTo(state.map));
    });
  }
  const key = state.selected + ":" + kind;
  const inView = state.fitted === key && pts.length > 0 && state.map.getBounds().contains(L.latLngBounds(pts));
  if (state.fitted !== key || pts.length <= 2 || !inView) {  // a live track that left the view is followed
    const bounds = pts.length ? L.latLngBounds(pts) : L.latLngBounds([[-10, -10], [10, 10]]);
    if (kind === "grid") bounds.extend([0, 0]);
    state.map.fitBounds(bounds.pad(0.15), { maxZoom: kind === "tiles" ? 19 : 4 });
    state.fitted = key;
  }
}

// ------------------------------------------------------------------------------------------- timelines
function timeAxis(traj, tl) {
  const ts = [];
  for (const b of tl.batches) { ts.push(b.t_start_ns, b.t_end_ns); }
  for (const p of traj.positions) ts.push(p.t_ns);
  if (!ts.length) return null;
  const t0 = Math.min(...ts), t1 = Math.max(...ts);
  return { t0, span: Math.max(t1 - t0, 1) };
}

function prepare(canvas) {
  const w = Math.floor(canvas.getBoundingClientRect().width) || canvas.width;
  if (w > 0 && canvas.width !== w) canvas.width = w;
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  return ctx;
}

function bands(canvas, axis, spans, colours) {
  const ctx = prepare(canvas);
  let drawn = 0;
  for (const [a, b, key] of spans) {
    const x0 = ((a - axis.t0) / axis.span) * canvas.width, x1 = ((b - axis.t0) / axis.span) * canvas.width;
    ctx.fillStyle = colours[key] || "#000";
    ctx.fillRect(x0, 12, Math.max(x1 - x0, 1), canvas.height - 13);
    drawn += 1;
  }
  ctx.font = "10px sans-serif";
  let x = 4;
  for (const [k, c] of Object.entries(colours)) {
    if (!spans.some((s) => s[2] === k)) continue;
    ctx.fillStyle = c; ctx.fillRect(x, 2, 8, 8); ctx.fillStyle = "#222"; ctx.fillText(k, x + 10, 10);
    x += 14 + ctx.measureText(k).width;
  }
  canvas.dataset.drawn = String(drawn);
}

function drawTimelines(traj, tl) {
  const axis = timeAxis(traj, tl);
  const ids = ["tl-behaviour", "tl-mode", "tl-gyro", "tl-rate", "tl-axis"];
  if (!axis) { for (const id of ids) { prepare($(id)); $(id).dataset.drawn = "0"; } return; }
  const spanOf = (b, i, arr) => [b.t_start_ns, i + 1 < arr.length ? arr[i + 1].t_start_ns : b.t_end_ns];
  bands($("tl-behaviour"), axis, tl.batches.map((b, i, a) => [...spanOf(b, i, a), b.behaviour]), BEHAVIOUR_COLOURS);
  bands($("tl-mode"), axis, tl.batches.map((b, i, a) => [...spanOf(b, i, a), b.mode]), MODE_COLOURS);
  bands($("tl-gyro"), axis, tl.batches.map((b, i, a) => [...spanOf(b, i, a), b.gyro_on ? "on" : "off"]),
        { on: "#d62728", off: "#e8e8e8" });
  // sampling rate: accelerometer, gyroscope and magnetometer rates as sent, step lines
  const c = $("tl-rate"), ctx = prepare(c);
  const max = Math.max(1, ...tl.batches.map((b) => Math.max(b.acc_hz, b.gyr_hz, b.mag_hz)));
  const y = (hz) => c.height - 4 - (hz / max) * (c.height - 14);
  let drawn = 0;
  for (const [key, colour] of [["acc_hz", "#2ca02c"], ["gyr_hz", "#d62728"], ["mag_hz", "#9467bd"]]) {
    ctx.strokeStyle = colour; ctx.lineWidth = 1.5; ctx.beginPath();
    tl.batches.forEach((b, i, arr) => {
      const [a, e] = spanOf(b, i, arr);
      const x0 = ((a - axis.t0) / axis.span) * c.width, x1 = ((e - axis.t0) / axis.span) * c.width;
      if (i === 0) ctx.moveTo(x0, y(b[key])); else ctx.lineTo(x0, y(b[key]));
      ctx.lineTo(x1, y(b[key]));
      drawn += 1;
    });
    ctx.stroke();
  }
  ctx.fillStyle = "#222"; ctx.font = "10px sans-serif";
  ctx.fillText(max.toFixed(0) + " Hz  (acc green, gyro red, mag purple)", 4, 10);
  c.dataset.drawn = String(drawn);
  const ax = $("tl-axis"), actx = prepare(ax);
  const secs = axis.span / 1e9, step = niceStep(secs);
  actx.fillStyle = "#444"; actx.font = "10px sans-serif";
  for (let s = 0; s <= secs + 1e-9; s += step) {
    const x = (s / secs) * ax.width;
    actx.fillRect(x, 0, 1, 4);
    actx.fillText(s.toFixed(0), Math.min(x + 2, ax.width - 20), 14);
  }
  ax.dataset.drawn = "1";
}

// ------------------------------------------------------------------------------------------- tables
function rows(table, data) {
  table.textContent = "";
  for (const r of data) {
    const tr = document.createElement("tr");
    r.forEach((v, k) => {
      const td = document.createElement(k === 0 ? "th" : "td");
      td.textContent = v;
      if (k > 0 && typeof v === "string" && /^-?[0-9.]/.test(v)) td.className = "num";
      tr.appendChild(td);
    });
    table.appendChild(tr);
  }
}

function drawEnergy(e) {
  if (!e) { rows($("energy"), [["no batches yet", ""]]); return; }
  const c = e.components_mj;
  rows($("energy"), [
    ["device profile", e.profile],
    ["duration", e.duration_s.toFixed(1) + " s"],
    ["accelerometer", c.acc.toFixed(1) + " mJ"], ["gyroscope", c.gyr.toFixed(1) + " mJ"],
    ["magnetometer", c.mag.toFixed(1) + " mJ"], ["computation", c.compute.toFixed(1) + " mJ"],
    ["radio", c.radio.toFixed(1) + " mJ"], ["total", e.total_mj.toFixed(1) + " mJ"],
    ["mean power", e.mean_power_mw.toFixed(2) + " mW"],
  ]);
}

function drawProfile(profiles) {
  const out = [];
  for (const p of profiles) {
    const d = p.data;
    if (!d) { out.push([p.behaviour, "reset (v" + p.version + ")"]); continue; }
    const deg = (r) => (r === null || r === undefined ? "-" : (r * 180 / Math.PI).toFixed(2) + "\u00b0");
    const sd = d.heading_deviation_var ? Math.sqrt(d.heading_deviation_var) : null;
    out.push([p.behaviour, (d.calibrated ? "calibrated" : "not calibrated") + ", " + d.n_steps + " steps, v" + p.version]);
    out.push(["  heading deviation", deg(d.heading_deviation_rad) + " \u00b1 " + deg(sd)]);
    out.push(["  step length \u03c3", d.sigma_d_m === null ? "-" : (100 * d.sigma_d_m).toFixed(1) + " cm"]);
    const cal = (d.step_model || {}).calibrator;
    if (cal && cal.fits) {
      const w = 2 * cal.band_hz;
      for (const [k, f] of Object.entries(cal.fits)) {
        const parts = k.split("/");
        const band = parts.length > 1 ? (Number(parts[1]) * w).toFixed(1) + "-" + ((Number(parts[1]) + 1) * w).toFixed(1) + " Hz"
                                      : "all paces";
        out.push(["  " + cal.model + " " + band, "n=" + f.n + ", \u03c3=" + (100 * f.sigma_d).toFixed(1) + " cm, K=[" +
                  f.coef.map((x) => x.toFixed(3)).join(", ") + "]"]);
      }
    }
  }
  rows($("profile"), out.length ? out : [["no profile yet", "close a session to store one"]]);
}

// -------------------------------------------------------------------------------------------- start
async function start() {
  try {
    state.config = await (await fetch("config.json")).json();
  } catch (e) {
    state.config = { tile_url: "", tile_attribution: "" };
  }
  $("signin").addEventListener("submit", (ev) => { ev.preventDefault(); signIn($("token").value, true); });
  $("signout").addEventListener("click", () => signOut());
  window.addEventListener("resize", () => { if (state.selected) refresh().catch(() => {}); });
  if (state.token) await signIn(state.token, false);
  else { document.body.dataset.state = "signed-out"; say("Sign in with your token."); }
}

start();
