// vdp dashboard: polls the service's own JSON endpoints once a second and draws plain SVG.
// No library and no network beyond this service: it has to work in a car.
"use strict";

const POLL_MS = 1000;
const KEEP = 900; // points kept per parameter (15 min at one a second)
const state = { meta: null, series: {}, lastBus: null, timer: null };

const $ = (id) => document.getElementById(id);

function el(tag, attrs, text) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

function fmt(v, digits) {
  if (v === null || v === undefined || !isFinite(v)) return "–";
  const a = Math.abs(v);
  if (a !== 0 && (a >= 1e5 || a < 1e-3)) return v.toExponential(2);
  return Number(v.toPrecision(digits || 4)).toString();
}

function age(s) {
  if (s === null || s === undefined) return "never";
  if (s < 1) return (1000 * s).toFixed(0) + " ms";
  if (s < 120) return s.toFixed(1) + " s";
  return (s / 60).toFixed(0) + " min";
}

function bytes(n) {
  if (n === null || n === undefined) return "–";
  const u = ["B", "kB", "MB", "GB", "TB"];
  let i = 0;
  while (n >= 1000 && i < u.length - 1) { n /= 1000; i++; }
  return n.toFixed(i ? 1 : 0) + " " + u[i];
}

async function getJSON(url) {
  const ctl = new AbortController();
  const t = setTimeout(() => ctl.abort(), 4000);
  try {
    const r = await fetch(url, { signal: ctl.signal, cache: "no-store" });
    if (!r.ok) throw new Error(url + ": " + r.status);
    return await r.json();
  } finally {
    clearTimeout(t);
  }
}

function build(meta) {
  $("vehicle").textContent = meta.vehicle;
  const stages = $("stages");
  for (const s of ["1", "2"]) {
    const box = el("div", { class: "stage", id: "stage-" + s });
    box.append(el("div", {}, s === "1" ? "Stage 1 · l_f, h, C_K" : "Stage 2 · C_α, I_z, I_x"));
    box.append(el("div", { class: "pct" }, "0 %"));
    const bar = el("div", { class: "bar" });
    bar.append(el("div"));
    box.append(bar, el("div", { class: "gate" }, ""));
    stages.append(box);
  }
  const params = $("params");
  for (const [name, p] of Object.entries(meta.parameters)) {
    state.series[name] = [];
    const c = el("div", { class: "card param", "data-param": name });
    const head = el("div", { class: "head" });
    const left = el("div");
    left.append(el("span", { class: "name" }, name.replace("alpha", "α") + " "), el("span", { class: "meta" }, "[" + p.unit + "] " + p.description));
    head.append(left, el("span", { class: "badge" }, "not run"));
    const nums = el("div");
    nums.append(el("span", { class: "value" }, "–"), el("span", { class: "std" }, ""));
    const bar = el("div", { class: "bar" });
    bar.append(el("div"));
    const svg = document.createElementNS("http://www.w3.org/2000/svg", "svg");
    svg.setAttribute("preserveAspectRatio", "none");
    svg.setAttribute("role", "img");
    svg.setAttribute("aria-label", name + " over time with its ±2σ band and prior");
    c.append(head, nums, bar, el("div", { class: "meta progress" }, ""), el("div", { class: "hint" }, ""), svg);
    params.append(c);
  }
}

// y range from the estimate and its band where the band is informative; the prior's band never sets it
function yRange(pts, prior) {
  let lo = Infinity, hi = -Infinity;
  const recent = pts.slice(Math.floor(pts.length / 3));
  for (const [, v, sd] of recent) {
    const w = sd !== null && sd < 0.25 * prior.std ? 2 * sd : 0;
    lo = Math.min(lo, v - w); hi = Math.max(hi, v + w);
  }
  for (const [, v] of pts) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!isFinite(lo)) { lo = prior.value - prior.std; hi = prior.value + prior.std; }
  const pad = Math.max(0.1 * (hi - lo), 1e-3 * Math.abs(hi) + 1e-9);
  return [lo - pad, hi + pad];
}

