"""The UI's one page: HTML, CSS and JavaScript inline, nothing fetched from elsewhere.

It works offline (no CDN, no build step).  The script opens ``/events`` (Server-Sent
Events): a snapshot first, then each status document, violation record and
/diagnostics update as it arrives; ages tick and sparklines are drawn in the
browser from the values it has seen.  ``__NONCE__`` is replaced per response (the
Content-Security-Policy admits this script only).  ``__BASE__`` is where the page's
stream and reset are (empty for the one robot; ``/robot/<id>`` in the fleet) and
``__FLEET__`` the fleet page to link back to (empty: no link); ``__HOLD_S__`` how
long a violation stays shown after it (``ui --violated-for``).
docs/reference/commands.md, ``ui``.
"""

from __future__ import annotations

# Both pages' scripts: the live tables redrawn in place, a burst of events one redraw.
PATCH_JS = r"""
// Live tables are redrawn in place (docs/reference/commands.md, ui): only the text and
// attributes that changed are touched, and keyed rows (data-key) keep their elements,
// so a button or link under a person's pointer stays the same element through a
// redraw and their click lands on what they pressed.
function patch(el, html) {
  const t = document.createElement("template");
  t.innerHTML = html;
  patchChildren(el, t.content);
}
function keyOf(n) { return n.nodeType === 1 ? n.getAttribute("data-key") : null; }
function patchNode(old, neu) {
  if (old.nodeType !== 1) { if (old.nodeValue !== neu.nodeValue) old.nodeValue = neu.nodeValue; return; }
  for (const a of Array.from(old.attributes)) if (!neu.hasAttribute(a.name)) old.removeAttribute(a.name);
  for (const a of Array.from(neu.attributes)) {
    if (old.getAttribute(a.name) !== a.value) old.setAttribute(a.name, a.value);
  }
  patchChildren(old, neu);
}
function patchChildren(old, neu) {
  const keyed = new Map();
  for (const c of old.childNodes) { const k = keyOf(c); if (k !== null && !keyed.has(k)) keyed.set(k, c); }
  const next = Array.from(neu.childNodes);
  next.forEach((n, i) => {
    const at = old.childNodes[i] ?? null, k = keyOf(n);
    let o = k !== null ? keyed.get(k) : at;
    if (k !== null) keyed.delete(k);  // a repeated key gets an element of its own
    else if (o !== null && keyOf(o) !== null) o = null;  // never reuse another row's element
    if (o && o.nodeType === n.nodeType && o.nodeName === n.nodeName) {
      patchNode(o, n);
      if (o !== at) old.insertBefore(o, at);
    } else {
      old.insertBefore(n, at);
    }
  });
  while (old.childNodes.length > next.length) old.removeChild(old.lastChild);
}

// A burst of events is one redraw: a redraw waits until the last one is REDRAW_MS old,
// so however fast events come (an incident floods the violations topic) the page keeps
// up and shows the present.  A redraw of a robot's page takes tens of ms in Chromium on
// a small machine; one per event fell tens of seconds behind.
const REDRAW_MS = 100;
function redrawer(render) {
  let pending = false, last = -Infinity;
  return () => {
    if (pending) return;
    pending = true;
    setTimeout(() => { pending = false; last = performance.now(); render(); },
      Math.max(0, last + REDRAW_MS - performance.now()));
  };
}
"""

