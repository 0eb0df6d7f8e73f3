// The lab page: a small vanilla-JS app over the REST API (no build step, no outside asset).
import { linePlot } from "/static/plot.js";
import { paramRows } from "/static/results.js";

const $ = (sel) => document.querySelector(sel);
const TOKEN_KEY = "dimacq-token";
const state = { setups: [], setup: null, article: null, frf: null, frfData: null, band: null,
  solution: null, timings: {} };
window.dimacq = state; // for the browser test and the curious engineer

// ------------------------------------------------------------------ token and HTTP
// The token comes once, in the URL fragment printed by `dimacq serve` (#token=...: a fragment is
// never sent to the server nor logged), or typed in the field; it is kept in sessionStorage (this
// tab only, gone when the tab closes) and sent as a bearer token on state-changing calls.
function takeTokenFromFragment() {
  const m = /(?:^#|&)token=([^&]+)/.exec(location.hash);
  if (m) {
    sessionStorage.setItem(TOKEN_KEY, decodeURIComponent(m[1]));
    history.replaceState(null, "", location.pathname + location.search);
  }
  $("#token-state").textContent = sessionStorage.getItem(TOKEN_KEY) ? " ✓" : " needed to change anything";
}

function say(text, err = false) {
  const m = $("#msg");
  m.textContent = text;
  m.className = err ? "err" : "";
}

async function api(method, path, body, { raw = false } = {}) {
  const headers = {};
  const tok = sessionStorage.getItem(TOKEN_KEY);
  // every call carries the token when the page has it: state-changing calls need it, and so do
  // reads when the service is bound to a non-loopback address
  if (tok) headers.Authorization = `Bearer ${tok}`;
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
    if (r.status === 401) $("#token-state").textContent = " wrong or missing token";
    throw new Error(`${method} ${path}: ${detail}`);
  }
  return data;
}

function guard(fn) {
  return async (...args) => {
    try { await fn(...args); } catch (e) { say(e.message, true); }
  };
}

const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
const f = (v, d = 4) => (v === null || v === undefined ? "—" : Number(v).toPrecision(d));
const mm = (v) => (v === null || v === undefined ? "—" : (1e3 * v).toFixed(3));

