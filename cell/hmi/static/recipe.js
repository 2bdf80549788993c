// The recipe editor: validate as you type (POST the text, the server runs the checks of
// `cellctl recipe validate`), save, then follow the controller's decision.
"use strict";
const $ = (id) => document.getElementById(id);
const csrf = document.body.dataset.csrf;
const editor = $("editor");
const name = editor.dataset.name;
let base = editor.dataset.sha;
let timer = null;
let seq = 0;

function post(path, doc) {
  return fetch(path, {method: "POST", headers: {"Content-Type": "application/json", "X-CSRF-Token": csrf},
                      body: JSON.stringify(doc), credentials: "same-origin"});
}

function showErrors(errors) {
  const box = $("check");
  box.replaceChildren();
  box.className = errors.length ? "bad" : "ok";
  if (!errors.length) { box.textContent = "valid"; return; }
  for (const e of errors) {
    const div = document.createElement("div");
    div.className = "err";
    const b = document.createElement("b");
    b.className = "field";
    b.textContent = e.field;
    div.append(`line ${e.line ?? "?"} · `, b, `: ${e.message}`);
    box.appendChild(div);
  }
}

async function validate() {
  const mine = ++seq;
  const r = await post(`/api/recipes/${name}/validate`, {text: editor.value});
  const out = await r.json().catch(() => ({}));
  if (mine !== seq) return;                // a later keystroke's answer will come
  if (r.status === 503) { timer = setTimeout(validate, 1000); return; }   // busy: check again shortly
  showErrors(out.errors || []);
  if (out.diff !== undefined) $("diff").textContent = out.diff || "no differences";
  return out;
}

editor.addEventListener("input", () => { clearTimeout(timer); timer = setTimeout(validate, 250); });

// what the page says of the saved version: pending until the controller decides, then
// active (no pending diff left) or rejected (the diff stays, marked rejected)
function showState(state, text) {
  const s = $("active-state");
  s.className = `state-${state}`;
  s.textContent = text;
  if (state === "pending") $("diff-title").textContent = "Pending change: the file against the active version";
  if (state === "rejected") $("diff-title").textContent = "Rejected change: the file against the active version, which stays";
  if (state === "active") {
    $("diff-title").textContent = "Diff against the active version";
    $("diff").textContent = "no differences";
  }
}

async function follow(sha) {
  const state = $("save-state");
  for (;;) {
    const r = await fetch(`/api/recipes/${name}/decision?sha256=${sha}`, {cache: "no-store"});
    const d = r.ok ? await r.json() : {state: "pending"};
    if (base !== sha) return;              // saved again meanwhile: that save is followed
    if (d.state === "active") {
      state.className = "ok";
      state.textContent = `activated ${sha.slice(0, 12)} by the controller at ${d.audit.at_local} (audit row ${d.audit.id}: ${d.audit.who})`;
      showState("active", "active");
      return;
    }
    if (d.state === "rejected") {
      state.className = "bad";
      state.textContent = `the controller rejected ${sha.slice(0, 12)} at ${d.audit.at_local}: ${d.audit.result}`;
      showState("rejected", "rejected by the controller; the active version stays");
      return;
    }
    await new Promise((res) => setTimeout(res, 1000));
  }
}

const save = $("save");
if (save) save.addEventListener("click", async () => {
  const state = $("save-state");
  state.className = "";
  state.textContent = "saving…";
  const r = await post(`/api/recipes/${name}/save`, {text: editor.value, base_sha256: base});
  const out = await r.json().catch(() => ({ok: false, error: `HTTP ${r.status}`}));
  if (!out.ok) {
    state.className = "bad";
    state.textContent = `not saved: ${out.error}`;
    if (out.errors) showErrors(out.errors);
    return;
  }
  base = out.sha256;
  $("file-sha").textContent = out.sha256.slice(0, 12);
  state.className = "";
  state.textContent = `saved ${out.sha256.slice(0, 12)}; waiting for the controller to activate it between cycles…`;
  showState("pending", "pending: saved, the controller has not decided yet");
  follow(out.sha256);
});
