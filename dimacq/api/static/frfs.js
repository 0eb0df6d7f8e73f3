// Step 4: FRFs — magnitude and coherence per input (all outputs or one), CMIF, and the
// reciprocity and driving-point checks where an input is at a response's place and direction;
// drag on a plot to pick the solve band.
import { $, api, dirName, emit, esc, f, guard, items, on, state, status, table } from "/static/core.js";
import { linePlot } from "/static/plot.js";
import { testQuery } from "/static/test.js";
import { fetchFrfData } from "/static/frf-data.js";

/** List the FRF sets; open ``select`` (the page does not fetch FRF values before asked). */
export async function loadFrfSets(select) {
  const sets = items(await api("GET", `/api/frfs${testQuery()}`));
  $("#frf-set").innerHTML = `<option value="">—</option>` + sets.map((s) => `<option value="${s.id}">${s.id} ${esc(s.name)} (${s.n_responses}×${s.n_inputs}×${s.n_lines})</option>`).join("");
  state.frfSets = sets;
  if (select) {
    $("#frf-set").value = select;
    await openFrf(+select);
  }
}

/** Progress of an FRF set's read on ``#frf-progress`` and in the step's status line. */
function showProgress(what) {
  const bar = $("#frf-progress");
  bar.hidden = false;
  return (got, total) => {
    bar.firstElementChild.style.width = total ? `${(100 * got) / total}%` : "50%";
    status("frfs").update(`${what}: ${(got / 1e6).toFixed(1)}${total ? ` of ${(total / 1e6).toFixed(1)}` : ""} MB read`);
    if (total && got >= total) bar.hidden = true;
  };
}

/** Name of a channel as the setup and the report write it: "101+X", a load cell's "LC1 Fx". */
function channelName(c) {
  const d = c.direction;
  if (c.kind === "reaction") return `LC${c.node} ${["Fx", "Fy", "Fz", "Mx", "My", "Mz"][Math.abs(d) - 1] || d}`;
  const ax = ["X", "Y", "Z", "RX", "RY", "RZ"][Math.abs(d) - 1] || String(d);
  return `${c.node}${d < 0 ? "-" : "+"}${ax}`;
}

/** The FRF's unit as the set states it ("(m/s²)/N"); a bare numerator gets the input's. */
function frfUnit(unit, den = "N") {
  if (unit.includes("/")) return unit;
  return `${/ /.test(unit) ? `(${unit})` : unit}/${den}`;
}

const FRF_KEY = "dimacq-frf";

/** After a reload: the set this tab had open, when it is still listed (read after the page is
 * ready: a large set takes seconds, the page answers meanwhile). */
export async function restore() {
  const kept = +sessionStorage.getItem(FRF_KEY);
  if (kept && (state.frfSets || []).some((s) => s.id === kept) && (!state.frf || state.frf.id !== kept)) {
    $("#frf-set").value = kept;
    await openFrf(kept);
  }
}

export async function openFrf(id) {
  const t0 = performance.now();
  sessionStorage.setItem(FRF_KEY, String(id));
  const line = status("frfs");
  line.busy(`reading FRF set ${id}…`);
  for (const k of ["#frf-mag", "#frf-coh", "#frf-cmif"]) $(k).classList.add("stale");
  let summary;
  let data;
  try {
    [summary, data] = await Promise.all([api("GET", `/api/frfs/${id}`), fetchFrfData(id, "", showProgress(`reading FRF set ${id}`))]);
  } catch (e) {
    line.fail(e);
    throw e;
  } finally {
    $("#frf-progress").hidden = true;
    for (const k of ["#frf-mag", "#frf-coh", "#frf-cmif"]) $(k).classList.remove("stale");
  }
  state.timings.frf_fetch_ms = performance.now() - t0;
  setFrfData(summary, data);
  line.done(`FRF set ${id}: ${data.responses.length} outputs × ${data.inputs.length} inputs × ${data.frequencies_hz.length} lines, read in ${((performance.now() - t0) / 1000).toFixed(1)} s`);
  await emit("frf-opened", summary);
}

/** Show an FRF set from its arrays (``data`` as :func:`fetchFrfData` gives it: any
 * fetch that yields these arrays, JSON or binary, can feed the plots). */
