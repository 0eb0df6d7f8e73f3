// The lab page's bench-calibration step: a load cell calibration run (static with dead weights,
// or inertial with the calibration mass) as a job of the REST API, its progress, the operator's
// prompts, the certificate figures and the circular check. Its own module and section (added to
// the page's <main> at load), so that the rest of the page does not depend on it.

import { dirName } from "/static/core.js";

const $ = (sel) => document.querySelector(sel);
const TOKEN_KEY = "dimacq-token";
const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
const num = (v, d = 4) => (v === null || v === undefined || !Number.isFinite(Number(v)) ? "—" : Number(v).toFixed(d));
const AXES = ["Fx", "Fy", "Fz", "Mx", "My", "Mz"];
const bench = { job: null, result: null, prompts: 0, strikes: 0 };
window.dimacqBench = bench; // for the browser test

async function api(method, path, body) {
  const headers = {};
  const tok = sessionStorage.getItem(TOKEN_KEY);
  if (tok) headers.Authorization = `Bearer ${tok}`;
  let payload;
  if (body !== undefined) { headers["Content-Type"] = "application/json"; payload = JSON.stringify(body); }
  const r = await fetch(path, { method, headers, body: payload });
  const text = await r.text();
  let data = null;
  try { data = text ? JSON.parse(text) : null; } catch { data = text; }
  if (!r.ok) throw new Error(`${method} ${path}: ${data && data.detail ? data.detail : `HTTP ${r.status}`}`);
  return data;
}

function say(text, err = false) {
  const m = $("#bench-msg");
  m.textContent = text;
  m.className = err ? "fail" : "small";
}

const SECTION = `
<h2>7 Bench calibration of the load cell</h2>
<p class="small">Static: dead weights on the loading arm, the operator prompted for each load
case. Inertial: the calibration mass on the cell, struck on the cell's support side. The result
becomes the cell's next calibration version and a record; the circular check solves DIM on the
calibration mass through it.</p>
<p>
  <label>method <select id="bench-method"><option value="static">static (dead weights)</option>
    <option value="inertial">inertial (calibration mass)</option></select></label>
  <label>averages per input <input id="bench-averages" type="number" min="1" max="1000" value="1" size="3"></label>
  <label><input id="bench-check" type="checkbox" checked> circular check</label>
  <label><input id="bench-download" type="checkbox"> download to the amplifier (real rig)</label>
  <button id="bench-start">Calibrate</button>
</p>
<p id="bench-prompt" class="prompt">—</p>
<p class="small">Inertial and circular check on a real rig: strike where the prompt says (the
trigger sees the hit); load cases: put the load in place, then confirm.</p>
<p><button id="bench-confirm" disabled>Load in place</button></p>
<div class="bar"><div id="bench-bar"></div></div>
<p id="bench-msg" class="small"></p>
<div id="bench-result"></div>
<h3>Calibrations</h3>
<div id="bench-list" class="scroll"></div>`;

/** Crosstalk per axis from the certificate's 6 × 6 ``[i][j]`` (error on axis i while axis j
 * carries the load): the largest over the other axes j ≠ i that were loaded (null: none was). */
function crosstalkPerAxis(m) {
  if (!Array.isArray(m) || !Array.isArray(m[0])) return m;
  return m.map((row, i) => {
    const v = row.filter((x, j) => j !== i && x !== null && Number.isFinite(Number(x))).map(Number);
    return v.length ? Math.max(...v) : null;
  });
}

function certificateTable(r) {
  const rows = [["nonlinearity", r.nonlinearity_pct_fs], ["hysteresis", r.hysteresis_pct_fs],
    ["uncertainty (k = 2)", r.uncertainty_pct_fs], ["crosstalk (largest from another axis)", crosstalkPerAxis(r.crosstalk_pct_fs)]]
    .filter(([, v]) => Array.isArray(v));
  const th = AXES.map((a) => `<th>${a}</th>`).join("");
  const tr = rows.map(([n, v]) => `<tr><td class="l">${esc(n)}</td>${v.map((x) => `<td>${num(x)}</td>`).join("")}</tr>`).join("");
  // the inertial method has no rated-load reference: its figures are % of the reading
  const unit = r.method === "static" ? "% of rated load" : "% of the reading";
  return `<table id="bench-cert"><thead><tr><th class="l">${unit}</th>${th}</tr></thead><tbody>${tr}</tbody></table>`;
}