function draw(svg, pts, prior) {
  const W = 300, H = 120;
  svg.setAttribute("viewBox", `0 0 ${W} ${H}`);
  while (svg.firstChild) svg.removeChild(svg.firstChild);
  const ns = "http://www.w3.org/2000/svg";
  if (pts.length < 2) {
    const t = document.createElementNS(ns, "text");
    t.setAttribute("x", 6); t.setAttribute("y", 16); t.textContent = "no estimates yet";
    svg.append(t);
    return;
  }
  const t0 = pts[0][0], t1 = pts[pts.length - 1][0];
  const [lo, hi] = yRange(pts, prior);
  const x = (t) => ((t - t0) / Math.max(t1 - t0, 1e-9)) * W;
  const y = (v) => H - ((Math.min(Math.max(v, lo), hi) - lo) / (hi - lo)) * H;
  const bandPath = (part) => {
    let up = "", down = "";
    part.forEach(([t, v, sd], i) => {
      up += `${i ? "L" : "M"}${x(t).toFixed(1)},${y(v + (sd === null ? 0 : 2 * sd)).toFixed(1)}`;
    });
    for (let i = part.length - 1; i >= 0; i--) {
      const [t, v, sd] = part[i];
      down += `L${x(t).toFixed(1)},${y(v - (sd === null ? 0 : 2 * sd)).toFixed(1)}`;
    }
    const e = document.createElementNS(ns, "path");
    e.setAttribute("d", up + down + "Z");
    return e;
  };
  let line = "";
  pts.forEach(([t, v], i) => {
    line += `${i ? "L" : "M"}${x(t).toFixed(1)},${y(v).toFixed(1)}`;
  });
  // the ±2σ band at full strength from where the data has narrowed it (below half the prior's
  // std); before that it is the prior's width, drawn faintly so it does not flood the plot
  const faint = bandPath(pts);
  faint.setAttribute("class", "band faint");
  svg.append(faint);
  const from = pts.findIndex(([, , sd]) => sd !== null && sd < 0.5 * prior.std);
  if (from >= 0 && pts.length - from >= 2) {
    const band = bandPath(pts.slice(from));
    band.setAttribute("class", "band");
    svg.append(band);
  }
  const path = document.createElementNS(ns, "path");
  path.setAttribute("class", "line"); path.setAttribute("d", line);
  svg.append(path);
  // the prior's mean as a dashed line, or an arrow label when it is off the axes
  const pl = document.createElementNS(ns, "text");
  pl.setAttribute("x", 4);
  if (prior.value >= lo && prior.value <= hi) {
    const l = document.createElementNS(ns, "line");
    l.setAttribute("class", "prior");
    l.setAttribute("x1", 0); l.setAttribute("x2", W);
    l.setAttribute("y1", y(prior.value)); l.setAttribute("y2", y(prior.value));
    svg.append(l);
    pl.setAttribute("y", Math.max(y(prior.value) - 3, 10));
    pl.textContent = "prior " + fmt(prior.value, 3);
  } else {
    pl.setAttribute("y", prior.value > hi ? 10 : H - 3);
    pl.textContent = (prior.value > hi ? "↑ prior " : "↓ prior ") + fmt(prior.value, 3);
  }
  svg.append(pl);
  const span = document.createElementNS(ns, "text");
  span.setAttribute("x", W - 4); span.setAttribute("y", H - 3); span.setAttribute("text-anchor", "end");
  span.textContent = `last ${age(t1 - t0)}`;
  const top = document.createElementNS(ns, "text");
  top.setAttribute("x", W - 4); top.setAttribute("y", 10); top.setAttribute("text-anchor", "end");
  top.textContent = fmt(hi, 3);
  svg.append(span, top);
}

function push(name, t, p) {
  const s = state.series[name];
  if (p.value === null || p.value === undefined) return;
  if (s.length && t <= s[s.length - 1][0]) s[s.length - 1] = [t, p.value, p.std];
  else s.push([t, p.value, p.std]);
  if (s.length > KEEP) s.splice(0, s.length - KEEP);
}

