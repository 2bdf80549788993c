// Polls /api/status every second and fills the status page (no inline script: CSP).
"use strict";
const $ = (id) => document.getElementById(id);
const fmt = (v, k = 1, digits = 1) => (v === null || v === undefined) ? "–" : (v * k).toFixed(digits);
function cell(tr, text) { const td = document.createElement("td"); td.textContent = text; tr.appendChild(td); }
let trendCount = -1;
let trendAt = 0;
async function poll() {
  try {
    const r = await fetch("/api/status", {cache: "no-store"});
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
      $("plc-line").textContent = `PLC link ${s.plc.address}: recipe ${s.plc.recipe_ack} (status ${s.plc.recipe_status}), ${s.plc.cycle_count} cycles since start`;
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
       fmt(c.final_error_mm, 1000), c.moves ?? "–", fmt(c.cycle_time_s, 1, 2), c.finished_at.slice(11, 19)].forEach((v) => cell(tr, v));
      body.appendChild(tr);
    }
    const audit = $("audit").tBodies[0];
    audit.replaceChildren();
    for (const a of s.audit) {
      const tr = document.createElement("tr");
      [a.id, a.at.slice(11, 19), a.who, a.action, a.result.slice(0, 80)].forEach((v) => cell(tr, v));
      audit.appendChild(tr);
    }
    // the trend is redrawn every 10 new cycles, or 15 s after the last new ones
    if (trendCount < 0 || s.cycles_total - trendCount >= 10 ||
        (s.cycles_total !== trendCount && Date.now() - trendAt > 15000)) {
      trendCount = s.cycles_total;
      trendAt = Date.now();
      $("trend").src = `/trend.png?n=${s.cycles_total}`;
    }
    $("updated").textContent = `updated ${new Date().toLocaleTimeString()}`;
  } catch (e) {
    $("log-error").textContent = `status unavailable: ${e}`;
  }
}
poll();
setInterval(poll, 1000);
