// retrocomp live page: polls /status at 4 Hz and the history/log endpoints at 0.5–1 Hz, renders
// with plain DOM and uPlot (embedded, no network beyond the box). Corrections in µm, sign as in
// /status (correction = −error). No framework: the page must work offline on the shop floor.
"use strict";

const $ = (s) => document.querySelector(s);
const el = (tag, attrs = {}, ...kids) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v; else if (k === "text") e.textContent = v; else e.setAttribute(k, v);
  }
  for (const k of kids) e.append(k);
  return e;
};
const um = (v) => (v === null || v === undefined || !isFinite(v)) ? "–" : (v >= 0 ? "+" : "−") + Math.abs(v).toFixed(3);
const when = (unix) => new Date(unix * 1000).toLocaleTimeString([], { hour12: false });
// "0.04 s", "12 s", "3 min": how old a reading is.
const ageText = (s) => s === null ? "–" : s < 10 ? s.toFixed(2) + " s" : s < 120 ? s.toFixed(0) + " s" : (s / 60).toFixed(0) + " min";
const day = (unix) => new Date(unix * 1000).toLocaleString([], { hour12: false });

let lastOk = 0;
let snap = null;
let windowKind = "fine";
const plots = {};

async function getJson(path) {
  const r = await fetch(path, { cache: "no-store" });
  if (!r.ok) throw new Error(path + ": " + r.status);
  return r.json();
}

function banner() {
  const b = $("#banner");
  const stale = Date.now() - lastOk > 2000;
  let cls = "ok", text = "COMPENSATING";
  if (!snap) { cls = "wait"; text = "WAITING FOR DATA"; }
  if (snap && stale) { cls = "bad"; text = "NO DATA FROM GATEWAY"; }
  else if (snap && snap.active_faults.length) { cls = "bad"; text = `FAULT (${snap.active_faults.length})`; }
  else if (snap && snap.model_error) { cls = "bad"; text = "MODEL ERROR"; }
  else if (snap && !snap.enabled) { cls = "warn"; text = "COMPENSATION DISABLED"; }
  else if (snap && snap.axes.some((a) => a.mode !== "tracking")) { cls = "warn"; text = "OUTPUT RAMPING OR HELD"; }
  b.className = "banner " + cls;
  b.textContent = text;
}

function renderAxes(s) {
  const box = $("#axes");
  box.replaceChildren();
  const maxTerm = Math.max(1e-9, ...s.axes.flatMap((a) => Object.values(a.terms_um).map(Math.abs)));
  for (const a of s.axes) {
    const cls = a.mode === "tracking" ? "" : "warn";
    const rows = Object.entries(a.terms_um).map(([t, v]) => el("tr", {},
      el("td", { text: t }),
      el("td", { class: "v", text: um(v) + " µm" }),
      el("td", {}, el("span", { class: "bar" + (v < 0 ? " neg" : ""), style: `width:${(80 * Math.abs(v) / maxTerm).toFixed(0)}px` }))));
    box.append(el("div", { class: "card " + cls, "data-axis": a.axis },
      el("h2", { text: `axis ${a.axis} · applied correction` }),
      el("div", { class: "big" }, el("span", { class: "applied", "data-value": String(a.applied_um), text: um(a.applied_um) }), el("small", { text: " µm" })),
      el("div", {}, "model asks ", el("b", { class: "target", text: um(a.target_um) + " µm" }),
        " · mode ", el("span", { class: "mode", text: a.mode })),
      el("div", { class: "meta", text: `position ${a.position_mm === null ? "–" : a.position_mm.toFixed(3) + " mm"} · ${a.direction} · clamp hits ${a.clamp_hits} · cap hits ${a.cap_hits}` }),
      el("table", {}, el("tbody", {}, ...rows))));
  }
}

function renderSensors(s) {
  const tb = $("#sensors tbody");
  tb.replaceChildren();
  for (const [name, c] of Object.entries(s.channels)) {
    const bad = c.health !== "ok" || c.faults.length > 0;
    const flags = [];
    if (c.substituted) flags.push(el("span", { class: "pill warn", text: "SUBSTITUTED" }), " ");
    for (const f of c.faults) flags.push(el("span", { class: "pill bad", text: f }), " ");
    // Age from the reading's own time (gateway clock), not the snapshot's: a held value ages.
    const age = c.reading_t_s === null || c.reading_t_s === undefined ? null : Math.max(0, s.t_s - c.reading_t_s);
    tb.append(el("tr", { class: bad ? "bad" : (c.substituted ? "warn" : ""), "data-channel": name, "data-faults": c.faults.join(","), "data-age-s": age === null ? "" : String(age) },
      el("td", { text: name }),
      el("td", { text: c.value === null ? "–" : c.value.toFixed(3) }),
      el("td", { class: "age" + (age !== null && age > 1 ? " old" : ""), text: ageText(age) }),
      el("td", {}, el("span", { class: "pill " + (c.health === "ok" ? "ok" : "bad"), text: c.health })),
      el("td", {}, ...flags)));
  }
}

