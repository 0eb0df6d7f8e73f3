// One printable HTML report of a solution: setup (with its 3-D view), data quality (averages
// accepted and rejected with their reasons, coherence per input), figures (FRFs, parameters
// against frequency) and results; UFF, JSON, setup and figure downloads. Print to PDF from the browser.
import { api, esc, f, table, takeTokenFromFragment, wireDownloads } from "/static/core.js";
import { linePlot } from "/static/plot.js";
import { paramRows } from "/static/results.js";
import { spectrumPlot } from "/static/solve.js";
import { view3d } from "/static/view3d.js";

const ci = (u) => (u && u.ci95 ? `[${f(u.ci95[0], 5)}, ${f(u.ci95[1], 5)}]` : "—");

/** The accelerances drawn (min/max per group of lines, interleaved: what a plot of every line
 * shows at this width) for the first inputs, up to ~60 curves; one envelope request. */
async function frfFigure(frfId, nInputs, accKeys, width) {
  const points = Math.max(64, Math.min(600, Math.round(width / 2))); // min/max pairs: ~1 px each
  const perInput = Math.max(1, accKeys.size);
  const k = Math.min(nInputs, Math.max(1, Math.ceil(60 / perInput)));
  const e0 = await api("GET", `/api/frfs/${frfId}/envelope?${Array.from({ length: k }, (_, j) => `input=${j}`).join("&")}&points=${points}`);
  const n = e0.frequencies_hz.length;
  const x = new Float64Array(2 * n);
  for (let p = 0; p < n; p++) { x[2 * p] = e0.f_lo_hz[p]; x[2 * p + 1] = e0.f_hi_hz[p]; }
  const series = [];
  for (let j = 0; j < k; j++) {
    e0.responses.forEach((o, i) => {
      if (!accKeys.has(`${o.node}/${o.direction}`)) return;
      const y = new Float64Array(2 * n);
      for (let p = 0; p < n; p++) {
        const hi = e0.magnitude_max[p][i][j];
        const lo = e0.magnitude_min[p][i][j];
        y[2 * p] = hi === null ? NaN : hi;
        y[2 * p + 1] = lo === null ? NaN : lo;
      }
      series.push({ y });
    });
  }
  return { x, series, linesPerPoint: e0.lines_per_point, shown: k };
}

