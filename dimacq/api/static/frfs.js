// Step 4: FRFs — magnitude and coherence per input (all outputs or one), CMIF, and the
// reciprocity and driving-point checks where an input is at a response's place and direction;
// drag on a plot to pick the solve band.
import { $, api, emit, esc, f, guard, items, on, state, table } from "/static/core.js";
import { linePlot } from "/static/plot.js";
import { testQuery } from "/static/test.js";
import { fetchFrfData } from "/static/frf-data.js";

/** List the FRF sets; open ``select`` (the page does not fetch FRF values before asked). */
export async function loadFrfSets(select) {
  const sets = items(await api("GET", `/api/frfs${testQuery()}`));
  $("#frf-set").innerHTML = `<option value="">—</option>` + sets.map((s) => `<option value="${s.id}">${s.id} ${esc(s.name)} (${s.n_responses}×${s.n_inputs}×${s.n_lines})</option>`).join("");
  if (select) {
    $("#frf-set").value = select;
    await openFrf(+select);
  }
}

export async function openFrf(id) {
  const t0 = performance.now();
  const [summary, data] = await Promise.all([api("GET", `/api/frfs/${id}`), fetchFrfData(id)]);
  state.timings.frf_fetch_ms = performance.now() - t0;
  state.frf = summary;
  const nL = data.nLines;
  const nO = data.nResponses;
  const nI = data.nInputs;
  // flatten once: (line, output, input) → Float64Array per (input, output) of |H| and γ²
  const mag = [];
  const coh = [];
  for (let j = 0; j < nI; j++) {
    mag.push([]); coh.push([]);
    for (let o = 0; o < nO; o++) {
      const m = new Float64Array(nL);
      const c = new Float64Array(nL);
      for (let l = 0; l < nL; l++) {
        const k = data.at(l, o, j);
        m[l] = Math.hypot(data.real[k], data.imag[k]);
        c[l] = data.coherence ? data.coherence[k] : NaN;
      }
      mag[j].push(m); coh[j].push(c);
    }
  }
  state.frfData = { x: Float64Array.from(data.frequencies_hz), outputs: data.responses, inputs: data.inputs, mag, coh, data };
  $("#frf-input").innerHTML = data.inputs.map((inp, j) => `<option value="${j}">${j + 1}: node ${inp.node} dir ${inp.direction}</option>`).join("");
  $("#frf-output").innerHTML = `<option value="">all ${nO} outputs</option>` + data.responses.map((o, k) => `<option value="${k}">${k + 1}: node ${o.node} dir ${o.direction}</option>`).join("");
  $("#frf-info").textContent = `${nO} outputs × ${nI} inputs × ${nL} lines, ${f(summary.f_min_hz)}–${f(summary.f_max_hz)} Hz`;
  drawFrfs();
  drawCmif();
  checks();
  await emit("frf-opened", summary);
}

function drawFrfs() {
  const d = state.frfData;
  const j = +$("#frf-input").value || 0;
  const o = $("#frf-output").value;
  const outs = o === "" ? d.mag[j].map((_, k) => k) : [+o];
  const onBand = (lo, hi) => setBand(lo, hi);
  const mag = linePlot($("#frf-mag"), { x: d.x, logY: true, xLabel: "frequency, Hz", yLabel: "|H|",
    title: `FRF magnitude, input ${j + 1} (${o === "" ? `all ${d.outputs.length} outputs` : `output ${+o + 1}`})`, band: state.band,
    series: outs.map((k) => ({ y: d.mag[j][k] })), onBand });
  state.timings.frf_draw_ms = mag.ms;
  state.plots.mag = mag;
  state.plots.coh = linePlot($("#frf-coh"), { x: d.x, yRange: [0, 1.02], xLabel: "frequency, Hz", yLabel: "γ²",
    title: "coherence", band: state.band, series: outs.map((k) => ({ y: d.coh[j][k] })), onBand });
}

/** Setup geometry of the set's channels: which outputs are accelerometers, and which input is
 * at which response's place and direction (within 10 mm and 10°; ``sign`` of the directions). */
function colocated() {
  const d = state.frfData;
  const setup = state.setups.find((s) => s.id === state.frf.setup_id);
  if (!setup) return { acc: d.outputs.map((_, i) => i), pairs: [] };
  const st = setup.setup;
  const resp = new Map(st.responses.map((c) => [`${c.node}/${c.direction}`, c]));
  const exc = new Map(st.inputs.map((e) => [`${e.node}/${e.direction}`, e]));
  const acc = d.outputs.map((o, i) => i).filter((i) => resp.has(`${d.outputs[i].node}/${d.outputs[i].direction}`));
  const pairs = [];
  d.inputs.forEach((inp, j) => {
    const e = exc.get(`${inp.node}/${inp.direction}`);
    if (!e) return;
    for (const o of acc) {
      const c = resp.get(`${d.outputs[o].node}/${d.outputs[o].direction}`);
      const dist = Math.hypot(...c.position_m.map((v, k) => v - e.position_m[k]));
      const dot = c.direction_gcs.reduce((s, v, k) => s + v * e.direction_gcs[k], 0);
      if (dist < 0.01 && Math.abs(dot) > Math.cos(Math.PI / 18)) pairs.push({ input: j, output: o, sign: Math.sign(dot) });
    }
  });
  return { acc, pairs };
}

