// Step 5: solve — the band picked on the plots (or automatic), selection and exclusions, the ten
// parameters with 95 % intervals and the verdict, the parameters against frequency, and stored
// solutions compared side by side.
import { $, UserError, api, authHeaders, emit, esc, f, items, job, on, say, state, status, table } from "/static/core.js";
import { linePlot } from "/static/plot.js";
import { paramRows } from "/static/results.js";
import { testQuery } from "/static/test.js";

function interval(u) {
  if (!u || !u.ci95) return "—";
  return `[${f(u.ci95[0])}, ${f(u.ci95[1])}]`;
}

/** An image from the API with the token (an <img src> cannot send it). */
export async function tokenImage(img, path) {
  const r = await fetch(path, { headers: authHeaders() });
  if (!r.ok) throw new Error(`GET ${path}: HTTP ${r.status}`);
  img.src = URL.createObjectURL(await r.blob());
}

const LAST_KEY = "dimacq-solution";

/** The band as typed, checked against the open FRF set: inside its span and wide enough for the
 * estimate (a handful of lines at least: the fit per line is averaged over the band). */
function bandFromForm() {
  const lo = Number($("#band-lo").value);
  const hi = Number($("#band-hi").value);
  if ($("#band-lo").value.trim() === "" || !Number.isFinite(lo)) throw new UserError("band, Hz: type the low end (Hz), drag on the FRF plot, or tick automatic band", { selector: "#band-lo" });
  if ($("#band-hi").value.trim() === "" || !Number.isFinite(hi)) throw new UserError("band, Hz: type the high end (Hz), drag on the FRF plot, or tick automatic band", { selector: "#band-hi" });
  if (!(hi > lo)) throw new UserError(`band, Hz: the low end (${lo}) must be below the high end (${hi})`, { selector: "#band-lo" });
  const fr = state.frf;
  if (fr && fr.f_max_hz !== undefined) {
    if (lo < fr.f_min_hz || hi > fr.f_max_hz) {
      throw new UserError(`band, Hz: ${lo}–${hi} Hz is outside FRF set ${fr.id}'s ${f(fr.f_min_hz)}–${f(fr.f_max_hz)} Hz; pick a band inside it`, { selector: hi > fr.f_max_hz ? "#band-hi" : "#band-lo" });
    }
    const df = fr.n_lines > 1 ? (fr.f_max_hz - fr.f_min_hz) / (fr.n_lines - 1) : 0;
    const lines = df > 0 ? Math.floor((hi - lo) / df) + 1 : 0;
    if (df > 0 && lines < MIN_LINES) {
      throw new UserError(`band, Hz: ${lo}–${hi} Hz holds ${lines} frequency line(s) at ${f(df, 3)} Hz spacing; widen it to ${MIN_LINES} lines (${f((MIN_LINES - 1) * df, 3)} Hz) or more`, { selector: "#band-hi" });
    }
  }
  return [lo, hi];
}
const MIN_LINES = 5;

async function solve() {
  const body = { frf_id: +$("#frf-set").value };
  if (!body.frf_id) throw new UserError("FRF set: open one in step 4 first", { selector: "#frf-set" });
  if (!$("#auto-band").checked) body.band_hz = bandFromForm();
  // the old result stays readable but greyed until the new one replaces it
  $("#solution").classList.add("stale");
  $("#spec-plot").classList.add("stale");
  try {
    // one key per click: a request the network or the browser sends twice stores one solution
    const key = `solve-${Date.now().toString(36)}-${Math.random().toString(36).slice(2, 10)}`;
    const s = await api("POST", "/api/solutions", body, { headers: { "Idempotency-Key": key } });
    state.solution = s;
    sessionStorage.setItem(LAST_KEY, String(s.id));
    await renderSolution(s);
    await loadSolutions();
    say(`solution ${s.id}: verdict ${s.result.verdict}`);
    await emit("solved", s);
    return `solution ${s.id}: verdict ${s.result.verdict}`;
  } finally {
    $("#solution").classList.remove("stale");
    $("#spec-plot").classList.remove("stale");
  }
}

/** Open stored solution ``id``: its parameters, intervals, verdict, plot and report link. */
export async function openSolution(id) {
  const s = await api("GET", `/api/solutions/${id}`);
  state.solution = s;
  sessionStorage.setItem(LAST_KEY, String(s.id));
  await renderSolution(s);
  markCurrent();
  await emit("solved", s);
  return `solution ${s.id} open: verdict ${s.result.verdict}`;
}