function table(headers, rows, cls = "") {
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

// ------------------------------------------------------------------ 1 setup
async function loadSetups() {
  state.setups = await api("GET", "/api/setups");
  $("#setups tbody").innerHTML = state.setups.map((s) => `<tr><td>${s.id}</td><td class="l">${esc(s.name)}</td>
    <td>${s.n_responses}</td><td>${s.n_inputs}</td><td>${s.n_load_cells}</td>
    <td><button data-setup="${s.id}">open</button></td></tr>`).join("");
  for (const b of document.querySelectorAll("[data-setup]")) {
    b.onclick = guard(() => openSetup(+b.dataset.setup));
  }
  $("#acq-setup").innerHTML = state.setups.map((s) => `<option value="${s.id}">${s.id} ${esc(s.name)}</option>`).join("");
  if (state.setup) $("#acq-setup").value = state.setup.id;
}

function openSetup(id) {
  const s = state.setups.find((x) => x.id === id);
  if (!s) return;
  state.setup = s;
  $("#acq-setup").value = id;
  const st = s.setup;
  const v = (p) => (p || []).map((x) => f(x, 4)).join(", ");
  $("#setup-detail").innerHTML = `<h3>Setup ${s.id}: ${esc(s.name)}</h3><div class="row">
    <div><h4>Responses (${st.responses.length})</h4><div class="scroll">${table(["node", "dir", "position, m", "direction (GCS)"],
      st.responses.map((c) => [c.node, c.direction, v(c.position_m), v(c.direction_gcs)]))}</div></div>
    <div><h4>Inputs (${st.inputs.length})</h4><div class="scroll">${table(["#", "node", "strike along", "position, m"],
      st.inputs.map((e, i) => [i + 1, e.node, dirName(e.direction_gcs), v(e.position_m)]))}</div></div>
    <div><h4>Load cells (${(st.load_cells || []).length})</h4>${table(["node", "position, m", "sign"],
      (st.load_cells || []).map((c) => [c.node, v(c.position_m), esc(c.sign || "")]))}</div></div>`;
}

async function importSetupFile(file) {
  const name = file.name.toLowerCase();
  const format = name.endsWith(".toml") ? "toml" : name.endsWith(".json") ? "json" : "uff";
  const out = await api("POST", `/api/setups/import?format=${format}&name=${encodeURIComponent(file.name)}`,
    await file.arrayBuffer(), { raw: true });
  await loadSetups();
  openSetup(out.id);
  if (out.frf_id) await loadFrfSets(out.frf_id);
  say(`imported ${file.name} as setup ${out.id}${out.frf_id ? ` with FRF set ${out.frf_id}` : ""}`);
}

async function loadArticle() {
  try {
    state.article = await api("GET", "/api/simulation/article");
  } catch {
    $("#sim-article").hidden = true;
    $("#digitize-all").disabled = true;
    return;
  }
  const a = state.article.setup;
  $("#scenario").textContent = `(${state.article.scenario})`;
  $("#n-inputs").value = a.inputs.length;
  const pts = [...a.responses.map((c) => c.position_m), ...a.inputs.map((e) => e.position_m)];
  const xs = pts.map((p) => p[0]);
  const ys = pts.map((p) => p[1]);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const s = Math.min(280 / (x1 - x0 || 1), 200 / (y1 - y0 || 1));
  const X = (x) => 20 + (x - x0) * s;
  const Y = (y) => 220 - (y - y0) * s;
  const nodes = new Map(a.responses.map((c) => [c.node, c.position_m]));
  let svg = `<rect x="0" y="0" width="320" height="240" fill="#fcfcfc" stroke="#ddd"/>`;
  for (const [n, p] of nodes) {
    svg += `<circle cx="${X(p[0])}" cy="${Y(p[1])}" r="4" fill="#1f77b4"><title>triax ${n}</title></circle>`;
    svg += `<text x="${X(p[0]) + 5}" y="${Y(p[1]) - 4}" font-size="9">${n}</text>`;
  }
  for (const e of a.inputs) {
    const [x, y] = [X(e.position_m[0]), Y(e.position_m[1])];
    svg += `<path d="M${x},${y - 4} l4,7 l-8,0 z" fill="#d62728"><title>input ${e.node} along ${dirName(e.direction_gcs)}</title></path>`;
  }
  $("#article-view").innerHTML = svg;
}

// ------------------------------------------------------------------ 2 digitize (simulation)
function arrayPlacement() {
  // the array hangs 1.1 m above the article's centre, axes along the GCS: DACS = GCS + t
  const a = state.article.setup;
  const pts = [...a.responses.map((c) => c.position_m), ...a.inputs.map((e) => e.position_m)];
  const lo = [0, 1, 2].map((k) => Math.min(...pts.map((p) => p[k])) - 0.02);
  const hi = [0, 1, 2].map((k) => Math.max(...pts.map((p) => p[k])) + 0.02);
  const c = [0, 1, 2].map((k) => 0.5 * (lo[k] + hi[k]));
  const t = [-c[0], -c[1], 1.1 - c[2]];
  return { lo, hi, dacs: (p) => p.map((v, k) => v + t[k]) };
}

const geo = { points: [], orientations: [], loas: [], registration: null, triaxes: [], inputs: [] };

async function digitize(label, pGcs, dacs) {
  const body = { label, shots: +$("#shots").value, sim_probe: { tip_m: dacs(pGcs), axis: [0, 0, 1] } };
  const p = await api("POST", "/api/digitizer/points", body);
  geo.points.push(p);
  const rej = p.n_shots - p.n_used;
  $("#readout").textContent = `${p.label}\narray  ${p.position_array_m.map((v) => v.toFixed(4)).join("  ")} m\n`
    + `spread ${p.spread_m.map((v) => (1e3 * v).toFixed(3)).join("  ")} mm\n`
    + `shots ${p.n_shots}, used ${p.n_used}, echoes rejected ${rej}`;
  return p;
}

function renderPoints() {
  $("#points").innerHTML = table(["label", "array position, m", "GCS position, m", "shots", "rejected"],
    geo.points.map((p) => [`<span class="l">${esc(p.label)}</span>`, p.position_array_m.map((v) => v.toFixed(4)).join(", "),
      p.position_m ? p.position_m.map((v) => v.toFixed(4)).join(", ") : "—", p.n_shots,
      p.n_shots - p.n_used ? `<span class="rej">${p.n_shots - p.n_used}</span>` : 0]));
}

function renderRegistration(reg) {
  const r = reg.registration || reg;
  const limit = r.residual_limit_m ?? r.limit_m ?? reg.residual_limit_m ?? reg.limit_m ?? null;
  $("#registration").innerHTML = `<p>method ${esc(r.method)}, RMS ${mm(r.rms_m)} mm${limit !== null ? `, limit ${mm(limit)} mm` : ""}</p>`
    + table(["node", "residual, mm", "limit, mm"], r.labels.map((l, i) => {
      const v = r.residual_norm_m[i];
      const over = limit !== null && v > limit;
      return [esc(l), `<span class="${over ? "over" : "ok"}">${mm(v)}</span>`, limit !== null ? mm(limit) : "—"];
    }));
}

async function digitizeAll() {
  const a = state.article.setup;
  const jig = state.article.jig;
  const { lo, hi, dacs } = arrayPlacement();
  const corners = [[lo[0], lo[1], lo[2]], [hi[0], lo[1], lo[2]], [lo[0], hi[1], lo[2]],
    [lo[0], lo[1], hi[2]], [hi[0], hi[1], hi[2]], [hi[0], lo[1], hi[2]]];
  const refs = Object.fromEntries(corners.map((p, i) => [`REF${i}`, p]));
  const nodes = [...new Set(a.responses.map((c) => c.node))].sort((x, y) => x - y);
  // n inputs spread over the list (every direction of a symmetric layout, not the first face)
  const nIn = Math.min(a.inputs.length, Math.max(1, +$("#n-inputs").value));
  const inputs = Array.from({ length: nIn }, (_, i) => a.inputs[Math.floor((i * a.inputs.length) / nIn)]);
  const total = corners.length + nodes.length * jig.labels.length + inputs.length * 4;
  let done = 0;
  const step = () => { done += 1; $("#dig-bar").style.width = `${(100 * done) / total}%`; };
  Object.assign(geo, { points: [], orientations: [], loas: [] });
  await api("PUT", "/api/digitizer/reference-nodes", { nodes: refs });
  for (const [l, p] of Object.entries(refs)) { await digitize(l, p, dacs); step(); }
  const reg = await api("POST", "/api/digitizer/registrations", { method: "rigid" });
  geo.registration = reg;
  renderRegistration(reg);
  for (const n of nodes) {
    const chans = a.responses.filter((c) => c.node === n).sort((x, y) => x.direction - y.direction);
    const C = chans.map((c) => c.direction_gcs); // columns of the sensor axes
    const o = chans[0].position_m;
    for (let j = 0; j < jig.labels.length; j++) {
      const xl = jig.points_local_m[j];
      const p = [0, 1, 2].map((k) => o[k] + C[0][k] * xl[0] + C[1][k] * xl[1] + C[2][k] * xl[2]);
      await digitize(`jig${n}/${jig.labels[j]}`, p, dacs);
      step();
    }
    geo.orientations.push(await api("POST", "/api/digitizer/orientations", { node: n }));
    $("#orientations").innerHTML = table(["node", "points", "residual RMS, mm", "uncertainty, °"],
      geo.orientations.map((r) => [r.node, r.n_points, mm(r.residual_rms_m), f(r.uncertainty_deg, 3)]));
  }
  for (const e of inputs) {
    const p = e.position_m;
    const d = e.direction_gcs;
    await digitize(`in${e.node}`, p, dacs); step();
    const labels = [];
    for (const [j, s] of [0.04, 0.08, 0.12].entries()) {
      await digitize(`loa${e.node}/${j}`, p.map((v, k) => v - s * d[k]), dacs); step();
      labels.push(`loa${e.node}/${j}`);
    }
    geo.loas.push(await api("POST", "/api/digitizer/lines-of-action", { node: e.node, input_label: `in${e.node}`, labels }));
    $("#loas").innerHTML = table(["node", "direction (GCS)", "strike along", "perp. RMS, mm", "angle std, °"],
      geo.loas.map((l) => [l.node, l.direction.map((v) => v.toFixed(3)).join(", "), dirName(l.direction), mm(l.perpendicular_rms_m), f(l.angle_std_deg, 3)]));
  }
  const nNew = geo.points.length;
  geo.points = await api("GET", "/api/digitizer/points");
  renderPoints();
  geo.triaxes = nodes;
  geo.inputs = inputs.map((e) => e.node);
  say(`digitized ${nNew} points: ${nodes.length} triaxes oriented, ${inputs.length} lines of action`);
}

async function buildSetup() {
  const a = state.article ? state.article.setup : null;
  const body = { name: `page ${new Date().toISOString().slice(0, 16)}`,
    reference_point_m: a ? a.reference_point_m || [0, 0, 0] : [0, 0, 0],
    load_cells: a ? a.load_cells || [] : [] };
  if (geo.triaxes.length) body.triaxes = geo.triaxes;
  if (geo.inputs.length) body.inputs = geo.inputs;
  const s = await api("POST", "/api/setups/from-geometry", body);
  await loadSetups();
  openSetup(s.id);
  say(`setup ${s.id}: ${s.n_responses} responses, ${s.n_inputs} inputs, ${s.n_load_cells} load cell(s)`);
}

// ------------------------------------------------------------------ 3 acquire
const acq = { id: null, job: null, es: null, last: 0, setup: null, perInput: 0 };

function renderAcquisition(a) {
  const ex = acq.setup.setup.inputs;
  const per = ex.map(() => ({ acc: 0, rej: 0, reasons: [] }));
  for (const av of a.averages) {
    const p = per[av.input_index];
    if (!p) continue;
    if (av.accepted) p.acc += 1;
    else { p.rej += 1; p.reasons.push(av.reason); }
  }
  const running = a.state === "running" || a.state === "pending";
  const cur = per.findIndex((p) => p.acc < acq.perInput);
  if (running && cur >= 0) {
    const e = ex[cur];
    $("#prompt").textContent = `Strike point ${e.node} along ${dirName(e.direction_gcs)} — input ${cur + 1}/${ex.length}, average ${per[cur].acc + 1}/${acq.perInput}`;
  } else {
    $("#prompt").textContent = `acquisition ${a.id} ${a.state}: ${a.averages_accepted} averages accepted, ${a.averages_rejected} rejected`;
  }
  $("#acq-inputs").innerHTML = table(["#", "node", "strike along", "accepted", "rejected", "reasons"],
    per.map((p, i) => [i + 1, ex[i].node, dirName(ex[i].direction_gcs),
      `${p.acc}/${acq.perInput}`, p.rej ? `<span class="rej">${p.rej}</span>` : 0,
      `<span class="l small">${esc([...new Set(p.reasons)].join("; "))}</span>`]));
  $("#acq-state").textContent = `${a.state} — ${a.message || ""}`;
}

async function refreshAcquisition() {
  const a = await api("GET", `/api/acquisitions/${acq.id}`);
  renderAcquisition(a);
  return a;
}

async function startAcquisition() {
  const sid = +$("#acq-setup").value;
  acq.setup = state.setups.find((s) => s.id === sid);
  acq.perInput = +$("#averages").value;
  const a = await api("POST", "/api/acquisitions", { setup_id: sid, averages_per_input: acq.perInput });
  Object.assign(acq, { id: a.id, job: a.job_id });
  $("#acq-stop").disabled = false;
  $("#acq-start").disabled = true;
  renderAcquisition({ ...a, averages: a.averages || [] });
  acq.es = new EventSource(`/api/jobs/${a.job_id}/events?poll_s=0.2`);
  // the job's server-sent events: "status" on every change, "end" at a final state
  const onSnap = guard(async (ev) => {
    const snap = JSON.parse(ev.data);
    $("#acq-bar").style.width = `${100 * snap.progress}%`;
    const now = performance.now();
    const done = ev.type === "end" || !["pending", "running"].includes(snap.state);
    if (done) {
      if (!acq.es) return;
      acq.es.close();
      acq.es = null;
    }
    if (done || now - acq.last > 300) {
      acq.last = now;
      const info = await refreshAcquisition();
      if (done) await acquisitionEnded(info);
    }
  });
  acq.es.addEventListener("status", onSnap);
  acq.es.addEventListener("end", onSnap);
}

async function acquisitionEnded(a) {
  $("#acq-stop").disabled = true;
  $("#acq-start").disabled = false;
  if (a.state !== "succeeded" && a.frf_id === null) {
    // a job can end just before the acquisition row says so: read it once more
    await new Promise((r) => setTimeout(r, 300));
    a = await refreshAcquisition();
  }
  say(`acquisition ${a.id} ${a.state}: ${a.message}`, a.state === "failed");
  if (a.frf_id) await loadFrfSets(a.frf_id);
}

async function stopAcquisition() {
  await api("POST", `/api/acquisitions/${acq.id}/stop`);
  say(`acquisition ${acq.id}: stop asked (the accepted averages are kept)`);
}

// ------------------------------------------------------------------ 4 FRFs
/** List the FRF sets; open ``select`` (the page does not fetch FRF values before asked). */
async function loadFrfSets(select) {
  const sets = await api("GET", "/api/frfs");
  $("#frf-set").innerHTML = `<option value="">—</option>` + sets.map((s) => `<option value="${s.id}">${s.id} ${esc(s.name)} (${s.n_responses}×${s.n_inputs}×${s.n_lines})</option>`).join("");
  if (select) {
    $("#frf-set").value = select;
    await openFrf(+select);
  }
}

async function openFrf(id) {
  const t0 = performance.now();
  const [summary, data] = await Promise.all([api("GET", `/api/frfs/${id}`), api("GET", `/api/frfs/${id}/data`)]);
  state.timings.frf_fetch_ms = performance.now() - t0;
  state.frf = summary;
  const nL = data.frequencies_hz.length;
  const nO = data.responses.length;
  const nI = data.inputs.length;
  // flatten once: (line, output, input) → Float64Array per (output, input) of |H| and γ²
  const mag = [];
  const coh = [];
  for (let j = 0; j < nI; j++) {
    mag.push([]); coh.push([]);
    for (let o = 0; o < nO; o++) {
      const m = new Float64Array(nL);
      const c = new Float64Array(nL);
      for (let l = 0; l < nL; l++) {
        const re = data.real[l][o][j];
        const im = data.imag[l][o][j];
        m[l] = Math.hypot(re, im);
        c[l] = data.coherence ? data.coherence[l][o][j] : NaN;
      }
      mag[j].push(m); coh[j].push(c);
    }
  }
  state.frfData = { x: Float64Array.from(data.frequencies_hz), responses: data.responses, inputs: data.inputs, mag, coh, data };
  $("#frf-input").innerHTML = data.inputs.map((inp, j) => `<option value="${j}">${j + 1}: node ${inp.node} dir ${inp.direction}</option>`).join("");
  $("#frf-info").textContent = `${nO} responses × ${nI} inputs × ${nL} lines, ${f(summary.f_min_hz)}–${f(summary.f_max_hz)} Hz`;
  drawFrfs(0);
  drawCmif();
}

function drawFrfs(j) {
  const d = state.frfData;
  const onBand = (lo, hi) => setBand(lo, hi);
  const mag = linePlot($("#frf-mag"), { x: d.x, logY: true, xLabel: "frequency, Hz", yLabel: "|H|",
    title: `FRF magnitude, input ${j + 1} (all ${d.responses.length} responses)`, band: state.band,
    series: d.mag[j].map((y) => ({ y })), onBand });
  state.timings.frf_draw_ms = mag.ms;
  state.plots = { mag };
  state.plots.coh = linePlot($("#frf-coh"), { x: d.x, yRange: [0, 1.02], xLabel: "frequency, Hz", yLabel: "γ²",
    title: "coherence", band: state.band, series: d.coh[j].map((y) => ({ y })), onBand });
}

/** CMIF: the two largest singular values of H(f) (accelerometer outputs × inputs) per line,
 * by power iteration with deflation on the Hermitian HᴴH. */
function drawCmif() {
  const d = state.frfData;
  const nI = d.inputs.length;
  const setup = state.setups.find((s) => s.id === state.frf.setup_id);
  const resp = new Set(setup ? setup.setup.responses.map((c) => `${c.node}/${c.direction}`) : []);
  const outs = d.responses.map((o, i) => i).filter((i) => !setup || resp.has(`${d.responses[i].node}/${d.responses[i].direction}`));
  const nL = d.x.length;
  const K = Math.min(2, nI);
  const sv = Array.from({ length: K }, () => new Float64Array(nL));
  const re = d.data.real;
  const im = d.data.imag;
  for (let l = 0; l < nL; l++) {
    // A = HᴴH (nI × nI), complex
    const Ar = new Float64Array(nI * nI);
    const Ai = new Float64Array(nI * nI);
    for (const o of outs) {
      const hr = re[l][o];
      const hi = im[l][o];
      for (let a = 0; a < nI; a++) {
        for (let b = 0; b < nI; b++) {
          Ar[a * nI + b] += hr[a] * hr[b] + hi[a] * hi[b];
          Ai[a * nI + b] += hr[a] * hi[b] - hi[a] * hr[b];
        }
      }
    }
    for (let k = 0; k < K; k++) {
      let vr = new Float64Array(nI).fill(1);
      let vi = new Float64Array(nI);
      let lam = 0;
      for (let it = 0; it < 12; it++) {
        const wr = new Float64Array(nI);
        const wi = new Float64Array(nI);
        for (let a = 0; a < nI; a++) {
          let sr = 0; let si = 0;
          for (let b = 0; b < nI; b++) {
            const ar = Ar[a * nI + b]; const ai = Ai[a * nI + b];
            sr += ar * vr[b] - ai * vi[b]; si += ar * vi[b] + ai * vr[b];
          }
          wr[a] = sr; wi[a] = si;
        }
        let n = 0;
        for (let a = 0; a < nI; a++) n += wr[a] * wr[a] + wi[a] * wi[a];
        n = Math.sqrt(n) || 1;
        lam = n;
        for (let a = 0; a < nI; a++) { wr[a] /= n; wi[a] /= n; }
        vr = wr; vi = wi;
      }
      sv[k][l] = Math.sqrt(lam);
      for (let a = 0; a < nI; a++) {
        for (let b = 0; b < nI; b++) { // A -= λ v vᴴ
          Ar[a * nI + b] -= lam * (vr[a] * vr[b] + vi[a] * vi[b]);
          Ai[a * nI + b] -= lam * (vi[a] * vr[b] - vr[a] * vi[b]);
        }
      }
    }
  }
  state.plots.cmif = linePlot($("#frf-cmif"), { x: d.x, logY: true, xLabel: "frequency, Hz", yLabel: "σ",
    title: "CMIF (two largest singular values, accelerometers)", band: state.band,
    series: sv.map((y) => ({ y })) });
}

function setBand(lo, hi) {
  state.band = [lo, hi];
  $("#band-lo").value = lo.toFixed(1);
  $("#band-hi").value = hi.toFixed(1);
  $("#auto-band").checked = false;
  for (const p of Object.values(state.plots || {})) { p.opts.band = state.band; p.draw(); }
}

// ------------------------------------------------------------------ 5 solve
function interval(u) {
  if (!u || !u.ci95) return "—";
  return `[${f(u.ci95[0])}, ${f(u.ci95[1])}]`;
}

async function solve() {
  const body = { frf_id: +$("#frf-set").value };
  if (!$("#auto-band").checked) {
    const lo = parseFloat($("#band-lo").value);
    const hi = parseFloat($("#band-hi").value);
    if (!(hi > lo)) throw new Error("band: drag on the FRF plot or type low < high (Hz), or tick automatic band");
    body.band_hz = [lo, hi];
  }
  say("solving…");
  const s = await api("POST", "/api/solutions", body);
  state.solution = s;
  renderSolution(s);
  say(`solution ${s.id}: verdict ${s.result.verdict}`);
}

function renderSolution(s) {
  const r = s.result;
  const reasons = (r.verdict_reasons || []).map((x) => (typeof x === "string" ? { message: x } : x));
  const ex = (k) => (r[k] || []).map((p) => (Array.isArray(p) ? p.join("/") : JSON.stringify(p))).join(", ") || "none";
  $("#solution").innerHTML = `<p class="verdict ${esc(r.verdict)}">verdict: ${esc(r.verdict)}</p>
    <ul>${reasons.map((x) => `<li class="${esc(x.severity || "")}">${esc(x.severity ? `${x.severity}: ` : "")}${esc(x.message || JSON.stringify(x))}</li>`).join("")}</ul>
    <p>band ${f(r.band_hz[0])}–${f(r.band_hz[1])} Hz; reference point P ${esc((r.reference_point_m || []).join(", "))} m; excluded responses: ${esc(ex("excluded_responses"))}; excluded inputs: ${esc(ex("excluded_inputs"))}</p>
    ${table(["parameter", "unit", "estimate", "95 % interval"], paramRows(r).map(([n, un, v, uu]) => [`<span class="l">${n}</span>`, un, f(v, 6), interval(uu)]))}
    <p><img id="solution-figure" alt="solution figure" src="/api/solutions/${s.id}/figure?format=svg" style="max-width:100%"></p>`;
  $("#report-links").innerHTML = `<a id="report-link" href="/report?solution=${s.id}" target="_blank">HTML report of solution ${s.id}</a> (print it to PDF from the browser) ·
    <a href="/api/frfs/${s.frf_id}/uff" download="frf-${s.frf_id}.uff">FRFs as UFF</a> ·
    <a href="/api/solutions/${s.id}" download="solution-${s.id}.json">solution as JSON</a>`;
}

// ------------------------------------------------------------------ status and wiring
async function loadStatus() {
  const st = await api("GET", "/api/status");
  $("#devices").textContent = Object.entries(st.devices).map(([k, v]) => `${k} ${v.connected ? "●" : "○"}`).join("  ");
}

async function init() {
  const t0 = performance.now();
  takeTokenFromFragment();
  $("#token-form").onsubmit = (ev) => {
    ev.preventDefault();
    sessionStorage.setItem(TOKEN_KEY, $("#token").value.trim());
    $("#token").value = "";
    takeTokenFromFragment();
  };
  $("#setup-file").onchange = guard(async (ev) => { if (ev.target.files[0]) await importSetupFile(ev.target.files[0]); });
  $("#digitize-all").onclick = guard(async () => {
    $("#digitize-all").disabled = true;
    try { await digitizeAll(); } finally { $("#digitize-all").disabled = false; }
  });
  $("#build-setup").onclick = guard(buildSetup);
  $("#acq-start").onclick = guard(startAcquisition);
  $("#acq-stop").onclick = guard(stopAcquisition);
  $("#frf-set").onchange = guard(async () => { if ($("#frf-set").value) await openFrf(+$("#frf-set").value); });
  $("#frf-input").onchange = () => drawFrfs(+$("#frf-input").value);
  $("#solve-btn").onclick = guard(solve);
  $("#acq-setup").onchange = () => openSetup(+$("#acq-setup").value);
  await Promise.all([loadStatus(), loadSetups(), loadArticle(), loadFrfSets()]);
  state.timings.init_ms = performance.now() - t0;
  document.body.dataset.ready = "1";
}

guard(init)();