/** Driving point (input j measured at its own place and direction): a rigid body's accelerance
 * there is positive real (A = 1/m + (r×d)ᵀ I⁻¹ (r×d) > 0) and a passive structure's mobility has
 * a non-negative real part (Im A ≥ 0 with e^{jωt}); reciprocity: H_ab = H_ba for two inputs at
 * each other's response places (Maxwell–Betti). Median relative difference over the band picked
 * (all lines when none). */
function checks() {
  const d = state.frfData;
  const { pairs } = colocated();
  const re = (l, o, j) => d.data.real[d.data.at(l, o, j)];
  const im = (l, o, j) => d.data.imag[d.data.at(l, o, j)];
  const nL = d.x.length;
  const inBand = (l) => !state.band || (d.x[l] >= state.band[0] && d.x[l] <= state.band[1]);
  const rows = [];
  for (const p of pairs) {
    let pos = 0; let passive = 0; let n = 0;
    for (let l = 0; l < nL; l++) {
      if (!inBand(l)) continue;
      const a = p.sign * re(l, p.output, p.input);
      const b = p.sign * im(l, p.output, p.input);
      const m = Math.hypot(a, b);
      n += 1;
      if (a > 0) pos += 1;
      if (b >= -0.02 * m) passive += 1;
    }
    const ok = n && pos / n > 0.95 && passive / n > 0.95;
    rows.push(["driving point", `input ${p.input + 1} at output ${p.output + 1}`,
      `Re A > 0 on ${f((100 * pos) / (n || 1), 3)} % of lines; Im A ≥ 0 on ${f((100 * passive) / (n || 1), 3)} %`,
      `<span class="${ok ? "ok" : "warn"}">${ok ? "ok" : "check the sensor and the impact point"}</span>`]);
  }
  for (const p of pairs) {
    for (const q of pairs) {
      if (q.input <= p.input) continue;
      // H(out at q's input place, input p) vs H(out at p's input place, input q)
      // both along the inputs' lines of action: s_q H(q's place, p) vs s_p H(p's place, q),
      // relative to the larger of the two, or to 1 % of the driving points where both are ~0
      const diffs = [];
      for (let l = 0; l < nL; l++) {
        if (!inBand(l)) continue;
        const ar = q.sign * re(l, q.output, p.input);
        const ai = q.sign * im(l, q.output, p.input);
        const br = p.sign * re(l, p.output, q.input);
        const bi = p.sign * im(l, p.output, q.input);
        const dp = Math.hypot(re(l, p.output, p.input), im(l, p.output, p.input));
        const dq = Math.hypot(re(l, q.output, q.input), im(l, q.output, q.input));
        const den = Math.max(Math.hypot(ar, ai), Math.hypot(br, bi), 0.01 * Math.sqrt(dp * dq)) || 1;
        diffs.push(Math.hypot(ar - br, ai - bi) / den);
      }
      diffs.sort((a, b) => a - b);
      const med = diffs.length ? diffs[Math.floor(diffs.length / 2)] : NaN;
      rows.push(["reciprocity", `inputs ${p.input + 1} ↔ ${q.input + 1}`, `median |H_ab − H_ba| / |H| = ${(100 * med).toFixed(3)} %`,
        `<span class="${med < 0.1 ? "ok" : "warn"}">${med < 0.1 ? "ok" : "differ by more than 10 %"}</span>`]);
    }
  }
  state.frfChecks = rows.map((r) => ({ kind: r[0], what: r[1], value: r[2] }));
  $("#frf-checks").innerHTML = rows.length
    ? table(["check", "FRFs", "measured", "verdict"], rows)
    : `<p class="small">No input of this set is at a response's place and direction (within 10 mm and 10°): the driving-point and reciprocity checks need one (strike next to a triax, along one of its axes). Coherence and CMIF above still apply.</p>`;
}

/** CMIF: the two largest singular values of H(f) (accelerometer outputs × inputs) per line,
 * by power iteration with deflation on the Hermitian HᴴH. */
function drawCmif() {
  const d = state.frfData;
  const nI = d.inputs.length;
  const { acc: outs } = colocated();
  const nL = d.x.length;
  const K = Math.min(2, nI);
  const sv = Array.from({ length: K }, () => new Float64Array(nL));
  const re = d.data.real;
  const im = d.data.imag;
  const nO = d.outputs.length;
  for (let l = 0; l < nL; l++) {
    const Ar = new Float64Array(nI * nI);
    const Ai = new Float64Array(nI * nI);
    for (const o of outs) {
      const hr = re.subarray((l * nO + o) * nI, (l * nO + o + 1) * nI);
      const hi = im.subarray((l * nO + o) * nI, (l * nO + o + 1) * nI);
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
    series: sv.map((y) => ({ y })), onBand: (lo, hi) => setBand(lo, hi) });
}

export function setBand(lo, hi) {
  state.band = [lo, hi];
  $("#band-lo").value = lo.toFixed(1);
  $("#band-hi").value = hi.toFixed(1);
  $("#auto-band").checked = false;
  for (const k of ["mag", "coh", "cmif"]) {
    const p = state.plots[k];
    if (p) { p.opts.band = state.band; p.draw(); }
  }
  if (state.frfData) checks();
}

export function init() {
  $("#frf-set").onchange = guard(async () => { if ($("#frf-set").value) await openFrf(+$("#frf-set").value); });
  $("#frf-input").onchange = () => drawFrfs();
  $("#frf-output").onchange = () => drawFrfs();
  on("frf-stored", (id) => loadFrfSets(id));
  on("test-opened", () => loadFrfSets(state.frf && (!state.test || state.test.setup_ids.includes(state.frf.setup_id)) ? state.frf.id : undefined));
}