function showEstimates(est) {
  const coach = est.coaching || {};
  $("next").textContent = coach.next || "–";
  const gates = (est.supervisor || {}).reasons || {};
  for (const s of ["1", "2"]) {
    const box = $("stage-" + s);
    const st = (coach.stages || {})[s] || {};
    const pct = Math.round(100 * (st.progress || 0));
    box.querySelector(".pct").textContent = pct + " %";
    box.querySelector(".bar > div").style.width = pct + "%";
    const gate = st.why_not ? "cannot run: " + st.why_not : gates[s] === "open" ? "window open: learning" : gates[s] || "";
    box.querySelector(".gate").textContent = gate;
  }
  const t = est.bus_time !== null && est.bus_time !== undefined ? est.bus_time : est.updated;
  for (const [name, p] of Object.entries(est.parameters || {})) {
    const c = document.querySelector(`[data-param="${name}"]`);
    if (!c) continue;
    push(name, t, p);
    c.querySelector(".value").textContent = fmt(p.value, 4);
    c.querySelector(".std").textContent = p.std !== null ? ` ± ${fmt(p.std, 2)} ${state.meta.parameters[name].unit}` : "";
    const b = c.querySelector(".badge");
    b.className = "badge " + p.status;
    b.textContent = p.status.replace("_", " ") + (p.valid ? " ✓" : "");
    const pct = Math.round(100 * (p.progress || 0));
    c.querySelector(".bar > div").style.width = pct + "%";
    const cp = ((coach.parameters || {})[name]) || {};
    c.querySelector(".progress").textContent =
      `learnt ${pct} % · ${fmt(cp.window_s || 0, 3)} s in windows · valid: ${p.valid ? "yes" : "no"}` +
      (p.reason ? ` · ${p.reason}` : "");
    c.querySelector(".hint").textContent = p.hint || "";
    draw(c.querySelector("svg"), state.series[name], state.meta.parameters[name].prior);
  }
  $("updated").textContent = new Date(est.updated * 1000).toLocaleTimeString();
  $("bustime").textContent = est.bus_time ? new Date(est.bus_time * 1000).toLocaleTimeString() : "–";
}

function kv(box, rows) {
  box.replaceChildren();
  for (const [k, v, bad] of rows) {
    box.append(el("span", {}, k));
    box.append(el("b", bad ? { class: "bad" } : {}, v));
  }
}

function profileCheck(pc) {
  // the self-check of the profile against the bus: not yet run, the bus does not fit, findings, or ok
  if (!pc) return "–";
  if (pc.checked_at === null || pc.checked_at === undefined) return `waits for ${fmt(pc.start_after_s, 2)} s of bus time`;
  if (pc.error) return pc.error;
  const cov = pc.coverage || {};
  const parts = [];
  if ((cov.missing || []).length) parts.push(cov.message);
  for (const f of pc.findings || []) parts.push(f.message);
  return parts.join("; ") || `ok (${cov.seen} of ${cov.wanted} messages seen)`;
}

function showStatus(st, health) {
  const pill = $("health");
  pill.className = "pill " + (health.status || "");
  pill.textContent = health.status === "ok" ? "ok" : "degraded";
  pill.title = (health.reasons || []).join("; ");
  const bus = st.bus || {}, dec = st.decode || {};
  const byKind = dec.errors_by_kind || {};
  const errs = Object.values(byKind).reduce((a, b) => a + b, 0);
  const kinds = Object.entries(byKind).map(([k, n]) => `${k} ${n}`).join(", ");
  const sim = st.simulation;
  const source = sim
    ? `simulated '${sim.scenario}' at ${sim.speed}x, ${fmt(sim.sim_time, 3)} of ${fmt(sim.duration, 3)} s` +
      (sim.loops ? `, loop ${sim.loops + 1}` : "") + (sim.paused_s > 0.5 ? `, waited ${fmt(sim.paused_s, 2)} s for estimation` : "")
    : `${bus.interface || "?"} ${bus.channel || ""}`;
  kv($("bus"), [
    ["source", source],
    ["state", bus.state || "–", bus.state !== "up"],
    ["frames/s", fmt(bus.frames_per_s || 0, 4)],
    ["frames", String(bus.frames || 0)],
    ["decode errors", errs ? `${errs} (${kinds})` : "0", errs > 0],
    ["invalid channels", (dec.invalid_channels || []).join(", ") || "none", (dec.invalid_channels || []).length > 0],
    ["unknown ids", String(dec.unknown_distinct || 0)],
    ["last frame", age(bus.last_frame_age_s)],
    ["profile check", profileCheck(st.profile_check), !!st.profile_check && (!!st.profile_check.error || (st.profile_check.findings || []).length > 0 || ((st.profile_check.coverage || {}).missing || []).length > 0)],
    ["health", (health.reasons || []).join("; ") || "ok", (health.reasons || []).length > 0],
  ]);
  const tb = $("channels").querySelector("tbody");
  tb.replaceChildren();
  for (const [name, f] of Object.entries(st.channels || {})) {
    const tr = el("tr");
    tr.append(el("td", {}, name), el("td", f.stale ? { class: "stale" } : {}, age(f.age)), el("td", f.stale ? { class: "stale" } : {}, f.stale ? "stale" : "fresh"));
    tb.append(tr);
  }
  const r = st.raw_log || {};
  if (r.enabled === false) kv($("rawlog"), [["raw log", "disabled", true]]);
  else
    kv($("rawlog"), [
      ["state", r.error ? "stopped: " + r.error : r.active ? "recording" : "not recording", !!r.error || !r.active],
      ["frames", String(r.frames || 0)],
      ["lost", String(r.lost || 0), r.lost > 0],
      ["files", `${r.closed_files || 0} closed + current`],
      ["size", bytes(r.bytes)],
      ["disk free", bytes(r.disk_free), r.disk_full],
      ["dir", r.dir || "–"],
    ]);
}