export function setFrfData(summary, data) {
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
  const names = data.responses.map(channelName);
  state.frfData = { x: Float64Array.from(data.frequencies_hz), outputs: data.responses, inputs: data.inputs, mag, coh, data, names };
  const acc = data.responses.map((o, k) => [o, k]).filter(([o]) => o.kind !== "reaction");
  const lc = data.responses.map((o, k) => [o, k]).filter(([o]) => o.kind === "reaction");
  // each input with the direction it was struck along in the GCS (its UFF label is the node's)
  const setup = (state.setups || []).find((x) => x.id === summary.setup_id);
  const along = (inp) => {
    const e = setup && setup.setup.inputs.find((x) => x.node === inp.node && x.direction === inp.direction);
    return e ? ` (struck along ${dirName(e.direction_gcs)})` : "";
  };
  $("#frf-input").innerHTML = data.inputs.map((inp, j) => `<option value="${j}">${j + 1}: ${esc(channelName(inp))}${esc(along(inp))}</option>`).join("");
  $("#frf-output").innerHTML = (acc.length ? `<option value="acc">all ${acc.length} accelerometers</option>` : "")
    + (lc.length ? `<option value="lc">all ${lc.length} load-cell channels</option>` : "")
    + `<option value="">all ${nO} outputs</option>`
    + data.responses.map((o, k) => `<option value="${k}">${k + 1}: ${esc(names[k])}${o.kind === "reaction" ? " (load cell)" : ""}</option>`).join("");
  $("#frf-info").textContent = `${nO} outputs × ${nI} inputs × ${nL} lines, ${f(summary.f_min_hz)}–${f(summary.f_max_hz)} Hz`;
  drawFrfs();
  drawCmif();
  checks();
}

function drawFrfs() {
  const d = state.frfData;
  const j = +$("#frf-input").value || 0;
  const o = $("#frf-output").value;
  const byKind = (lc) => d.outputs.map((c, k) => [c, k]).filter(([c]) => (c.kind === "reaction") === lc).map(([, k]) => k);
  const outs = o === "acc" ? byKind(false) : o === "lc" ? byKind(true) : o === "" ? d.mag[j].map((_, k) => k) : [+o];
  const onBand = (lo, hi) => setBand(lo, hi);
  const inUnit = d.inputs[j] && d.inputs[j].unit ? d.inputs[j].unit : "N";
  const units = [...new Set(outs.map((k) => frfUnit(d.outputs[k].unit || "m/s²", inUnit)))];
  const what = o === "acc" ? `${outs.length} accelerometers` : o === "lc" ? `${outs.length} load-cell channels` : o === "" ? `all ${d.outputs.length} outputs` : d.names[+o];
  const scale = { logX: $("#frf-logx").checked, db: $("#frf-db").checked };
  const series = outs.map((k) => ({ y: d.mag[j][k], label: d.names[k], group: d.outputs[k].kind === "reaction" ? "load cells" : "accelerometers" }));
  const mag = linePlot($("#frf-mag"), { x: d.x, logY: true, ...scale, xLabel: "frequency, Hz", xUnit: "Hz", yLabel: "|H|",
    yUnit: units.join(" and "),
    title: `FRF magnitude, input ${j + 1} ${channelName(d.inputs[j])} (${what})`, band: state.band, keepView: true,
    series, onBand });
  state.timings.frf_draw_ms = mag.ms;
  state.plots.mag = mag;
  state.plots.coh = linePlot($("#frf-coh"), { x: d.x, logX: scale.logX, yRange: [0, 1.02], xLabel: "frequency, Hz", xUnit: "Hz", yLabel: "γ²", yUnit: "1",
    title: "coherence", band: state.band, keepView: true, legend: false, series: series.map((s, i) => ({ ...s, y: d.coh[j][outs[i]] })), onBand });
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
  const accUnit = outs.length ? (d.outputs[outs[0]].unit || "m/s²") : "m/s²";
  state.plots.cmif = linePlot($("#frf-cmif"), { x: d.x, logY: true, logX: $("#frf-logx").checked, db: $("#frf-db").checked, xLabel: "frequency, Hz", xUnit: "Hz", yLabel: "σ",
    yUnit: frfUnit(accUnit), title: "CMIF (two largest singular values, accelerometers)", band: state.band, keepView: true,
    series: sv.map((y, k) => ({ y, label: `σ${k + 1}` })), onBand: (lo, hi) => setBand(lo, hi) });
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
  // scales for the three plots at once; the wheel's zoom stays on each
  const rescale = () => {
    for (const k of ["mag", "cmif"]) if (state.plots[k]) state.plots[k].setScale({ logX: $("#frf-logx").checked, db: $("#frf-db").checked });
    if (state.plots.coh) state.plots.coh.setScale({ logX: $("#frf-logx").checked });
  };
  $("#frf-logx").onchange = rescale;
  $("#frf-db").onchange = rescale;
  $("#frf-reset").onclick = () => { for (const k of ["mag", "coh", "cmif"]) if (state.plots[k]) state.plots[k].reset(); };
  $("#frf-input").onchange = () => drawFrfs();
  $("#frf-output").onchange = () => drawFrfs();
  on("frf-stored", (id) => loadFrfSets(id));
  on("test-opened", () => loadFrfSets(state.frf && (!state.test || state.test.setup_ids.includes(state.frf.setup_id)) ? state.frf.id : undefined));
}
