// One printable HTML report of a solution: setup, data quality, figures, results, downloads.
import { paramRows } from "/static/results.js";

const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
const f = (v, d = 5) => (v === null || v === undefined ? "—" : Number(v).toPrecision(d));

async function get(path) {
  const r = await fetch(path);
  if (!r.ok) throw new Error(`GET ${path}: HTTP ${r.status}`);
  return r.json();
}

function table(headers, rows) {
  return `<table><thead><tr>${headers.map((h) => `<th>${esc(h)}</th>`).join("")}</tr></thead><tbody>${
    rows.map((r) => `<tr>${r.map((c) => `<td>${c}</td>`).join("")}</tr>`).join("")}</tbody></table>`;
}

const ci = (u) => (u && u.ci95 ? `[${f(u.ci95[0])}, ${f(u.ci95[1])}]` : "—");

async function main() {
  const id = new URLSearchParams(location.search).get("solution");
  const s = await get(`/api/solutions/${id}`);
  const frf = await get(`/api/frfs/${s.frf_id}`);
  const setup = await get(`/api/setups/${frf.setup_id}`);
  const acq = frf.acquisition_id ? await get(`/api/acquisitions/${frf.acquisition_id}`) : null;
  const r = s.result;
  const rows = paramRows(r).map(([n, un, v, uu]) => [`${n}, ${un}`, v, uu]);
  const reasons = (r.verdict_reasons || []).map((x) => (typeof x === "string" ? x : `${x.severity || ""}: ${x.message || JSON.stringify(x)}`));
  const st = setup.setup;
  document.title = `dimacq report — solution ${s.id}`;
  document.getElementById("report-body").innerHTML = `
  <h1>DIM test report — solution ${s.id}</h1>
  <p class="small">generated ${new Date().toISOString()} from the lab service</p>
  <section><h2>Result</h2>
  <p class="verdict ${esc(r.verdict)}">verdict: ${esc(r.verdict)}</p><ul>${reasons.map((x) => `<li>${esc(x)}</li>`).join("")}</ul>
  <p>band ${f(r.band_hz[0])}–${f(r.band_hz[1])} Hz; condition number ${f(r.condition_number, 3)}; relative residual ${f(r.residual_rel, 3)}</p>
  ${table(["parameter", "estimate", "95 % interval"], rows.map(([n, v, uu]) => [`<span class="l">${n}</span>`, f(v, 6), ci(uu)]))}</section>
  <section><h2>Setup ${setup.id}: ${esc(setup.name)}</h2>
  <p>${st.responses.length} response channels, ${st.inputs.length} inputs, ${(st.load_cells || []).length} load cell(s); reference point ${esc((st.reference_point_m || [0, 0, 0]).join(", "))} m</p>
  ${table(["input", "node", "position, m", "line of action (GCS)"], st.inputs.map((e, i) => [i + 1, e.node, e.position_m.map((v) => f(v, 4)).join(", "), e.direction_gcs.map((v) => f(v, 3)).join(", ")]))}</section>
  <section><h2>Data quality</h2>
  <p>FRF set ${frf.id} (${esc(frf.name)}): ${frf.n_responses} responses × ${frf.n_inputs} inputs × ${frf.n_lines} lines, ${f(frf.f_min_hz)}–${f(frf.f_max_hz)} Hz.</p>
  ${acq ? `<p>acquisition ${acq.id}: ${acq.averages_accepted} averages accepted, ${acq.averages_rejected} rejected${acq.averages_rejected ? ` (${esc([...new Set(acq.averages.filter((a) => !a.accepted).map((a) => a.reason))].join("; "))})` : ""}.</p>` : "<p>FRFs imported (no acquisition record).</p>"}
  <p>excluded responses: ${esc(JSON.stringify(r.excluded_responses || []))}; excluded inputs: ${esc(JSON.stringify(r.excluded_inputs || []))}</p></section>
  <section><h2>Figures</h2><img src="/api/solutions/${s.id}/figure?format=svg" alt="solution figure" style="max-width:100%"></section>
  <section><h2>Downloads</h2><p><a href="/api/frfs/${frf.id}/uff" download="frf-${frf.id}.uff">FRFs (UFF)</a> ·
  <a href="/api/solutions/${s.id}" download="solution-${s.id}.json">solution (JSON)</a> ·
  <a href="/api/setups/${setup.id}/export?format=toml" download="setup-${setup.id}.toml">setup (TOML)</a></p></section>`;
  document.body.dataset.ready = "1";
}

main().catch((e) => { document.getElementById("report-body").innerHTML = `<p class="fail">${esc(e.message)}</p>`; });
