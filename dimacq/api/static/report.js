// One printable HTML report of a solution: setup (with its 3-D view), data quality (averages
// accepted and rejected with their reasons, coherence per input), figures (FRFs, parameters
// against frequency) and results; UFF, JSON and setup downloads. Print to PDF from the browser.
import { api, esc, f, table, takeTokenFromFragment, wireDownloads } from "/static/core.js";
import { linePlot } from "/static/plot.js";
import { paramRows } from "/static/results.js";
import { tokenImage } from "/static/solve.js";
import { view3d } from "/static/view3d.js";

const ci = (u) => (u && u.ci95 ? `[${f(u.ci95[0], 5)}, ${f(u.ci95[1], 5)}]` : "—");

async function main() {
  takeTokenFromFragment();
  const id = new URLSearchParams(location.search).get("solution");
  const s = await api("GET", `/api/solutions/${id}`);
  const [frf, data] = await Promise.all([api("GET", `/api/frfs/${s.frf_id}`), api("GET", `/api/frfs/${s.frf_id}/data`)]);
  const setup = await api("GET", `/api/setups/${frf.setup_id}`);
  // the acquisitions behind the set: a redo / append acquisition merged into an earlier set
  // (merge_frf_id) brings that set's acquisitions along; each input's averages come from the
  // latest acquisition that struck it
  const chain = [];
  for (let fid = frf.id, guardN = 0; fid && guardN < 50; guardN++) {
    const fs = fid === frf.id ? frf : await api("GET", `/api/frfs/${fid}`);
    if (!fs.acquisition_id) break;
    const a = await api("GET", `/api/acquisitions/${fs.acquisition_id}`);
    chain.push(a);
    fid = (a.config || {}).merge_frf_id || null;
  }
  const acq = chain[0] || null;
  const struckBy = (j) => chain.find((a) => (a.inputs || []).includes(j)) || null;
  const r = s.result;
  const reasons = (r.verdict_reasons || []).map((x) => (typeof x === "string" ? x : `${x.severity || ""}: ${x.message || JSON.stringify(x)}`));
  const st = setup.setup;
  const nL = data.frequencies_hz.length;
  const resp = new Set(st.responses.map((c) => `${c.node}/${c.direction}`));
  const acc = data.responses.map((o, i) => i).filter((i) => resp.has(`${data.responses[i].node}/${data.responses[i].direction}`));
  const inBand = data.frequencies_hz.map((x) => x >= r.band_hz[0] && x <= r.band_hz[1]);
  const coh = data.inputs.map((inp, j) => {
    let sum = 0; let n = 0;
    for (let l = 0; l < nL; l++) {
      if (!inBand[l] || !data.coherence) continue;
      for (const o of acc) { const v = data.coherence[l][o][j]; if (v !== null) { sum += v; n += 1; } }
    }
    return n ? sum / n : null;
  });
  const perInput = st.inputs.map((e, j) => {
    const by = struckBy(j);
    const avs = by ? by.averages.filter((a) => a.input_index === j) : [];
    const k = data.inputs.findIndex((i) => i.node === e.node && i.direction === e.direction);
    return [j + 1, e.node, by ? by.id : "—", avs.filter((a) => a.accepted).length, avs.filter((a) => !a.accepted).length,
      `<span class="l small">${esc([...new Set(avs.filter((a) => !a.accepted).map((a) => a.reason))].join("; "))}</span>`,
      k < 0 ? "no FRF" : f(coh[k], 3)];
  });
  document.title = `dimacq report — solution ${s.id}`;
  document.getElementById("report-body").innerHTML = `
  <h1>DIM test report — solution ${s.id}</h1>
  <p class="small">setup ${setup.id} "${esc(setup.name)}", FRF set ${frf.id}${acq ? `, acquisition ${acq.id}` : ""}${frf.created_at ? `, measured ${esc(frf.created_at)}` : ""}; generated ${new Date().toISOString()} by the lab service</p>
  <section><h2>Result</h2>
  <p class="verdict ${esc(r.verdict)}">verdict: ${esc(r.verdict)}</p><ul>${reasons.map((x) => `<li>${esc(x)}</li>`).join("")}</ul>
  <p>band ${f(r.band_hz[0])}–${f(r.band_hz[1])} Hz; condition number ${f(r.condition_number, 3)}; relative residual ${f(r.residual_rel, 3)}; reference point P ${esc((r.reference_point_m || [0, 0, 0]).join(", "))} m</p>
  ${table(["parameter", "unit", "estimate", "95 % interval"], paramRows(r).map(([n, un, v, uu]) => [`<span class="l">${n}</span>`, un, f(v, 6), ci(uu)]))}</section>
  <section><h2>Setup</h2>
  <p>${st.responses.length} response channels, ${st.inputs.length} inputs, ${(st.load_cells || []).length} load cell(s); length unit ${esc(st.length_unit || "m")}</p>
  <canvas id="report-3d" class="plot"></canvas>
  ${table(["input", "node", "position, m", "line of action (GCS)"], st.inputs.map((e, i) => [i + 1, e.node, e.position_m.map((v) => f(v, 4)).join(", "), e.direction_gcs.map((v) => f(v, 3)).join(", ")]))}</section>
  <section><h2>Data quality</h2>
  <p>FRF set ${frf.id} (${esc(frf.name)}): ${frf.n_responses} outputs × ${frf.n_inputs} inputs × ${frf.n_lines} lines, ${f(frf.f_min_hz)}–${f(frf.f_max_hz)} Hz.
  ${chain.length ? `Acquisitions ${chain.map((a) => a.id).reverse().join(", ")}: ${chain.reduce((n, a) => n + a.averages_accepted, 0)} averages accepted, ${chain.reduce((n, a) => n + a.averages_rejected, 0)} rejected (every hit is kept on the stand's disk with its reason).` : "FRFs imported (no acquisition record)."}</p>
  ${table(["input", "node", "acquisition", "accepted", "rejected", "reasons", "mean γ² in band"], perInput)}
  <p>excluded responses: ${esc(JSON.stringify(r.excluded_responses || []))}; excluded inputs: ${esc(JSON.stringify(r.excluded_inputs || []))}</p></section>
  <section><h2>Figures</h2>
  <canvas id="report-frf" class="plot"></canvas>
  <img id="report-figure" alt="parameters against frequency" style="max-width:100%"></section>
  <section><h2>Downloads</h2><p><a href="/api/frfs/${frf.id}/uff" data-download="frf-${frf.id}.uff">FRFs (UFF)</a> ·
  <a href="/api/solutions/${s.id}" data-download="solution-${s.id}.json">solution (JSON)</a> ·
  <a href="/api/setups/${setup.id}/export?format=toml" data-download="setup-${setup.id}.toml">setup (TOML)</a></p></section>`;
  wireDownloads();
  view3d(document.getElementById("report-3d"), st);
  const x = Float64Array.from(data.frequencies_hz);
  const series = [];
  for (let j = 0; j < data.inputs.length && series.length < 60; j++) {
    for (const o of acc) series.push({ y: Float64Array.from(data.real.map((row, l) => Math.hypot(row[o][j], data.imag[l][o][j]))) });
  }
  linePlot(document.getElementById("report-frf"), { x, series, logY: true, band: r.band_hz, xLabel: "frequency, Hz", yLabel: "|H|, (m/s²)/N",
    title: `accelerances (${series.length} of ${acc.length * data.inputs.length}), the band shaded` });
  await tokenImage(document.getElementById("report-figure"), `/api/solutions/${s.id}/figure?format=svg`);
  document.body.dataset.ready = "1";
}

main().catch((e) => { document.getElementById("report-body").innerHTML = `<p class="fail">${esc(e.message)}</p>`; });