function kv(box, pairs) {
  const d = el("div", { class: "kv" });
  for (const [k, v, cls] of pairs) d.append(el("span", { text: k }), el("span", { class: cls || "", text: v }));
  box.append(d);
}

function renderSink(s) {
  const box = $("#sink");
  box.replaceChildren();
  const k = s.sink;
  if (!k || !k.kind) { box.append(el("div", { class: "meta", text: "no output sink (dry run)" })); }
  else {
    kv(box, [
      ["sink", k.kind],
      ["controller link", k.connected ? "connected" : "disconnected", k.connected ? "ok" : "bad"],
      ["writes ok / failed", `${k.writes_ok} / ${k.writes_failed}`, k.writes_failed ? "bad" : ""],
      ["last error", k.last_error || "none", k.last_error ? "bad" : ""],
      ["controller holds", Object.entries(k.held_um).map(([a, v]) => `${a} ${um(v)} µm`).join(", ") || "–"],
      ["clamp / cap hits", s.axes.map((a) => `${a.axis} ${a.clamp_hits}/${a.cap_hits}`).join(", ")],
    ]);
    for (const [src, kind, since] of k.faults) box.append(el("div", { class: "result bad", text: `${src}: ${kind} since t=${since.toFixed(1)} s` }));
  }
  const sb = $("#sources");
  sb.replaceChildren();
  if (!s.sources.length) sb.append(el("div", { class: "meta", text: "–" }));
  for (const src of s.sources) {
    kv(sb, [[src.name, (src.connected ? "connected" : "disconnected") + ` · reconnects ${src.reconnects}` + (src.faults.length ? " · " + src.faults.map((f) => f[0]).join(", ") : ""), src.connected && !src.faults.length ? "ok" : "bad"]]);
  }
}

function render(s) {
  snap = s;
  document.body.dataset.cycles = String(s.cycles);
  const m = s.model;
  $("#model").replaceChildren("model ", el("b", { text: m ? m.name : "unknown" }),
    m ? ` · sha256 ${m.sha256.slice(0, 12)} · loaded ${day(m.loaded_unix_s)}` : "");
  $("#clock").textContent = `t = ${s.t_s.toFixed(1)} s · ${s.cycles} cycles`;
  renderAxes(s);
  renderSensors(s);
  renderSink(s);
  const sel = $("#term-axis");
  if (sel.options.length !== s.axes.length) {
    sel.replaceChildren(...s.axes.map((a) => el("option", { value: a.axis, text: a.axis })));
  }
  banner();
}

async function pollStatus() {
  try {
    render(await getJson("/status"));
    lastOk = Date.now();
  } catch (e) { banner(); }
}

function renderLog(sel, items, line) {
  const ol = $(sel);
  ol.replaceChildren(...items.slice(-50).reverse().map(line));
}

async function pollLogs() {
  try {
    const f = await getJson("/api/faults");
    const act = $("#faults-active");
    act.replaceChildren(...(f.active.length ? f.active.map((a) => el("div", { class: "result bad" },
      `${a.source}: ${a.kind}` + (a.ack ? ` (acknowledged ${when(a.ack.unix_s)} by ${a.ack.peer})` : " (not acknowledged)")))
      : [el("div", { class: "result ok", text: "no active fault" })]));
    if (f.log.length !== faultLog.length || (f.log.length && f.log[f.log.length - 1].unix_s !== faultLog[faultLog.length - 1].unix_s)) {
      faultLog = f.log;
      for (const p of Object.values(plots)) p.u.redraw(false);
    }
    renderLog("#fault-log", f.log, (e) => el("li", { class: e.event, text: `${when(e.unix_s)}  ${e.event.toUpperCase()}  ${e.source} ${e.kind}` }));
    const h = await getJson("/api/health");
    renderLog("#health-log", h.log, (e) => el("li", { class: e.health === "ok" && !e.faults.length ? "clear" : "start",
      text: `${when(e.unix_s)}  ${e.channel} ${e.health}${e.substituted ? " substituted" : ""}${e.faults.length ? " [" + e.faults.join(", ") + "]" : ""}` }));
    await pollModels();
    const a = await getJson("/api/actions");
    renderLog("#action-log", a.log, (e) => el("li", { text: `${when(e.unix_s)}  ${e.action} from ${e.peer} (${e.who}): ${e.result}` }));
  } catch (e) { /* the banner shows a dead link */ }
}

// The chart's width follows its box (window resized, phone turned): uPlot draws at a fixed size.
const chartWidth = (box) => Math.max(160, box.clientWidth || 320);
function resizeCharts() {
  for (const [id, p] of Object.entries(plots)) {
    const w = chartWidth($(id));
    if (w !== p.u.width) p.u.setSize({ width: w, height: 220 });
  }
}
window.addEventListener("resize", resizeCharts);
if (window.ResizeObserver) new ResizeObserver(resizeCharts).observe($("main"));