async function seed() {
  // the last minutes from the store, so a reload keeps its plots (skipped if the store is down)
  try {
    const head = await getJSON("/estimates/history?limit=1");
    const offset = Math.max(0, head.total - 1000);
    const page = await getJSON(`/estimates/history?limit=1000&offset=${offset}`);
    for (const it of page.items) {
      if (state.series[it.parameter] && it.value !== null) push(it.parameter, it.bus_t !== null ? it.bus_t : it.t, it);
    }
  } catch (e) { /* no history: the plots start now */ }
}

const DRIVES_MS = 15000; // /history changes once a drive looks again (every few seconds of bus time)

async function drives() {
  // each parameter as each drive ended it, newest drive first, and the changes named between drives
  try {
    const h = await getJSON("/history?limit=50");
    const names = Object.keys(h.parameters);
    const ul = $("changes");
    ul.replaceChildren();
    for (const c of h.changes.slice().reverse()) {
      const when = new Date(c.t * 1000).toLocaleString();
      ul.append(el("li", { class: "stale" }, `${when}, drive ${c.drive ?? "–"}: ${c.what} (reset ${c.params.join(", ")})`));
    }
    const head = $("drives").querySelector("thead");
    const tr = el("tr");
    tr.append(el("th", {}, "drive"), el("th", {}, "began"), el("th", {}, "mass [kg]"));
    for (const n of names) tr.append(el("th", {}, n.replace("alpha", "α")));
    head.replaceChildren(tr);
    const tb = $("drives").querySelector("tbody");
    tb.replaceChildren();
    for (const d of h.drives.slice().reverse()) {
      const row = el("tr");
      const m = d.mass;
      row.append(el("td", {}, String(d.id)), el("td", {}, new Date(d.t0 * 1000).toLocaleString()),
        el("td", {}, m ? `${fmt(m.value)} ± ${fmt(m.std, 2)}` : "–"));
      for (const n of names) {
        const e = (d.last || {})[n];
        row.append(el("td", e && !e.valid ? { class: "stale" } : {}, e ? `${fmt(e.value)} ± ${fmt(e.std, 2)}` : "–"));
      }
      tb.append(row);
    }
  } catch (e) { /* no store: no history across drives */ }
  setTimeout(drives, DRIVES_MS);
}

async function tick() {
  try {
    const [est, st, health] = await Promise.all([getJSON("/estimates"), getJSON("/status"), getJSON("/health")]);
    $("offline").hidden = true;
    showEstimates(est);
    showStatus(st, health);
  } catch (e) {
    $("offline").hidden = false;
  }
  state.timer = setTimeout(tick, POLL_MS);
}

async function start() {
  for (;;) {
    try {
      state.meta = await getJSON("/dashboard/meta");
      break;
    } catch (e) {
      $("offline").hidden = false;
      await new Promise((r) => setTimeout(r, POLL_MS));
    }
  }
  build(state.meta);
  await seed();
  tick();
  drives();
}

start();