async function main() {
  const t0 = performance.now();
  takeTokenFromFragment();
  const id = new URLSearchParams(location.search).get("solution");
  const s = await api("GET", `/api/solutions/${id}`);
  const r = s.result;
  // what the report shows, not the set: the set's summary, each pair's mean coherence in the
  // band (envelope, one point) and the figure's envelopes; the acquisitions behind the set
  const frf = await api("GET", `/api/frfs/${s.frf_id}`);
  const bandQ = `f_min_hz=${r.band_hz[0]}&f_max_hz=${r.band_hz[1]}`;
  const quiet = (p) => { p.catch(() => {}); return p; }; // awaited below, where a failure is shown
  const bandP = quiet(api("GET", `/api/frfs/${frf.id}/envelope?points=1&${bandQ}`));
  const spectrumP = quiet(api("GET", `/api/solutions/${s.id}/spectrum`));
  // the acquisitions behind the set: a redo / append acquisition merged into an earlier set
  // (merge_frf_id) brings that set's acquisitions along; each input's averages come from the
  // latest acquisition that struck it
  const chainP = quiet((async () => {
    const out = [];
    for (let fid = frf.id, guardN = 0; fid && guardN < 50; guardN++) {
      const fs = fid === frf.id ? frf : await api("GET", `/api/frfs/${fid}`);
      if (!fs.acquisition_id) break;
      const a = await api("GET", `/api/acquisitions/${fs.acquisition_id}`);
      out.push(a);
      fid = (a.config || {}).merge_frf_id || null;
    }
    return out;
  })());
  const setup = await api("GET", `/api/setups/${frf.setup_id}`);
  const testP = quiet(setup.test_id ? api("GET", `/api/tests/${setup.test_id}`) : Promise.resolve(null));
  const resp = new Set(setup.setup.responses.map((c) => `${c.node}/${c.direction}`));
  const figureP = quiet(frfFigure(frf.id, frf.n_inputs, resp, Math.min(1200, document.body.clientWidth - 40)));
  const [band, chain] = await Promise.all([bandP, chainP]);
  const test = await testP;
  const acq = chain[0] || null;
  const struckBy = (j) => chain.find((a) => (a.inputs || []).includes(j)) || null;
  const reasons = (r.verdict_reasons || []).map((x) => (typeof x === "string" ? x : `${x.severity || ""}: ${x.message || JSON.stringify(x)}`));
  const st = setup.setup;
  const acc = band.responses.map((o, i) => i).filter((i) => resp.has(`${band.responses[i].node}/${band.responses[i].direction}`));
  // mean γ² of each input over the band's lines and the accelerometer outputs (each pair's mean
  // from the service, weighted alike: every pair has the band's lines)
  const coh = band.inputs.map((inp, j) => {
    if (!band.coherence_mean) return null;
    const v = acc.map((o) => band.coherence_mean[o][j]).filter((c) => c !== null);
    return v.length ? v.reduce((a, b) => a + b, 0) / v.length : null;
  });
  const perInput = st.inputs.map((e, j) => {
    const by = struckBy(j);
    const avs = by ? by.averages.filter((a) => a.input_index === j) : [];
    const k = band.inputs.findIndex((i) => i.node === e.node && i.direction === e.direction);
    return [j + 1, e.node, by ? by.id : "—", avs.filter((a) => a.accepted).length, avs.filter((a) => !a.accepted).length,
      `<span class="l small">${esc([...new Set(avs.filter((a) => !a.accepted).map((a) => a.reason))].join("; "))}</span>`,
      // hits the operator accepted over the checks: in the FRFs, their reasons on record
      `<span class="l small warn override">${esc(avs.filter((a) => a.accepted && a.reason).map((a) => `hit ${a.number}: ${a.reason.replace(/; accepted by the operator over the checks$/, "")}`).join("; "))}</span>`,
      k < 0 ? "no FRF" : f(coh[k], 3)];
  });
  document.title = `dimacq report — solution ${s.id}`;
  document.getElementById("report-body").innerHTML = `
  <h1>DIM test report — solution ${s.id}</h1>
  ${test ? `<p>test ${test.id}: <b>${esc(test.article)}</b>; operator ${esc(test.operator || "—")}; date ${esc(test.date)}${test.archived ? " (archived)" : ""}${test.notes ? `<br><span class="small">${esc(test.notes)}</span>` : ""}</p>` : ""}
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
  ${table(["input", "node", "acquisition", "accepted", "rejected", "reasons", "accepted over the checks", "mean γ² in band"], perInput)}
  <p>excluded responses: ${esc(JSON.stringify(r.excluded_responses || []))}; excluded inputs: ${esc(JSON.stringify(r.excluded_inputs || []))}</p></section>
  <section><h2>Figures</h2>
  <canvas id="report-frf" class="plot"></canvas>
  <h3>Parameters against frequency</h3><div id="report-spectrum" class="grid2"></div></section>
  <section><h2>Downloads</h2><p><a href="/api/frfs/${frf.id}/uff" data-download="frf-${frf.id}.uff">FRFs (UFF)</a> ·
  <a href="/api/solutions/${s.id}" data-download="solution-${s.id}.json">solution (JSON)</a> ·
  <a href="/api/setups/${setup.id}/export?format=toml" data-download="setup-${setup.id}.toml">setup (TOML)</a> ·
  <a href="/api/solutions/${s.id}/figure?format=svg" data-download="solution-${s.id}-parameters.svg">parameters against frequency (SVG, drawn by the service)</a></p></section>`;
  wireDownloads();
  view3d(document.getElementById("report-3d"), st);
  const canvas = document.getElementById("report-frf");
  const fig = await figureP;
  linePlot(canvas, { x: fig.x, series: fig.series, logY: true, band: r.band_hz, xLabel: "frequency, Hz", xUnit: "Hz", yLabel: "|H|", yUnit: "(m/s²)/N",
    title: `accelerances of inputs 1–${fig.shown} (${fig.series.length} of ${acc.length * frf.n_inputs}; ${fig.linesPerPoint > 1 ? `largest and smallest |H| of every ${fig.linesPerPoint} lines` : "every line"}), the band shaded` });
  // parameters against frequency: one small plot per parameter, from the solution's spectrum
  const sp = await spectrumP;
  const grid = document.getElementById("report-spectrum");
  grid.innerHTML = sp.parameters.map((p, k) => `<canvas id="report-spec-${k}" class="plot short"></canvas>`).join("");
  sp.parameters.forEach((p, k) => spectrumPlot(document.getElementById(`report-spec-${k}`), sp, k, { title: `${p} (${sp.units[k]}) per line, band estimate red` }));
  window.dimacqReport = { ready_ms: performance.now() - t0 };
  document.body.dataset.ready = "1";
}

main().catch((e) => { document.getElementById("report-body").innerHTML = `<p class="fail">${esc(e.message)}</p>`; });