/** After a reload: the solution this tab had open (if it belongs to the open test), else none. */
export async function restore() {
  const kept = +sessionStorage.getItem(LAST_KEY);
  if (kept && state.solutions.some((s) => s.id === kept)) await openSolution(kept);
}

function markCurrent() {
  for (const tr of document.querySelectorAll("#solutions tbody tr")) {
    tr.classList.toggle("current", !!state.solution && +tr.dataset.id === state.solution.id);
  }
}

async function renderSolution(s) {
  const r = s.result;
  const reasons = (r.verdict_reasons || []).map((x) => (typeof x === "string" ? { message: x } : x));
  const ex = (k) => (r[k] || []).map((p) => (Array.isArray(p) ? p.join("/") : `${p.node}/${p.direction}`)).join(", ") || "none";
  $("#solution").innerHTML = `<h3>solution ${s.id} (FRF set ${s.frf_id})</h3><p class="verdict ${esc(r.verdict)}">verdict: ${esc(r.verdict)}</p>
    <ul>${reasons.map((x) => `<li class="${esc(x.severity || "")}">${esc(x.severity ? `${x.severity}: ` : "")}${esc(x.message || JSON.stringify(x))}</li>`).join("")}</ul>
    <p>band ${f(r.band_hz[0])}–${f(r.band_hz[1])} Hz${r.band_selection && r.band_selection.automatic ? " (automatic)" : " (picked)"}; reference point P ${esc((r.reference_point_m || []).join(", "))} m; excluded responses: ${esc(ex("excluded_responses"))}; excluded inputs: ${esc(ex("excluded_inputs"))}</p>
    ${await truthTable(r)}`;
  await drawSpectrum(s.id);
}

/** The simulated article's true properties, once per page (null: not a simulated lab). */
async function simulatorTruth() {
  if (state.truth !== undefined) return state.truth;
  if (!state.article) return null; // no simulated device: no simulator, no truth
  try { state.truth = await api("GET", "/api/simulation/truth"); } catch { state.truth = null; }
  return state.truth;
}

/** Estimates with their intervals and, in a simulated lab, the simulator's truth beside them
 * (inertia about P only when P is the scenario's reference point). */
async function truthTable(r) {
  const rows = paramRows(r);
  const t = await simulatorTruth();
  const sameP = t && (r.reference_point_m || [0, 0, 0]).every((v, k) => Math.abs(v - (t.reference_point_m || [0, 0, 0])[k]) < 1e-9);
  const tRows = t ? paramRows({ ...t, inertia_p_kgm2: sameP ? t.inertia_p_kgm2 : [[null, null, null], [null, null, null], [null, null, null]] }) : [];
  const head = ["parameter", "unit", "estimate", "95 % interval"];
  if (t) head.push("simulator's truth (not known to the solve)", "inside the interval");
  return `${t ? `<p class="small truth-note">Simulated lab: the last columns are the simulator's truth for scenario ${esc(t.scenario)}, shown for the demonstration only; the solve reads the FRFs and the setup, never this.</p>` : ""}`
    + table(head, rows.map(([n, un, v, uu], i) => {
      const row = [`<span class="l">${n}</span>`, un, f(v, 6), interval(uu)];
      if (t) {
        const tv = tRows[i] ? tRows[i][2] : null;
        const inside = tv === null || tv === undefined || !uu || !uu.ci95 ? "—" : (tv >= uu.ci95[0] && tv <= uu.ci95[1] ? '<span class="ok">yes</span>' : '<span class="warn">no</span>');
        row.push(`<span class="truth">${f(tv, 6)}</span>`, inside);
      }
      return row;
    }));
}

async function drawSpectrum(id) {
  const sp = await api("GET", `/api/solutions/${id}/spectrum`);
  state.spectrum = sp;
  $("#spec-param").innerHTML = sp.parameters.map((p, k) => `<option value="${k}">${p} (${sp.units[k]})</option>`).join("");
  plotSpectrum(0);
}

/** Parameter ``k`` of a solution's spectrum (``GET /api/solutions/{id}/spectrum``) on ``canvas``:
 * its estimate per frequency line (blue) and the band estimate (red), the band shaded. */
