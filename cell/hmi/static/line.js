// Polls /api/line every 2 s and fills the line view (no inline script: CSP).
"use strict";
const $ = (id) => document.getElementById(id);
const two = (n) => String(n).padStart(2, "0");
// one time format on every page: local, 24-hour, YYYY-MM-DD HH:MM:SS (as the server writes)
function when(t) {
  if (t === null || t === undefined || t === "") return "–";
  const d = t instanceof Date ? t : new Date(t);
  if (Number.isNaN(d.getTime())) return String(t);
  return `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())} ` +
         `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
}
const um = (v) => (v === null || v === undefined) ? "–" : (v * 1000).toFixed(1);
function ago(s) {
  if (s === null || s === undefined) return "–";
  if (s < 120) return `${Math.max(0, s).toFixed(0)} s ago`;
  if (s < 7200) return `${(s / 60).toFixed(0)} min ago`;
  return `${(s / 3600).toFixed(1)} h ago`;
}
function td(tr, text, cls) {
  const e = document.createElement("td");
  e.textContent = text;
  if (cls) e.className = cls;
  tr.appendChild(e);
  return e;
}
function pair(sh) { return sh ? `${um(sh.final_p50_mm)} / ${um(sh.final_p95_mm)}` : "–"; }
async function poll() {
  try {
    const r = await fetch("/api/line", {cache: "no-store"});
    if (!r.ok) throw new Error(r.status === 503 ? "the HMI is busy" : `HTTP ${r.status}`);
    const doc = await r.json();
    $("line-error").textContent = doc.error || "";
    if (doc.shifts) $("shifts").textContent = `shifts in UTC: ${doc.shifts}`;
    const rows = doc.cells.map((c) => {
      const tr = document.createElement("tr");
      tr.dataset.cell = c.cell;
      const name = document.createElement("td");
      const a = document.createElement("a");
      a.href = c.href;
      a.textContent = c.cell;
      a.className = "cell-link";
      name.appendChild(a);
      tr.appendChild(name);
      td(tr, c.state, c.online === true ? "online" : (c.online === false ? "offline" : ""));
      td(tr, when(c.status_since));
      td(tr, c.last_part === null ? "–" : `${c.last_part} (${c.last_recipe}, ${c.last_outcome})` +
             (c.last_fault ? ` ${c.last_fault}` : ""));
      td(tr, when(c.last_finished_at));
      const cur = c.shifts.find((s) => s.current);
      const prev = c.shifts.filter((s) => !s.current).pop();
      td(tr, pair(cur));
      td(tr, pair(prev));
      td(tr, cur ? `${cur.parts} · ${cur.faults}` : "0 · 0");
      td(tr, String(c.received));
      td(tr, c.watermark === null ? "–" : String(c.watermark));
      td(tr, String(c.held_above));
      td(tr, ago(c.since_last_record_s));
      return tr;
    });
    $("line").tBodies[0].replaceChildren(...rows);
    $("line-none").textContent = rows.length ? "" : "no cells in the historian's database yet";
    $("updated").textContent = `updated ${when(new Date())}`;
  } catch (e) {
    $("line-error").textContent = `cannot read the line: ${e.message}`;
  }
}
poll();
setInterval(poll, 2000);
