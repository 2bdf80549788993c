// Polls /api/status every second and fills the status page (no inline script: CSP).
"use strict";
const $ = (id) => document.getElementById(id);
const fmt = (v, k = 1, digits = 1) => (v === null || v === undefined) ? "–" : (v * k).toFixed(digits);
const two = (n) => String(n).padStart(2, "0");
// one time format on every page: local, 24-hour, YYYY-MM-DD HH:MM:SS (as the server writes)
function when(t) {
  const d = t instanceof Date ? t : new Date(t);
  if (Number.isNaN(d.getTime())) return String(t ?? "");
  return `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())} ` +
         `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
}
function cell(tr, text) { const td = document.createElement("td"); td.textContent = text; tr.appendChild(td); }
let trendCount = -1;
let trendAt = 0;
// the trend: a text while nothing is logged; else the picture, redrawn every 10 new cycles
// or 15 s after the last new ones
function showTrend(total) {
  const box = $("trend-box");
  if (!total) {
    if (!$("trend-none")) {
      const p = document.createElement("p");
      p.id = "trend-none";
      p.className = "small";
      p.textContent = "no cycles logged yet";
      box.replaceChildren(p);
    }
    trendCount = 0;
    return;
  }
  let img = $("trend");
  if (!img) {
    img = document.createElement("img");
    img.id = "trend";
    img.alt = "accuracy trend (cellctl report)";
    box.replaceChildren(img);
    trendCount = -1;
  }
  if (trendCount < 0 || total - trendCount >= 10 || (total !== trendCount && Date.now() - trendAt > 15000)) {
    trendCount = total;
    trendAt = Date.now();
    img.src = `/trend.png?n=${total}`;
  }
}
async function poll() {
  try {
    const r = await fetch("/api/status", {cache: "no-store"});
    if (!r.ok) throw new Error(r.status === 503 ? "the HMI is busy" : `HTTP ${r.status}`);
    const s = await r.json();
    $("count").textContent = s.cycles_total;
    $("log-error").textContent = s.error || "";
    const f = s.in_flight;
    $("inflight").textContent = f ? `in flight: part ${f.part_id}, ${f.recipe} (${f.stage})` : "no cycle in flight";
    const last = s.cycles[0];
    $("last-error").textContent = last ? `${fmt(last.final_error_mm, 1000)} µm` : "–";
    $("last-recipe").textContent = last ? `cycle ${last.id}, ${last.recipe} ${last.recipe_hash.slice(0, 12)}` : "";
    if (s.plc && s.plc.reachable) {
      $("state").textContent = s.plc.state;
      $("fault").textContent = s.plc.fault_code || "none";
      $("bits").textContent = Object.entries(s.plc.status).filter(([, v]) => v).map(([k]) => k).join(" · ");
      const plant = s.plc.plant_backlog ? `, ${s.plc.plant_backlog} records not yet at the plant historian` : "";
      $("plc-line").textContent = `PLC link ${s.plc.address}: ${s.plc.recipe_line}, ${s.plc.cycle_count} cycles since start${plant}`;
    } else {
      $("state").textContent = f ? "cycle running" : (s.ok ? "idle or stopped" : "no log");
      $("fault").textContent = last && last.fault_code ? last.fault_code : "none";
      $("bits").textContent = last && last.fault_text ? last.fault_text : "";
      if (s.plc) $("plc-line").textContent = `PLC link ${s.plc.address}: ${s.plc.error}`;
    }
    const body = $("cycles").tBodies[0];
    body.replaceChildren();
    for (const c of s.cycles) {
      const tr = document.createElement("tr");
      tr.className = c.status === "done" ? "ok" : "bad";
      [c.id, c.part_id, c.recipe, c.recipe_hash.slice(0, 12), c.fault_code ? `${c.status} ${c.fault_code}` : c.status,
       fmt(c.final_error_mm, 1000), c.moves ?? "–", fmt(c.cycle_time_s, 1, 2), when(c.finished_at)].forEach((v) => cell(tr, v));
      body.appendChild(tr);
    }
    const audit = $("audit").tBodies[0];
    audit.replaceChildren();
    for (const a of s.audit) {
      const tr = document.createElement("tr");
      [a.id, when(a.at), a.who, a.action, a.result.slice(0, 80)].forEach((v) => cell(tr, v));
      audit.appendChild(tr);
    }
    showTrend(s.cycles_total);
    $("updated").textContent = `updated ${when(new Date())}`;
  } catch (e) {
    $("log-error").textContent = `status unavailable: ${e}`;
  }
}
poll();
setInterval(poll, 1000);