export function spectrumPlot(canvas, sp, k, extra = {}) {
  const x = Float64Array.from(sp.frequencies_hz);
  const y = Float64Array.from(sp.per_line.map((row) => (row[k] === null ? NaN : row[k])));
  const inBand = [...x.keys()].filter((i) => x[i] >= sp.band_hz[0] && x[i] <= sp.band_hz[1]).map((i) => y[i]).filter(Number.isFinite);
  inBand.sort((a, b) => a - b);
  const lo = inBand.length ? inBand[Math.floor(0.02 * inBand.length)] : -1;
  const hi = inBand.length ? inBand[Math.floor(0.98 * (inBand.length - 1))] : 1;
  const pad = 0.5 * Math.max(hi - lo, Math.abs(sp.headline[k]) * 0.05, 1e-9);
  return linePlot(canvas, { x, band: sp.band_hz, xLabel: "frequency, Hz",
    yLabel: `${sp.parameters[k]}, ${sp.units[k]}`, yRange: [lo - pad, hi + pad],
    title: `${sp.parameters[k]} per frequency line (blue) and the band estimate (red)`,
    series: [{ y }, { y: new Float64Array(x.length).fill(sp.headline[k]), color: "#d62728" }], ...extra });
}

function plotSpectrum(k) {
  state.plots.spectrum = spectrumPlot($("#spec-plot"), state.spectrum, k);
}

async function loadSolutions() {
  state.solutions = items(await api("GET", `/api/solutions${testQuery()}`));
  const tok = sessionStorage.getItem("dimacq-token");
  const frag = tok ? `#token=${encodeURIComponent(tok)}` : "";
  $("#solutions tbody").innerHTML = state.solutions.map((s) => `<tr class="open-solution" data-id="${s.id}"><td><input type="checkbox" data-cmp="${s.id}"${state.solution && s.id === state.solution.id ? " checked" : ""}></td>
    <td>${s.id}</td><td>${s.frf_id}</td><td>${f(s.result.band_hz[0])}–${f(s.result.band_hz[1])}</td>
    <td class="${esc(s.result.verdict)}">${esc(s.result.verdict)}</td><td>${f(s.result.mass_kg, 5)}</td>
    <td><button type="button" data-open-solution="${s.id}">open</button> <a data-report="${s.id}" href="/report?solution=${s.id}${frag}" target="_blank" rel="noopener">report</a></td></tr>`).join("");
  for (const c of document.querySelectorAll("[data-cmp]")) c.onchange = compare;
  for (const b of document.querySelectorAll("[data-open-solution]")) {
    b.onclick = job("solve", b, `opening solution ${b.dataset.openSolution}…`, () => openSolution(+b.dataset.openSolution));
  }
  markCurrent();
  compare();
}

/** The checked solutions side by side: estimate and 95 % interval of every parameter. */
function compare() {
  const ids = [...document.querySelectorAll("[data-cmp]:checked")].map((c) => +c.dataset.cmp);
  const sols = ids.map((id) => state.solutions.find((s) => s.id === id)).filter(Boolean);
  if (sols.length < 2) { $("#compare").innerHTML = `<p class="small">Tick two or more solutions to compare them.</p>`; return; }
  const rows = paramRows(sols[0].result).map(([n, un], i) => [`<span class="l">${n}</span>`, un,
    ...sols.map((s) => { const [, , v, u] = paramRows(s.result)[i] || []; return `${f(v, 5)}<br><span class="small">${interval(u)}</span>`; })]);
  rows.push(["verdict", "", ...sols.map((s) => `<span class="${esc(s.result.verdict)}">${esc(s.result.verdict)}</span>`)]);
  rows.push(["band", "Hz", ...sols.map((s) => `${f(s.result.band_hz[0])}–${f(s.result.band_hz[1])}`)]);
  $("#compare").innerHTML = table(["parameter", "unit", ...sols.map((s) => `solution ${s.id}`)], rows);
}

export function init() {
  $("#solve-btn").onclick = job("solve", "#solve-btn", "solving (the FRFs read, the parameters fitted per line and over the band)…", solve);
  $("#spec-param").onchange = () => plotSpectrum(+$("#spec-param").value);
  on("test-opened", () => loadSolutions());
}

export async function load() { await loadSolutions(); }