PAGE = r"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<link rel="icon" href="data:,">
<title>safety-supervisor</title>
<style>
body { font: 14px/1.4 system-ui, sans-serif; margin: 0; color: #222; background: #f6f6f4; }
header { background: #263238; color: #fff; padding: 8px 16px; display: flex; gap: 16px;
         align-items: center; flex-wrap: wrap; }
header h1 { font-size: 18px; margin: 0; }
main { display: grid; grid-template-columns: minmax(0, 3fr) minmax(0, 2fr); gap: 12px; padding: 12px; }
section { background: #fff; border: 1px solid #ddd; border-radius: 6px; padding: 8px 12px; }
h2 { font-size: 15px; margin: 4px 0 8px; }
table { border-collapse: collapse; width: 100%; }
td, th { text-align: left; padding: 3px 6px; border-bottom: 1px solid #eee; vertical-align: top; }
/* a long name or value wraps inside its cell, never widens the table past its section */
td { overflow-wrap: anywhere; }
td button { overflow-wrap: normal; white-space: nowrap; }
th { font-weight: 600; color: #555; }
code { font-size: 12px; word-break: break-word; }
.muted { color: #777; }
.state { padding: 1px 8px; border-radius: 9px; font-weight: 600; white-space: nowrap; }
.vago { font-size: 12px; color: #b71c1c; font-weight: 600; white-space: nowrap; }
.state-holding { background: #c8e6c9; color: #1b5e20; }
.state-violated, .state-escalated { background: #ffcdd2; color: #b71c1c; }
.state-latched { background: #f8bbd0; color: #880e4f; }
.state-debouncing, .state-cooldown { background: #fff3c4; color: #8a6d00; }
.state-unknown { background: #eee; color: #555; }
.stale { color: #b71c1c; font-weight: 600; }
.ok { color: #1b5e20; } .fail { color: #b71c1c; font-weight: 600; }
#quiet { background: #ffcdd2; color: #b71c1c; padding: 2px 8px; border-radius: 4px; }
#conn.off { color: #ffab91; }
/* Not live: what is shown is the last document, not the robot now; nothing is green. */
body.notlive header { background: #7f1d1d; }
body.notlive .state-holding, body.notlive .state-live { background: #eee; color: #555; }
body.notlive .ok { color: #555; }
#feed { list-style: none; padding: 0; margin: 0; max-height: 420px; overflow-y: auto; }
#feed li { border-bottom: 1px solid #eee; padding: 2px 0; }
#feed .k { display: inline-block; min-width: 76px; font-weight: 600; }
#feed .violation .k { color: #b71c1c; } #feed .mitigation .k { color: #6a1b9a; }
#feed .reset .k, #feed .ui .k { color: #0d47a1; }
/* where one daemon's entries end and the next one's begin */
#feed li.restart { background: #eceff1; border-top: 2px solid #263238; font-weight: 600; padding: 4px; }
button { cursor: pointer; }
button:disabled { cursor: not-allowed; }
#tokenbox { display: none; margin-top: 6px; }
#resetmsg { margin-left: 8px; }
svg.spark { display: block; width: 120px; height: 24px; }
/* fixed columns: the sparkline keeps its 120 px whatever the names (which wrap) */
table.inputs { table-layout: fixed; }
table.inputs col.value { width: 7em; } table.inputs col.age { width: 6.5em; }
table.inputs col.spark { width: 132px; }
@media (max-width: 900px) { main { grid-template-columns: minmax(0, 1fr); } }
svg.spark polyline { fill: none; stroke: #1565c0; stroke-width: 1.5; }
.full { grid-column: 1 / -1; }
#trust { padding: 0 12px; }
#trust div { background: #fff3c4; color: #8a6d00; border: 1px solid #e0c96b; border-radius: 4px;
             padding: 4px 8px; margin-top: 8px; font-weight: 600; }
#trust-note { color: #777; font-size: 12px; margin: 6px 12px 0; }
/* a requirement's margin (docs/reference/margins.md): a gauge around 0, its value and
   unit, the trend's arrow; an open prediction in its own colour */
.margin { font-size: 12px; margin-top: 4px; white-space: nowrap; }
svg.gauge { display: inline-block; vertical-align: middle; width: 80px; height: 12px; }
svg.gauge .bg { fill: #eee; } svg.gauge .zero { stroke: #555; stroke-width: 1; }
svg.gauge .pos { fill: #43a047; } svg.gauge .neg { fill: #e53935; }
.predicted { display: block; background: #ffe0b2; color: #e65100; font-weight: 600;
             border-radius: 4px; padding: 0 6px; margin-top: 2px; }
</style>
</head>
<body data-live="0">
<header>
  <h1>safety-supervisor</h1>
  <a id="fleet-link" href="__FLEET__" style="color:#fff">fleet</a>
  <span id="component" class="muted"></span>
  <span id="supervisor"></span>
  <span id="quiet" hidden></span>
  <span id="conn" class="off">connecting</span>
</header>
<div id="trust">
  <div id="trust-invalid" hidden></div>
  <div id="trust-publishers" hidden></div>
</div>
<p id="trust-note">What this page shows comes from the supervisor's status topic, which any
node of the ROS domain can publish: it is a view, not evidence (the violation log is).
Resets never go where the topic says, only to the control socket this UI was configured with.
Close the domain to other nodes with SROS2 (DDS Security) enclaves, a private
ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE.</p>
<main>
<section class="full" id="health-section">
  <h2>Supervisor</h2>
  <table><tbody id="health"></tbody></table>
</section>
<section id="req-section">
  <h2>Requirements</h2>
  <div>
    <button id="reset-all" disabled>Reset all</button>
    <span id="resetmsg" class="muted"></span>
    <form id="tokenbox">
      <label>Token for resets: <input type="password" id="token" size="40" autocomplete="off"></label>
      <button id="token-save">Use</button>
    </form>
  </div>
  <table>
    <thead><tr><th>requirement</th><th>state</th><th>violations</th><th>last violation</th>
      <th>mitigations</th><th></th></tr></thead>
    <tbody id="requirements"></tbody>
  </table>
</section>
<section id="side">
  <div id="opview-section" style="display:none">
    <h2>Operational state</h2>
    <svg id="opview" viewBox="0 0 460 220" width="100%" role="img"></svg>
  </div>
  <h2>Inputs</h2>
  <table class="inputs">
    <colgroup><col><col class="value"><col class="age"><col class="spark"></colgroup>
    <thead><tr><th>input</th><th>value</th><th>age</th><th>last seconds</th></tr></thead>
    <tbody id="inputs"></tbody>
  </table>
</section>
<section class="full">
  <h2>Events</h2>
  <ul id="feed"></ul>
</section>
</main>
<script nonce="__NONCE__">
"use strict";
/*__PATCH__*/
const SPARK_S = 30;          // seconds of values a sparkline shows
// No status document for LIVE_PERIODS of the period the documents announce
// (status_period_s, the daemon's ros.status_ms), at least LIVE_MIN_S: not live.  A
// document without it (or /diagnostics alone) gets QUIET_DEFAULT_S, as the fleet does
// (fleet.py; docs/reference/commands.md, ui).  Measured on this browser's clock, so a
// broken stream is noticed as well as a dead daemon.
const LIVE_PERIODS = 3, LIVE_MIN_S = 1.0, QUIET_DEFAULT_S = 3.0;
const FEED_MAX = 200;
// A requirement shows "violated N s ago", in red, for HOLD_S after each violation
// (ui --violated-for; a policy often resets it within milliseconds), and the most recently
// violated come first.
const HOLD_S = Number("__HOLD_S__") >= 0 ? Number("__HOLD_S__") : 60;
const TOKEN_KEY = "safety-supervisor-ui-token";
const BASE = "__BASE__";     // this robot's paths in the fleet ("" for the one robot)
if (!"__FLEET__") document.getElementById("fleet-link").remove();
const ZONES = [[3, "red"], [7, "yellow"]];   // sRobot: red < 3 m, yellow 3-7 m, green beyond
const CLASSES = {0: "nobody", 1: "trained worker", 2: "untrained person"};
const OPSTATES = {0: "normal", 1: "alert", 2: "alert + slow down", 3: "stop + UV off"};

const M = {
  status: null, statusAt: null, diag: {requirements: {}, inputs: {}}, diagAt: null,
  learned: {}, seen: {}, values: {}, reset: {available: false, why: "connecting"},
  lastAt: {},  // requirement -> its last violation on this page's clock (now())
  hist: {}, feed: [], connected: false, invalid: {count: 0}, publishers: [],
  marginMax: {},  // requirement -> the largest finite |margin| seen: its gauge's full scale
};
const $ = (id) => document.getElementById(id);
const esc = (s) => String(s ?? "").replace(/[&<>"']/g,
  (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}[c]));
const now = () => performance.now();
// Every value's type is checked before use: the server checks the documents
// (schema.py), and the page does not rely on it.  Data goes into the page only
// escaped (esc) or as textContent, never as markup.
const num = (v) => typeof v === "number" && Number.isFinite(v) ? v : null;
const arr = (v) => Array.isArray(v) ? v : [];
const obj = (v) => v !== null && typeof v === "object" && !Array.isArray(v) ? v : {};
const fixed = (v, d) => num(v) == null ? "?" : num(v).toFixed(d);
const fmtAge = (s) => num(s) == null ? "never" : (s < 10 ? s.toFixed(1) : s.toFixed(0)) + " s";
const fmtTs = (ts) => typeof ts === "string" ? ts.replace("T", " ").replace(/\.\d+Z$/, "Z") : "";
// a daemon's time (microseconds) in ms since the epoch, or NaN
const parseTs = (ts) => typeof ts === "string" ? Date.parse(ts.replace(/(\.\d{3})\d*Z$/, "$1Z")) : NaN;
const fmtAgo = (s) => s < 120 ? Math.floor(s) + " s" : Math.floor(s / 60) + " min";

// Values at their type's precision: a double as Python writes it (repr), a float32
// field's value (precision "float32") as the shortest text that reads back as the
// same float32 (0.8, not 0.800000011920929), integers and bools as they are.
function pyFloat(v, digits) {
  if (Object.is(v, -0)) return "-0.0";
  if (v === 0) return "0.0";
  // toExponential() without digits gives the shortest that reads back as v
  const [m, e] = (digits ? v.toExponential(digits - 1) : v.toExponential()).split("e");
  const d = m.replace("-", "").replace(".", "").replace(/0+$/, "") || "0";
  const x = Number(e), sign = v < 0 ? "-" : "";
  if (x < -4 || x >= 16) {
    return sign + (d.length > 1 ? d[0] + "." + d.slice(1) : d) + "e" + (x < 0 ? "-" : "+") +
      String(Math.abs(x)).padStart(2, "0");
  }
  if (x < 0) return sign + "0." + "0".repeat(-x - 1) + d;
  if (d.length <= x + 1) return sign + d + "0".repeat(x + 1 - d.length) + ".0";
  return sign + d.slice(0, x + 1) + "." + d.slice(x + 1);
}
function fmtValue(v, type, precision) {
  if (v === undefined) return "?";
  if (typeof v !== "number") return typeof v === "string" ? v : JSON.stringify(v);
  if (!Number.isFinite(v)) return String(v);
  if (precision === "float32" && Math.fround(v) === v) {
    for (let p = 1; p <= 9; p++) if (Math.fround(Number(v.toExponential(p - 1))) === v) return pyFloat(v, p);
  }
  if (type === "double") return pyFloat(v);
  return String(v);
}
const fmtDur = (s) => {
  s = Math.floor(num(s) || 0); const h = Math.floor(s / 3600), m = Math.floor(s % 3600 / 60);
  return (h ? h + " h " : "") + (h || m ? m + " min " : "") + (s % 60) + " s";
};

function onStatus(doc, age) {
  if (typeof doc !== "object" || doc === null) return;
  M.status = doc;
  M.statusAt = now() - 1000 * (num(age) || 0);
  M.seen = {};  // the document's counts include what the topic showed
  // each last violation on this page's clock: its age at the document's "now"
  const docNow = parseTs(doc.now);
  for (const r of arr(doc.requirements)) {
    const age = (docNow - parseTs(obj(r).last_violation)) / 1000;
    if (!Number.isFinite(age) || typeof r.id !== "string") continue;
    const at = M.statusAt - 1000 * Math.max(age, 0);
    if (!(M.lastAt[r.id] >= at)) M.lastAt[r.id] = at;
  }
  const t = Date.now() / 1000;
  for (const inp of arr(doc.inputs)) {
    if (typeof inp.name !== "string") continue;
    M.values[inp.name] = inp.value;
    const v = num(typeof inp.value === "boolean" ? +inp.value : inp.value);
    if (v == null) continue;
    const h = M.hist[inp.name] || (M.hist[inp.name] = []);
    h.push([t - (num(inp.age_s) || 0), v]);
    while (h.length && h[0][0] < t - SPARK_S) h.shift();
  }
}

function onViolation(rec) {
  const rid = String(obj(rec).requirement ?? "");
  M.learned[rid] = {text: rec.text, formula: rec.formula};
  const s = M.seen[rid] || (M.seen[rid] = {n: 0});
  s.n += 1; s.last = new Date().toISOString();
  M.lastAt[rid] = now();
  for (const [k, v] of Object.entries(obj(rec.inputs))) if (!(k in M.values)) M.values[k] = v;
}

function addFeed(entries) {
  for (const e of arr(entries)) M.feed.unshift(obj(e));
  M.feed.length = Math.min(M.feed.length, FEED_MAX);
}

function handle(msg) {
  msg = obj(msg);
  if (msg.reset) M.reset = obj(msg.reset);
  if (msg.invalid) M.invalid = obj(msg.invalid);
  if (msg.publishers) M.publishers = arr(msg.publishers);
  if (msg.type === "snapshot") {
    M.feed = []; addFeed(msg.feed);
    if (msg.status) onStatus(msg.status, msg.status_age_s);
    if (msg.diagnostics) { M.diag = msg.diagnostics; M.diagAt = now(); }
  } else if (msg.type === "status") {
    onStatus(msg.status, 0); addFeed(msg.feed);
  } else if (msg.type === "violation") {
    onViolation(msg.record); addFeed(msg.feed);
  } else if (msg.type === "diagnostics") {
    M.diag = msg.diagnostics; M.diagAt = now();
    if (!M.status) M.seen = {};  // its counts include what the topic showed
  } else if (msg.type === "feed") {
    addFeed(msg.feed);
  }
  redraw();
}
const redraw = redrawer(render);

// The status topic is open to any node of the domain: what the UI refused, and
// whether another node publishes it too (docs/reference/ros-interfaces.md).
function renderTrust() {
  const inv = M.invalid, bad = $("trust-invalid"), pubs = $("trust-publishers");
  bad.hidden = !(num(inv.count) > 0);
  bad.textContent = bad.hidden ? "" : `invalid status from ${String(inv.publisher ?? "?")}, ` +
    `not shown (${num(inv.count)} so far; the last at ${fmtTs(inv.at)}): ${String(inv.why ?? "")}`;
  const names = M.publishers.map(String);
  pubs.hidden = names.length < 2;
  pubs.textContent = pubs.hidden ? "" : `${names.length} nodes publish the status topic: ` +
    `${names.join(", ")}. Only one is the supervisor; what this page shows may be forged.`;
}

// ------------------------------------------------------------------ rendering

function requirements() {
  if (M.status) return arr(M.status.requirements);
  return Object.values(M.diag.requirements || {}).map((r) => ({
    id: r.id, state: r.state, violations: r.violations, actions: [],
    text: (M.learned[r.id] || {}).text, formula: (M.learned[r.id] || {}).formula,
  }));
}

function inputs() {
  if (M.status) return arr(M.status.inputs);
  const since = M.diagAt == null ? 0 : (now() - M.diagAt) / 1000;
  return Object.values(M.diag.inputs || {}).map((i) => ({
    name: i.name, topic: i.topic, value: M.values[i.name], stale: i.stale,
    age_s: i.age_s == null ? null : i.age_s, _since: since,
  }));
}

function quietAfter() {
  const p = M.status ? num(M.status.status_period_s) : null;
  return p ? Math.max(LIVE_PERIODS * p, LIVE_MIN_S) : QUIET_DEFAULT_S;
}

function render() {
  const st = M.status;
  $("component").textContent = st ? String(st.component ?? "") : "";
  $("supervisor").textContent = st ? String(st.supervisor ?? "") : (M.diagAt ? "(from /diagnostics)" : "");
  renderTrust(); renderHealth(); renderRequirements(); renderInputs(); renderFeed(); renderOpView(); tick();
}

function renderHealth() {
  const st = M.status;
  const rows = [];
  if (!st) {
    rows.push(["status", "no status document yet (a daemon without the status topic shows " +
               "requirements and inputs from /diagnostics only)"]);
  } else {
    const wd = obj(st.watchdog);
    rows.push(["config", `<code>${esc(st.config)}</code> sha256 <code>${esc(String(st.config_sha256 ?? "").slice(0, 16))}</code>`]);
    rows.push(["uptime", `<span id="uptime">${esc(fmtDur(st.uptime_s))}</span> (pid ${esc(st.pid)}, since ${esc(fmtTs(st.started))})`]);
    rows.push(["step", `${esc(st.policy)}: ${esc(st.ticks)} ticks, ${esc(fixed(st.tick_rate_hz, 1))} ticks/s`]);
    rows.push(["received", `${esc(st.received)} messages, ${esc(fixed(st.receive_rate_hz, 1))} msg/s, ` +
               `<span class="${num(st.lost) ? "fail" : ""}">${esc(st.lost)} lost</span>`]);
    if (num(st.events_dropped)) rows.push(["events", `<span class="fail">${esc(st.events_dropped)} not shown (more than a document holds)</span>`]);
    rows.push(["violations", `${esc(st.violations)}; reloads ${esc(st.reloads)}; recording ${st.recording === true ? "on" : "off"}`]);
    rows.push(["watchdog", wd.enabled === true ? `on, every ${esc(fixed(wd.interval_s, 1))} s` : "off (not under systemd)"]);
  }
  // the socket this UI is configured with, never the one the document names
  rows.push(["resets", M.reset.available ? `through <code>${esc(M.reset.socket)}</code>`
             : `<span class="muted">unavailable: ${esc(M.reset.why)}</span>`]);
  patch($("health"), rows.map(([k, v]) => `<tr><th>${esc(k)}</th><td>${v}</td></tr>`).join(""));
  $("reset-all").disabled = !M.reset.available;
}

// Seconds since the requirement's last violation while within HOLD_S, else null.
function heldFor(id) {
  const at = M.lastAt[id];
  if (typeof at !== "number") return null;
  const s = (now() - at) / 1000;
  return s < HOLD_S ? Math.max(s, 0) : null;
}
const PRESSING = ["latched", "escalated", "violated"];
let heldShown = "";  // the requirements shown as recently violated, to re-render on change

// A requirement's margin as a gauge: the bar from 0 to the margin, scaled by the
// largest finite margin this page saw of it (an infinite one fills its half); its
// value, unit and trend's arrow (margin units per second); an open prediction's
// time to violation.  Nothing when margins are off.
function gauge(r) {
  if (r.margin == null) return "";
  const m = obj(r.margin);
  const v = m.value, x = num(v);
  const inf = v === "inf" ? 1 : v === "-inf" ? -1 : 0;
  if (x == null && !inf) return "";
  const top = Math.max(M.marginMax[r.id] || 0, x == null ? 0 : Math.abs(x));
  M.marginMax[r.id] = top;
  const frac = inf || (top > 0 ? x / top : 0);
  const w = Math.abs(frac) * 39, at = frac >= 0 ? 40 : 40 - w;
  const shown = inf ? (inf > 0 ? "+\u221e" : "-\u221e") : Number(x.toPrecision(4)).toString();
  const t = num(m.trend_per_s);
  const arrow = t == null ? "" : t > 0 ? "\u2191" : t < 0 ? "\u2193" : "\u2192";
  const trend = t == null ? "" : ` <span class="trend" title="${esc(m.trend_from)}">${arrow} ` +
    `${esc(Number(t.toPrecision(3)))}/s</span>`;
  const unit = typeof m.unit === "string" && m.unit ? ` <span class="muted">(${esc(m.unit)})</span>` : "";
  const p = m.prediction == null ? null : obj(m.prediction);
  const ttv = p && num(p.ttv_ms) != null ? `in ${esc((p.ttv_ms / 1000).toFixed(1))} s` : "ahead";
  const pred = p ? `<span class="predicted" data-ttv-ms="${esc(num(p.ttv_ms))}">violation predicted ${ttv}</span>` : "";
  return `<div class="margin" data-margin="${esc(inf ? v : x)}">margin ` +
    `<svg class="gauge" viewBox="0 0 80 12"><rect class="bg" x="0" y="2" width="80" height="8"/>` +
    `<rect class="${frac >= 0 ? "pos" : "neg"}" x="${at.toFixed(1)}" y="2" width="${w.toFixed(1)}" height="8"/>` +
    `<line class="zero" x1="40" y1="0" x2="40" y2="12"/></svg> ` +
    `<span class="value">${esc(shown)}</span>${unit}${trend}${pred}</div>`;
}

function renderRequirements() {
  // the most recently violated first; the others in the document's order (stable sort)
  const list = requirements().map((r) => obj(r));
  const at = (r) => typeof M.lastAt[r.id] === "number" ? M.lastAt[r.id] : -Infinity;
  list.sort((a, b) => at(b) - at(a));
  const held = [];
  const rows = list.map((r) => {
    const seen = M.seen[r.id];
    const daemonState = seen ? "violated" : String(r.state || "unknown");
    const ago = heldFor(r.id);
    if (ago != null) held.push(r.id);
    // a requirement reset at once still shows its violation, in its colour
    const state = ago != null && !PRESSING.includes(daemonState) ? "violated" : daemonState;
    const badge = ago != null && state === "violated"
      ? `<span class="state state-violated">violated <span class="since" data-at="${esc(M.lastAt[r.id])}">${esc(fmtAgo(ago))}</span> ago</span>`
      : `<span class="state state-${esc(state)}">${esc(state)}</span>` +
        (ago != null ? `<div class="vago">violated <span class="since" data-at="${esc(M.lastAt[r.id])}">${esc(fmtAgo(ago))}</span> ago</div>` : "");
    const count = (num(r.violations) || 0) + (seen ? seen.n : 0);
    const last = seen ? seen.last : r.last_violation;
    const acts = arr(r.actions).map((a) => obj(a)).map((a) =>
      `<div class="${a.ok === true ? "ok" : "fail"}">${esc(a.action)} (${esc(a.stage)}) ${a.ok === true ? "ok" : "failed"}` +
      `${num(a.latency_ms) != null ? ", " + esc(fixed(a.latency_ms, 1)) + " ms" : ""}` +
      ` <span class="muted">${esc(fmtTs(a.ts))}</span></div>`).join("");
    const learned = M.learned[r.id] || {};
    const text = r.text || learned.text || "";
    const formula = r.formula || learned.formula || "";
    const staleIn = arr(r.stale_inputs).map(String);
    const stale = staleIn.length ? `<div class="stale">stale: ${esc(staleIn.join(", "))}</div>` : "";
    return `<tr class="req" data-key="${esc(r.id)}" data-requirement="${esc(r.id)}" data-state="${esc(state)}" ` +
      `data-daemon-state="${esc(daemonState)}" data-violations="${esc(count)}">` +
      `<td><b>${esc(r.id)}</b><div>${esc(text)}</div><code class="muted">${esc(formula)}</code></td>` +
      `<td>${badge}${stale}${gauge(r)}</td>` +
      `<td>${esc(count)}</td><td>${esc(fmtTs(last))}</td><td>${acts}</td>` +
      `<td><button class="reset-one" data-requirement="${esc(r.id)}" ${M.reset.available ? "" : "disabled"}>Reset</button></td></tr>`;
  });
  patch($("requirements"), rows.join("") ||
    `<tr><td colspan="6" class="muted">no requirements known yet</td></tr>`);
  heldShown = held.sort().join("\n");
}

function spark(name) {
  const h = M.hist[name] || [];  // numbers only (onStatus)
  if (h.length < 2) return `<svg class="spark" viewBox="0 0 120 24"></svg>`;
  const t1 = Date.now() / 1000, t0 = t1 - SPARK_S;
  let lo = Math.min(...h.map((p) => p[1])), hi = Math.max(...h.map((p) => p[1]));
  if (hi === lo) { hi += 1; lo -= 1; }
  const pts = h.map(([t, v]) => `${(120 * (t - t0) / SPARK_S).toFixed(1)},${(22 - 20 * (v - lo) / (hi - lo)).toFixed(1)}`);
  pts.push(`120,${pts[pts.length - 1].split(",")[1]}`);  // the value holds until now
  return `<svg class="spark" viewBox="0 0 120 24"><polyline points="${pts.join(" ")}"/></svg>`;
}

function renderInputs() {
  const rows = inputs().map((i) => obj(i)).map((i) =>
    `<tr class="input" data-key="${esc(i.name)}" data-input="${esc(i.name)}" data-stale="${i.stale === true ? 1 : 0}">` +
    `<td><b>${esc(i.name)}</b><div class="muted">${esc(i.topic)}</div></td>` +
    `<td class="value">${esc(fmtValue(i.value, i.type, i.precision))}</td>` +
    `<td><span class="age" data-age="${esc(num(i.age_s) ?? "")}">${esc(fmtAge(i.age_s))}</span>` +
    `${i.stale === true ? ' <span class="stale">stale</span>' : ""}</td><td>${spark(i.name)}</td></tr>`);
  patch($("inputs"), rows.join("") || `<tr><td colspan="4" class="muted">no inputs known yet</td></tr>`);
}

function renderFeed() {
  patch($("feed"), M.feed.map((e) =>
    `<li class="ev ${esc(e.event)}" data-event="${esc(e.event)}" data-requirement="${esc(e.requirement)}">` +
    `<span class="muted">${esc(fmtTs(e.ts))}</span> <span class="k">${esc(e.event)}</span> ` +
    `${esc(e.requirement)} ${esc(e.what)} <span class="muted">${esc(e.detail)}</span></li>`).join(""));
}

function renderOpView() {
  const names = new Set(inputs().map((i) => i.name));
  const shown = ["distance_to_target", "classifier", "OpState"].every((n) => names.has(n));
  $("opview-section").style.display = shown ? "" : "none";
  if (!shown) { $("opview").innerHTML = ""; return; }
  const d = Number(M.values.distance_to_target), cls = Number(M.values.classifier);
  const op = Number(M.values.OpState);
  const X0 = 40, Y0 = 110, PX = 30, MAXM = 13;   // robot position, pixels per metre
  const zone = !(d >= 0) ? "?" : d < 3 ? "red" : d <= 7 ? "yellow" : "green";
  let s = `<rect x="0" y="0" width="460" height="220" fill="#c8e6c9"/>` +
    `<circle cx="${X0}" cy="${Y0}" r="${7 * PX}" fill="#fff59d"/>` +
    `<circle cx="${X0}" cy="${Y0}" r="${3 * PX}" fill="#ef9a9a"/>` +
    `<rect x="${X0 - 16}" y="${Y0 - 11}" width="32" height="22" rx="4" fill="#37474f"/>` +
    `<text x="${X0}" y="${Y0 + 28}" text-anchor="middle" font-size="11">robot</text>`;
  for (const [m] of ZONES) s += `<text x="${X0 + m * PX + 2}" y="14" font-size="10">${m} m</text>`;
  if (cls > 0 && d >= 0) {
    const x = X0 + Math.min(d, MAXM) * PX, colour = cls === 1 ? "#0d47a1" : "#e65100";
    s += `<g id="person" data-distance="${d}"><circle cx="${x}" cy="${Y0 - 18}" r="6" fill="${colour}"/>` +
      `<line x1="${x}" y1="${Y0 - 12}" x2="${x}" y2="${Y0 + 6}" stroke="${colour}" stroke-width="3"/>` +
      `<line x1="${x}" y1="${Y0 + 6}" x2="${x - 6}" y2="${Y0 + 18}" stroke="${colour}" stroke-width="3"/>` +
      `<line x1="${x}" y1="${Y0 + 6}" x2="${x + 6}" y2="${Y0 + 18}" stroke="${colour}" stroke-width="3"/></g>`;
  }
  s += `<text x="10" y="192" font-size="12" id="opstate"><tspan>${esc(CLASSES[cls] || "class " + cls)}` +
    `${cls > 0 ? ` at ${esc(d)} m (${zone} zone)` : ""}</tspan>` +
    `<tspan x="10" dy="15">controller OpState ${esc(op)}: ${esc(OPSTATES[op] || "?")}</tspan></text>`;
  $("opview").innerHTML = s;
}

// Between updates: input ages and uptime tick, and a quiet daemon is said (not live).
function tick() {
  const t = now();
  // a violation's "N s ago" counts up; past HOLD_S its requirement shows its own state
  const held = requirements().map((r) => obj(r).id).filter((id) => heldFor(id) != null);
  if (held.sort().join("\n") !== heldShown) renderRequirements();
  for (const el of document.querySelectorAll("span.since[data-at]")) {
    el.textContent = fmtAgo(Math.max(t - Number(el.dataset.at), 0) / 1000);
  }
  const since = M.status ? (t - M.statusAt) / 1000 : (M.diagAt == null ? 0 : (t - M.diagAt) / 1000);
  for (const el of document.querySelectorAll(".age")) {
    if (el.dataset.age === "") continue;
    el.textContent = fmtAge(Number(el.dataset.age) + since);
  }
  // live: the stream is open and a document came within the bound
  const heard = M.status != null || M.diagAt != null;
  const quiet = heard && since > quietAfter();
  const up = $("uptime");  // a supervisor not heard from has no uptime beyond its last document
  if (up && M.status) up.textContent = fmtDur((num(M.status.uptime_s) || 0) + (quiet ? 0 : since));
  const live = M.connected && heard && !quiet;
  $("quiet").hidden = !quiet;
  $("quiet").textContent = quiet ? `no status for ${Math.floor(since)} s` : "";
  $("conn").textContent = !M.connected ? "reconnecting" : live ? "live" : quiet ? "not live" : "waiting for status";
  $("conn").className = live ? "" : "off";
  document.body.dataset.live = live ? "1" : "0";
  document.body.classList.toggle("notlive", !live);
}
setInterval(tick, 200);

// ------------------------------------------------------------------ resets

function askToken(why) {
  $("tokenbox").style.display = "block";
  $("resetmsg").textContent = why;
  $("token").focus();
}

async function reset(requirement) {
  const token = sessionStorage.getItem(TOKEN_KEY);
  if (!token) { askToken("a token is needed for resets"); M.pending = requirement; return; }
  const body = requirement ? {requirement} : {};
  $("resetmsg").textContent = "resetting ...";
  let res;
  try {
    res = await fetch(BASE + "/api/reset", {
      method: "POST", headers: {"Content-Type": "application/json", "Authorization": "Bearer " + token},
      body: JSON.stringify(body),
    });
  } catch (e) { $("resetmsg").textContent = "the UI did not answer"; return; }
  const answer = await res.json().catch(() => ({message: res.statusText}));
  if (res.status === 401) { sessionStorage.removeItem(TOKEN_KEY); askToken("wrong token"); return; }
  $("resetmsg").textContent = answer.message || res.statusText;
}

$("reset-all").addEventListener("click", () => reset(null));
$("requirements").addEventListener("click", (e) => {
  const b = e.target.closest("button.reset-one");
  if (b) reset(b.dataset.requirement);
});
$("tokenbox").addEventListener("submit", (e) => {
  e.preventDefault();  // the token stays in this page (sessionStorage), never in a URL
  const v = $("token").value.trim();
  if (!v) return;
  sessionStorage.setItem(TOKEN_KEY, v); $("token").value = ""; $("tokenbox").style.display = "none";
  const pending = M.pending; M.pending = undefined; reset(pending);
});

// ------------------------------------------------------------------ live updates

function connect() {
  const es = new EventSource(BASE + "/events");
  es.onopen = () => { M.connected = true; render(); };
  es.onmessage = (e) => {
    let msg;
    try { msg = JSON.parse(e.data); } catch (err) { return; }  // the server sends JSON only
    handle(msg);
  };
  es.onerror = () => { M.connected = false; render(); };  // EventSource reconnects itself
}
render();
connect();
</script>
</body>
</html>
"""

# The fleet page: one row per supervisor, each linking to its robot's page.  Rows are
# never removed: a supervisor whose status stops is LOST, in red, with when it was
# last seen (its row's ``lost_after_s``: 3 status periods; docs/reference/commands.md).
FLEET_PAGE = r"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<link rel="icon" href="data:,">
<title>safety-supervisor fleet</title>
<style>
body { font: 14px/1.4 system-ui, sans-serif; margin: 0; color: #222; background: #f6f6f4; }
header { background: #263238; color: #fff; padding: 8px 16px; display: flex; gap: 16px;
         align-items: center; }
header h1 { font-size: 18px; margin: 0; }
main { padding: 12px; }
section { background: #fff; border: 1px solid #ddd; border-radius: 6px; padding: 8px 12px; }
table { border-collapse: collapse; width: 100%; }
td, th { text-align: left; padding: 3px 6px; border-bottom: 1px solid #eee; vertical-align: top; }
th { font-weight: 600; color: #555; }
.muted { color: #777; }
.state { padding: 1px 8px; border-radius: 9px; font-weight: 600; white-space: nowrap; }
.state-live { background: #c8e6c9; color: #1b5e20; }
.state-lost { background: #d32f2f; color: #fff; }
.state-waiting { background: #eee; color: #555; }
tr.lost td { color: #b71c1c; }
.open { color: #b71c1c; font-weight: 600; }
.fail { color: #b71c1c; font-weight: 600; }
#conn.off { color: #ffab91; }
</style>
</head>
<body>
<header>
  <h1>safety-supervisor fleet</h1>
  <span id="count" class="muted"></span>
  <span id="conn" class="off">connecting</span>
</header>
<main>
<section>
  <table>
    <thead><tr><th>robot</th><th>state</th><th>host</th><th>component</th><th>config</th>
      <th>uptime</th><th>ticks/s</th><th>msg/s</th><th>lost msgs</th><th>open violations</th>
      <th>last status</th></tr></thead>
    <tbody id="robots"></tbody>
  </table>
</section>
</main>
<script nonce="__NONCE__">
"use strict";
/*__PATCH__*/
const R = {};               // robot id -> {row, at: performance.now() when received}
let connected = false;
const $ = (id) => document.getElementById(id);
const esc = (s) => String(s ?? "").replace(/[&<>"']/g,
  (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}[c]));
const num = (v, d) => v == null ? "" : Number(v).toFixed(d);
const fmtAge = (s) => s == null ? "never" : (s < 10 ? s.toFixed(1) : s.toFixed(0)) + " s ago";
const fmtTs = (ts) => ts ? String(ts).replace("T", " ").replace(/\.\d+Z$/, "Z") : "";
const fmtDur = (s) => {
  if (s == null) return "";
  s = Math.floor(s); const h = Math.floor(s / 3600), m = Math.floor(s % 3600 / 60);
  return (h ? h + " h " : "") + (h || m ? m + " min " : "") + (s % 60) + " s";
};

function age(e) {
  return e.row.age_s == null ? null : e.row.age_s + (performance.now() - e.at) / 1000;
}

// Any node of a domain can publish a robot's status topic: refused documents and a
// second publisher are said on its row (docs/reference/ros-interfaces.md).
function trust(r) {
  const n = Number(r.invalid) || 0, p = Number(r.publishers) || 0;
  return (n > 0 ? ` <div class="fail trust-invalid">${esc(n)} invalid status documents</div>` : "") +
    (p > 1 ? ` <div class="fail trust-publishers">${esc(p)} publishers of its status topic</div>` : "");
}

function render() {
  $("conn").textContent = connected ? "live" : "reconnecting";
  $("conn").className = connected ? "" : "off";
  const entries = Object.values(R).sort((a, b) => a.row.name.localeCompare(b.row.name));
  let lost = 0;
  patch($("robots"), entries.map((e) => {
    const r = e.row, a = age(e);
    const state = a == null ? "waiting" : (a > r.lost_after_s ? "lost" : "live");
    if (state === "lost") lost += 1;
    const where = `domain ${esc(r.domain)}, ${esc(r.topic)}${r.configured ? "" : " (discovered)"}`;
    const label = state === "lost" ? `LOST <span class="muted" style="color:#fff">since ${esc(fmtTs(r.last_seen))}</span>`
      : state === "waiting" ? "no status yet" : "live";
    const open = (r.open || []).length
      ? `<span class="open">${r.open.length}</span> <span class="muted">${esc(r.open.join(", "))}</span>` : "0";
    const uptime = state === "live" && r.uptime_s != null ? r.uptime_s + (performance.now() - e.at) / 1000 : r.uptime_s;
    return `<tr class="robot ${state}" data-key="${esc(r.id)}" data-robot="${esc(r.id)}" data-state="${state}" data-open="${(r.open || []).length}">` +
      `<td><a href="/robot/${encodeURIComponent(r.id)}"><b>${esc(r.name)}</b></a><div class="muted">${where}</div></td>` +
      `<td><span class="state state-${state}">${label}</span>${trust(r)}</td>` +
      `<td>${esc(r.host)}</td><td>${esc(r.component)}</td>` +
      `<td><code>${esc((r.config_sha256 || "").slice(0, 12))}</code></td>` +
      `<td>${esc(fmtDur(uptime))}</td><td>${num(r.tick_rate_hz, 1)}</td><td>${num(r.receive_rate_hz, 1)}</td>` +
      `<td class="${r.lost ? "fail" : ""}">${esc(r.lost)}</td><td>${open}</td>` +
      `<td class="age">${esc(fmtAge(a))}</td></tr>`;
  }).join("") || `<tr><td colspan="11" class="muted">no supervisors known yet</td></tr>`);
  $("count").textContent = `${entries.length} supervisors` + (lost ? `, ${lost} lost` : "");
}
setInterval(render, 250);   // ages tick and a silent robot turns LOST between updates

function handle(msg) {
  const t = performance.now();
  if (msg.type === "snapshot") {
    for (const r of msg.robots) R[r.id] = {row: r, at: t};  // rows are never removed
  } else if (msg.type === "robot") {
    R[msg.robot.id] = {row: msg.robot, at: t};
  }
  redraw();
}
const redraw = redrawer(render);

function connect() {
  const es = new EventSource("/fleet/events");
  es.onopen = () => { connected = true; render(); };
  es.onmessage = (e) => { let m; try { m = JSON.parse(e.data); } catch (err) { return; } handle(m); };
  es.onerror = () => { connected = false; render(); };  // EventSource reconnects itself
}
render();
connect();
</script>
</body>
</html>
"""

PAGE = PAGE.replace("/*__PATCH__*/", PATCH_JS)
FLEET_PAGE = FLEET_PAGE.replace("/*__PATCH__*/", PATCH_JS)