// Fault start (solid red) and clear (dashed green) as vertical lines, from /api/faults' log; the
// box's data-marks says how many are in view.
let faultLog = [];
function drawFaultMarks(u) {
  const [x0, x1] = [u.scales.x.min, u.scales.x.max];
  const ctx = u.ctx;
  let n = 0;
  ctx.save();
  ctx.lineWidth = Math.max(1, devicePixelRatio * 1.5);
  for (const e of faultLog) {
    if (!(e.unix_s >= x0 && e.unix_s <= x1)) continue;
    const x = Math.round(u.valToPos(e.unix_s, "x", true));
    ctx.strokeStyle = e.event === "start" ? "#c0161b" : "#1b7f3b";
    ctx.setLineDash(e.event === "start" ? [] : [6 * devicePixelRatio, 4 * devicePixelRatio]);
    ctx.beginPath();
    ctx.moveTo(x, u.bbox.top);
    ctx.lineTo(x, u.bbox.top + u.bbox.height);
    ctx.stroke();
    n++;
  }
  ctx.restore();
  u.root.parentElement.dataset.marks = String(n);
}

function plot(id, title, names, data) {
  const key = names.join("|");
  const box = $(id);
  const width = chartWidth(box);
  if (!plots[id] || plots[id].key !== key) {
    if (plots[id]) plots[id].u.destroy();
    const colors = ["#1f5fd6", "#d6401f", "#1b9e4b", "#8a3ffc", "#b86e00", "#00838f", "#c2185b", "#5d4037"];
    const opts = {
      width, height: 220,
      scales: { x: { time: true } },
      axes: [{}, { label: "µm", size: 60 }],
      series: [{}, ...names.map((n, i) => ({ label: n, stroke: colors[i % colors.length], width: 2, value: (u, v) => um(v) + " µm" }))],
      hooks: { draw: [drawFaultMarks] },
    };
    plots[id] = { key, u: new uPlot(opts, data, box) };
  } else {
    plots[id].u.setData(data);
  }
}

async function pollHistory() {
  try {
    const h = await getJson("/api/history?window=" + windowKind);
    const names = Object.keys(h.series);
    const applied = names.filter((n) => n.endsWith("/applied"));
    plot("#chart-applied", "applied", applied.map((n) => n.split("/")[0] + " applied"), [h.t_unix_s, ...applied.map((n) => h.series[n])]);
    const axis = $("#term-axis").value || (snap && snap.axes[0] && snap.axes[0].axis);
    const terms = names.filter((n) => n.startsWith(axis + "/term/"));
    plot("#chart-terms", "terms", terms.map((n) => n.split("/")[2]), [h.t_unix_s, ...terms.map((n) => h.series[n])]);
  } catch (e) { /* next poll */ }
}

async function action(path, body) {
  const out = $("#act-result");
  const token = $("#token").value.trim();
  const headers = { "content-type": "application/json" };
  if (token) headers.authorization = "Bearer " + token;
  try {
    const r = await fetch(path, { method: "POST", headers, body: JSON.stringify(body) });
    const text = (await r.text()).trim();
    out.className = "result " + (r.ok ? "ok" : "bad");
    out.textContent = r.ok ? `Done: ${text}` : `Refused (${r.status}): ${text}`;
  } catch (e) {
    out.className = "result bad";
    out.textContent = "No answer: " + e;
  }
  pollLogs();
}

$("#act-enable").onclick = () => action("/api/compensation", { enabled: true });
$("#act-disable").onclick = () => action("/api/compensation", { enabled: false });
$("#act-ack").onclick = () => action("/api/faults/ack", {});
$("#act-model").onclick = () => action("/api/model", { model: $("#model-select").value });

// The models declared in [gateway.models]; a switch ramps out, swaps, ramps in (takes ~1 s).
async function pollModels() {
  const m = await getJson("/api/models");
  const sel = $("#model-select");
  const names = m.declared.join("\n");
  if (sel.dataset.names !== names) {
    sel.dataset.names = names;
    sel.replaceChildren(...m.declared.map((n) => el("option", { value: n, text: n })));
  }
  $("#act-model").disabled = !m.declared.length;
  $("#model-state").textContent = !m.declared.length ? "no [gateway.models] declared"
    : m.switching_to ? `switching to ${m.switching_to.name} (${m.switching_to.sha256.slice(0, 12)}…)` : "";
}
for (const k of ["fine", "coarse"]) {
  $("#w-" + k).onclick = () => {
    windowKind = k;
    $("#w-fine").classList.toggle("on", k === "fine");
    $("#w-coarse").classList.toggle("on", k === "coarse");
    pollHistory();
  };
}
$("#term-axis").onchange = pollHistory;

pollStatus(); pollLogs(); pollHistory();
setInterval(pollStatus, 250);
setInterval(pollLogs, 1000);
setInterval(() => pollHistory(), 2000);
setInterval(banner, 500);
