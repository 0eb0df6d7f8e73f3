// What every step of the lab page shares: the token, HTTP calls, messages, small formatters and
// the page state (window.dimacq, for the browser test and the curious engineer).
// Standards only (ES modules, fetch, EventSource, canvas): no browser-specific API.

export const $ = (sel) => document.querySelector(sel);
export const $$ = (sel) => [...document.querySelectorAll(sel)];
export const TOKEN_KEY = "dimacq-token";

export const state = { setups: [], setup: null, article: null, frf: null, frfData: null, band: null,
  solution: null, solutions: [], timings: {}, plots: {} };
window.dimacq = state;

/** Listeners between the steps (one module per step: they meet only here). */
const handlers = {};
export function on(name, fn) { (handlers[name] ||= []).push(fn); }
export async function emit(name, ...args) {
  for (const fn of handlers[name] || []) await fn(...args);
}

// The token comes once, in the URL fragment printed by `dimacq serve` (#token=...: a fragment is
// never sent to the server nor logged), or typed in the field; it is kept in sessionStorage (this
// tab only, gone when the tab closes) and sent as a bearer token on every call.
export function takeTokenFromFragment() {
  const m = /(?:^#|&)token=([^&]+)/.exec(location.hash);
  if (m) {
    sessionStorage.setItem(TOKEN_KEY, decodeURIComponent(m[1]));
    history.replaceState(null, "", location.pathname + location.search);
  }
  const st = $("#token-state");
  if (st) st.textContent = sessionStorage.getItem(TOKEN_KEY) ? " ✓" : " needed to change anything";
}

export function authHeaders() {
  const tok = sessionStorage.getItem(TOKEN_KEY);
  return tok ? { Authorization: `Bearer ${tok}` } : {};
}

export function say(text, err = false) {
  const m = $("#msg");
  if (!m) return;
  m.textContent = text;
  m.className = err ? "err" : "";
}

/** The form's words for the API's field names (an error names the field the user typed in). */
export const FIELD_LABELS = {
  setup_id: ["setup", "#acq-setup"], averages_per_input: ["averages per input", "#averages"],
  min_averages: ["fewest averages per input", "#averages"], review: ["review every hit", "#acq-review"],
  frf_id: ["FRF set", "#frf-set"], band_hz: ["band, Hz", "#band-lo"], article: ["article", "#test-article"],
  operator: ["operator", "#test-operator"], date: ["date", "#test-date"], notes: ["notes", "#test-notes"],
  label: ["reference node label", "#ref-label"], position_m: ["reference node x, y, z", "#ref-x"],
};

/** An error the user can act on: ``field`` is the form field it names (its label), ``selector``
 * the input to mark; ``where`` the call, for the console. */
export class UserError extends Error {
  constructor(message, { field = null, selector = null, where = "", status = 0 } = {}) {
    super(message);
    Object.assign(this, { field, selector, where, status });
  }
}

/** "averages per input: must be at least 1" from the API's {detail, errors: [{loc, msg}]}. */
export function userMessage(data, status) {
  const errs = data && Array.isArray(data.errors) ? data.errors : [];
  if (status === 422 && errs.length) {
    const e = errs[0];
    const names = (e.loc || []).filter((p) => p !== "body" && p !== "query" && !/^\d+$/.test(p));
    const key = names[0] || "";
    const [label, selector] = FIELD_LABELS[key] || [key.replace(/_/g, " "), null];
    const msg = String(e.msg || "").replace(/^Input should be /, "must be ").replace(/^Value error, /, "")
      .replace("greater than or equal to", "at least").replace("less than or equal to", "at most")
      .replace("≥", "at least").replace("≤", "at most");
    return { text: label ? `${label}: ${msg}` : msg, field: label || null, selector };
  }
  const detail = data && data.detail ? data.detail : `the service answered HTTP ${status}`;
  return { text: typeof detail === "string" ? detail : JSON.stringify(detail), field: null, selector: null };
}

// --- the service's reachability: a banner, decisions off and polling backed off while it is gone
export const conn = { online: true, lastOk: 0, probe: null, delayMs: 500, failures: 0 };
state.conn = conn;

function banner() {
  const b = $("#offline");
  if (!b) return;
  b.hidden = conn.online;
  document.body.dataset.offline = conn.online ? "" : "1";
  if (!conn.online) b.textContent = `Service unreachable: decisions are off until it answers again (next try in ${(conn.delayMs / 1000).toFixed(0)} s). Nothing acquired is lost: the page picks up the running or interrupted acquisition when it is back.`;
}

function markOnline() {
  conn.lastOk = Date.now();
  if (conn.online) return;
  conn.online = true;
  conn.delayMs = 500;
  conn.failures = 0;
  if (conn.probe) { clearTimeout(conn.probe); conn.probe = null; }
  banner();
  emit("online").catch((e) => console.warn(`after the service came back: ${e.message}`));
}

function markOffline() {
  conn.failures += 1;
  if (!conn.online) return;
  conn.online = false;
  conn.delayMs = 500;
  banner();
  emit("offline").catch((e) => console.warn(`service unreachable: ${e.message}`));
  probeLater();
}

function probeLater() {
  conn.delayMs = Math.min(2 * conn.delayMs, 8000);
  banner();
  conn.probe = setTimeout(async () => {
    conn.probe = null;
    try {
      const r = await fetch("/api/status", { headers: authHeaders(), cache: "no-store" });
      if (r.status < 500) { markOnline(); return; }
    } catch { /* still gone */ }
    probeLater();
  }, conn.delayMs);
}

/** A heartbeat while nothing else talks to the service: a killed service is seen within ~2 s. */
export function startHeartbeat(periodMs = 1500) {
  setInterval(async () => {
    if (!conn.online || Date.now() - conn.lastOk < periodMs || document.hidden) return;
    try {
      const r = await fetch("/api/status", { headers: authHeaders(), cache: "no-store" });
      if (r.status < 500) markOnline(); else markOffline();
    } catch { markOffline(); }
  }, periodMs);
}

export async function api(method, path, body, { raw = false, headers: extra = {} } = {}) {
  // every call carries the token when the page has it: state-changing calls need it, and so do
  // reads when the service is bound to a non-loopback address
  const headers = { ...authHeaders(), ...extra };
  let payload;
  if (body !== undefined) {
    if (raw) payload = body;
    else { headers["Content-Type"] = "application/json"; payload = JSON.stringify(body); }
  }
  if (!conn.online && method !== "GET") {
    throw new UserError("the service is unreachable: try again when the banner is gone", { where: `${method} ${path}` });
  }
  let r;
  try {
    r = await fetch(path, { method, headers, body: payload });
  } catch (e) {
    markOffline();
    throw new UserError("the service is unreachable (is `dimacq serve` running?)", { where: `${method} ${path}` });
  }
  if (r.status === 502 || r.status === 503 || r.status === 504) markOffline(); else markOnline();
  const text = await r.text();
  let data = null;
  try { data = text ? JSON.parse(text) : null; } catch { data = text; }
  if (!r.ok) {
    if (r.status === 401 && $("#token-state")) $("#token-state").textContent = " wrong or missing token";
    const m = userMessage(data, r.status);
    throw new UserError(m.text, { field: m.field, selector: m.selector, where: `${method} ${path}`, status: r.status });
  }
  return data;
}

// --- each step's own status line: spinner, elapsed time, what is being done, the last failure
const lines = {};

/** The status line of step ``step`` (an element ``#status-<step>``). */
export function status(step) {
  const el = document.getElementById(`status-${step}`);
  const st = lines[step] ||= { timer: null, t0: 0, what: "" };
  const set = (cls, html) => { if (el) { el.className = `status ${cls}`; el.innerHTML = html; } };
  const tick = () => set("busy", `<span class="spinner"></span>${esc(st.what)} <span class="elapsed">${((performance.now() - st.t0) / 1000).toFixed(1)} s</span>`);
  return {
    busy(what) {
      clearInterval(st.timer);
      st.t0 = performance.now();
      st.what = what;
      tick();
      st.timer = setInterval(tick, 200);
    },
    /** What is being done now, the clock running on (started when not running). */
    update(what) {
      if (!st.timer) { this.busy(what); return; }
      st.what = what;
      tick();
    },
    done(text) { clearInterval(st.timer); st.timer = null; set("done", esc(text)); },
    fail(err) {
      clearInterval(st.timer);
      st.timer = null;
      set("err", `✗ ${esc(err.message || String(err))}`);
      if (err.selector) { const inp = $(err.selector); if (inp) { inp.classList.add("bad"); inp.addEventListener("input", () => inp.classList.remove("bad"), { once: true }); } }
    },
  };
}

/** Run ``fn`` as step ``step``'s job started by ``button``: the button is off until it ends,
 * the step's line says what is done and for how long, and the failure (in the user's words). */
export function job(step, button, what, fn) {
  return async (...args) => {
    const b = typeof button === "string" ? $(button) : button;
    if (b && b.dataset.busy === "1") return;
    if (b) { b.dataset.busy = "1"; b.disabled = true; }
    const line = status(step);
    line.busy(what);
    try {
      const out = await fn(...args);
      line.done(typeof out === "string" ? out : `${what.replace(/…$/, "")}: done`);
    } catch (e) {
      line.fail(e);
      say(e.message, true);
      if (e.where) console.warn(`${e.where}: ${e.message}`);
    } finally {
      if (b) { b.dataset.busy = ""; b.disabled = b.dataset.hold === "1"; }
    }
  };
}

/** Lists may come paginated ({items: [...]}) or bare: the page reads both. */
export const items = (d) => (Array.isArray(d) ? d : (d && d.items) || []);

/** A download through fetch (the token goes in the header, which a plain link cannot carry):
 * works on a non-loopback bind too. */
export async function download(path, filename) {
  const r = await fetch(path, { headers: authHeaders() });
  if (!r.ok) throw new Error(`GET ${path}: HTTP ${r.status}`);
  const url = URL.createObjectURL(await r.blob());
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}

/** Links marked data-download="name" download through fetch (see download). */
export function wireDownloads(root = document) {
  for (const a of root.querySelectorAll("a[data-download]")) {
    a.onclick = guard(async (ev) => { ev.preventDefault(); await download(a.getAttribute("href"), a.dataset.download); });
  }
}

export function guard(fn) {
  return async (...args) => {
    try { await fn(...args); } catch (e) { say(e.message, true); if (e.where) console.warn(`${e.where}: ${e.message}`); }
  };
}

export const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
export const f = (v, d = 4) => (v === null || v === undefined ? "—" : Number(v).toPrecision(d));
export const mm = (v) => (v === null || v === undefined ? "—" : (1e3 * v).toFixed(3));

export function table(headers, rows, cls = "") {
  const th = headers.map((h) => `<th>${esc(h)}</th>`).join("");
  const tr = rows.map((r) => `<tr>${r.map((c) => `<td>${c}</td>`).join("")}</tr>`).join("");
  return `<table class="${cls}"><thead><tr>${th}</tr></thead><tbody>${tr}</tbody></table>`;
}

/** "−Z" for a unit vector along an axis, else the vector. */
export function dirName(d) {
  const k = [0, 1, 2].reduce((a, b) => (Math.abs(d[b]) > Math.abs(d[a]) ? b : a), 0);
  if (Math.abs(d[k]) > 0.995) return `${d[k] < 0 ? "−" : "+"}${"XYZ"[k]}`;
  return `(${d.map((v) => v.toFixed(2)).join(", ")})`;
}

/** Server-sent events of a job with the token: EventSource cannot send a header, so the
 * stream is read through fetch (works on a non-loopback bind, where reads need the token).
 * onEvent(type, data) per event; onClose(broken) when the stream ends; returns {close()}. */
export function jobEvents(jobId, onEvent, onClose = null) {
  const ctl = new AbortController();
  (async () => {
    const r = await fetch(`/api/jobs/${jobId}/events?poll_s=0.2`, { headers: authHeaders(), signal: ctl.signal });
    if (!r.ok || !r.body) throw new Error(`job ${jobId} events: HTTP ${r.status}`);
    const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
    let buf = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buf += value;
      let k;
      while ((k = buf.indexOf("\n\n")) >= 0) {
        const block = buf.slice(0, k);
        buf = buf.slice(k + 2);
        let type = "message";
        const data = [];
        for (const line of block.split("\n")) {
          if (line.startsWith("event:")) type = line.slice(6).trim();
          else if (line.startsWith("data:")) data.push(line.slice(5).trimStart());
        }
        if (data.length) await onEvent(type, JSON.parse(data.join("\n")));
      }
    }
    if (onClose) onClose(false);
  })().catch((e) => { if (e.name !== "AbortError" && onClose) onClose(true); });
  return { close: () => ctl.abort() };
}
