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

export async function api(method, path, body, { raw = false } = {}) {
  // every call carries the token when the page has it: state-changing calls need it, and so do
  // reads when the service is bound to a non-loopback address
  const headers = authHeaders();
  let payload;
  if (body !== undefined) {
    if (raw) payload = body;
    else { headers["Content-Type"] = "application/json"; payload = JSON.stringify(body); }
  }
  const r = await fetch(path, { method, headers, body: payload });
  const text = await r.text();
  let data = null;
  try { data = text ? JSON.parse(text) : null; } catch { data = text; }
  if (!r.ok) {
    const detail = data && data.detail ? data.detail : `HTTP ${r.status}`;
    if (r.status === 401 && $("#token-state")) $("#token-state").textContent = " wrong or missing token";
    throw new Error(`${method} ${path}: ${typeof detail === "string" ? detail : JSON.stringify(detail)}`);
  }
  return data;
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
    try { await fn(...args); } catch (e) { say(e.message, true); }
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
 * onEvent(type, data) per event; returns {close()}. */
export function jobEvents(jobId, onEvent) {
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
  })().catch((e) => { if (e.name !== "AbortError") say(e.message, true); });
  return { close: () => ctl.abort() };
}