function showResult(r) {
  const parts = [`<p>load cell ${esc(r.load_cell_node)}: <b>${esc(r.method)}</b> calibration, version
    ${esc(r.version)}, record ${esc(r.record_id)}; verdict <span class="verdict ${["ok", "warn"].includes(r.verdict) ? r.verdict : "fail"}">${esc(r.verdict)}</span>
    ${(r.reasons || []).map(esc).join("; ")}</p>`, certificateTable(r)];
  if (r.matrix_uncertainty_rel !== undefined && r.matrix_uncertainty_rel !== null) {
    parts.push(`<p id="bench-matrix-u">matrix uncertainty (k = 2): ${num(100 * r.matrix_uncertainty_rel, 3)} % (Frobenius)</p>`);
  }
  if (r.downloaded) parts.push(`<p>downloaded to the amplifier: ${esc(r.download_verified)}/72 elements verified on read-back</p>`);
  if (r.circular_mass_error_pct !== undefined && r.circular_mass_error_pct !== null) {
    const e = r.circular_errors_pct;
    parts.push(`<p id="bench-circular">circular check: mass <b>${num(r.circular_mass_error_pct, 3)} %</b>,
      CG ${num(e.cg_error_mm, 2)} mm, principal moments ${num(e.I1_pct, 2)} / ${num(e.I2_pct, 2)} /
      ${num(e.I3_pct, 2)} %; verdict <span class="verdict ${r.circular_verdict === "ok" ? "ok" : "fail"}">${esc(r.circular_verdict)}</span>
      ${(r.circular_reasons || []).map(esc).join("; ")}</p>`);
  }
  $("#bench-result").innerHTML = parts.join("");
}

async function listCalibrations() {
  const cals = await api("GET", "/api/calibrations");
  const rows = cals.slice(-20).reverse().map((c) => `<tr><td>${c.id}</td><td>${esc(c.serial_number)}</td>
    <td>${esc(c.calibration.method)}</td><td>${esc(c.calibration.version)}</td><td>${esc(c.calibration.date)}</td></tr>`).join("");
  $("#bench-list").innerHTML = `<table><thead><tr><th>id</th><th>serial</th><th>method</th><th>version</th><th>date</th></tr></thead><tbody>${rows}</tbody></table>`;
}

async function follow(jobId) {
  let waitingCase = null;
  $("#bench-confirm").onclick = async () => {
    if (waitingCase === null) return;
    const c = waitingCase;
    waitingCase = null;
    $("#bench-confirm").disabled = true;
    try { await api("POST", `/api/calibrations/runs/${jobId}/confirm`, { case: c }); } catch (e) { say(e.message, true); }
  };
  for (;;) {
    const st = await api("GET", `/api/jobs/${jobId}`);
    $("#bench-bar").style.width = `${Math.round(100 * (st.progress || 0))}%`;
    if (st.message) say(st.message);
    if (["succeeded", "failed", "cancelled"].includes(st.state)) return st;
    const p = await api("GET", `/api/calibrations/runs/${jobId}/prompt`);
    if (p.waiting && p.kind === "strike") {
      // as the acquisition asks: the point, the axis of its line of action, input and average
      const text = `${p.stage}: strike point ${p.node} along ${dirName(p.direction_gcs)} — input ${p.input_index + 1}/${p.n_inputs}, average ${p.average}/${p.averages}`;
      if ($("#bench-prompt").textContent !== text) bench.strikes += 1;
      $("#bench-prompt").textContent = text;
      $("#bench-prompt").dataset.request = String(p.request);
    } else if (p.waiting && waitingCase !== p.case) {
      waitingCase = p.case;
      bench.prompts += 1;
      $("#bench-prompt").textContent = `Load case ${p.case + 1} of ${p.of}: ${p.message}`;
      $("#bench-confirm").disabled = false;
    } else if (!p.waiting && waitingCase === null && st.message) {
      // nothing asked of the operator now: what the bench does
      $("#bench-prompt").textContent = st.message;
    }
    await new Promise((res) => setTimeout(res, 250));
  }
}

async function start() {
  $("#bench-start").disabled = true;
  $("#bench-result").innerHTML = "";
  $("#bench-prompt").textContent = "—";
  try {
    const body = { method: $("#bench-method").value, circular_check: $("#bench-check").checked,
      averages_per_input: Number($("#bench-averages").value), download: $("#bench-download").checked };
    const { job_id: jobId, simulated } = await api("POST", "/api/calibrations/runs", body);
    bench.job = jobId;
    if (simulated && body.download) say("simulated lab: nothing to download to");
    const st = await follow(jobId);
    if (st.state !== "succeeded") throw new Error(`calibration ${st.state}: ${st.error || st.message || ""}`);
    bench.result = st.result;
    showResult(st.result);
    // the list first: "finished" is said once everything the run changed is on the page
    await listCalibrations();
    say(`calibration finished: ${st.result.method}, version ${st.result.version}`);
  } catch (e) {
    say(e.message, true);
  } finally {
    $("#bench-start").disabled = false;
  }
}

function mount() {
  const sec = document.createElement("section");
  sec.id = "bench";
  sec.innerHTML = SECTION;
  $("main").appendChild(sec);
  const nav = $("header nav");
  if (nav) nav.insertAdjacentHTML("beforeend", '<a href="#bench">7 Bench</a>');
  $("#bench-start").addEventListener("click", start);
  listCalibrations().catch((e) => say(e.message, true));
  sec.dataset.ready = "1";
}

if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", mount);
else mount();
