// Step 2: digitize — a new test, reference nodes (editable), live point readout with shots and
// echo rejections, registration residual per node with its limit, jig orientations, lines of
// action, redo a point; in simulation the page points the simulated probe at the article.
import { $, UserError, api, dirName, emit, esc, f, guard, items, job, mm, on, say, state, table } from "/static/core.js";

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

const aimed = new Map(); // label → GCS point the simulated probe was put on (redo a point)

async function digitize(label, pGcs, dacs) {
  aimed.set(label, [pGcs, dacs]);
  const body = { label, shots: +$("#shots").value };
  if (pGcs) body.sim_probe = { tip_m: dacs(pGcs), axis: [0, 0, 1] };
  const p = await api("POST", "/api/digitizer/points", body);
  geo.points.push(p);
  const rej = p.n_shots - p.n_used;
  $("#readout").textContent = `${p.label}\narray  ${p.position_array_m.map((v) => v.toFixed(4)).join("  ")} m\n`
    + `spread ${p.spread_m.map((v) => (1e3 * v).toFixed(3)).join("  ")} mm\n`
    + `shots ${p.n_shots}, used ${p.n_used}, echoes rejected ${rej}`;
  return p;
}

function renderPoints() {
  $("#points").innerHTML = table(["label", "array position, m", "GCS position, m", "shots", "rejected", ""],
    geo.points.map((p) => [`<span class="l">${esc(p.label)}</span>`, p.position_array_m.map((v) => v.toFixed(4)).join(", "),
      p.position_m ? p.position_m.map((v) => v.toFixed(4)).join(", ") : "—", p.n_shots,
      p.n_shots - p.n_used ? `<span class="rej">${p.n_shots - p.n_used}</span>` : 0,
      `<button data-redo-point="${esc(p.label)}">redo</button>`]));
  for (const b of document.querySelectorAll("[data-redo-point]")) b.onclick = guard(() => redoPoint(b.dataset.redoPoint));
}

/** Digitize a point again (same label: the newer point is the one used); refit what uses it. */
async function redoPoint(label) {
  const [pGcs, dacs] = aimed.get(label) || [null, null];
  const p = await digitize(label, pGcs, dacs);
  geo.points = await api("GET", "/api/digitizer/points");
  renderPoints();
  say(`point ${label} digitized again (${p.n_used}/${p.n_shots} shots used); fit its registration, orientation or line of action again`);
}

// ------------------------------------------------------------------ session and reference nodes
/** A fresh digitizing session for the open test (POST /api/digitizer/tests, named after it): new
 * patch, reference nodes, orientations and lines of action cleared. */
async function newSession() {
  const t = state.test;
  const name = t ? `test ${t.id}: ${t.article}` : `session ${new Date().toISOString().slice(0, 16)}`;
  await api("POST", "/api/digitizer/tests", { name: name.slice(0, 200) });
  Object.assign(geo, { points: [], orientations: [], loas: [], registration: null, triaxes: [], inputs: [] });
  for (const id of ["#points", "#registration", "#orientations", "#loas"]) $(id).innerHTML = "";
  $("#readout").textContent = "—";
  await loadReferenceNodes();
  $("#test-state").textContent = `${name}: new digitizing session (new patch; reference nodes, orientations and lines of action cleared)`;
}

async function loadReferenceNodes() {
  const refs = await api("GET", "/api/digitizer/reference-nodes");
  renderReferenceNodes(refs);
}

function renderReferenceNodes(refs) {
  $("#refnodes").innerHTML = table(["label", "x, m", "y, m", "z, m", ""], refs.map((r) => {
    const p = r.position_m || r.gcs_m || r.position || [0, 0, 0];
    return [`<span class="l">${esc(r.label)}</span>`, ...p.map((v) => f(v, 5)), `<button data-del-ref="${esc(r.label)}">remove</button>`];
  }));
  for (const b of document.querySelectorAll("[data-del-ref]")) {
    b.onclick = guard(async () => {
      await api("DELETE", `/api/digitizer/reference-nodes/${encodeURIComponent(b.dataset.delRef)}`);
      await loadReferenceNodes();
    });
  }
}

/** The article's extent (GCS, m): the box around the positions of the simulated article or of
 * the open setup; null when neither is known. */
function articleBox() {
  const st = (state.article && state.article.setup) || (state.setup && state.setup.setup);
  if (!st) return null;
  const pts = [...(st.responses || []), ...(st.inputs || []), ...(st.load_cells || [])].map((c) => c.position_m).filter(Boolean);
  if (!pts.length) return null;
  const lo = [0, 1, 2].map((k) => Math.min(...pts.map((q) => q[k])));
  const hi = [0, 1, 2].map((k) => Math.max(...pts.map((q) => q[k])));
  return { lo, hi, size: Math.max(...hi.map((v, k) => v - lo[k])) };
}

async function setReferenceNode() {
  const label = $("#ref-label").value.trim();
  const ids = ["#ref-x", "#ref-y", "#ref-z"];
  const p = ids.map((id) => Number($(id).value.trim() === "" ? NaN : $(id).value));
  if (!label) throw new UserError("reference node label: give one (e.g. REF1)", { selector: "#ref-label" });
  const bad = p.findIndex((v) => !Number.isFinite(v));
  if (bad >= 0) throw new UserError(`reference node ${"xyz"[bad]}: give a number in m`, { selector: ids[bad] });
  // a reference node is on or next to the article: within its size of its box (at least 1 m)
  const box = articleBox();
  if (box) {
    const margin = Math.max(1, box.size);
    const out = p.findIndex((v, k) => v < box.lo[k] - margin || v > box.hi[k] + margin);
    if (out >= 0) {
      throw new UserError(`reference node ${"xyz"[out]} = ${p[out]} m is ${f(Math.abs(p[out] - (p[out] < box.lo[out] ? box.lo[out] : box.hi[out])), 3)} m outside the article (${f(box.lo[out], 3)}…${f(box.hi[out], 3)} m along ${"xyz"[out]}); give the node's position in m, in the GCS`, { selector: ids[out] });
    }
  }
  renderReferenceNodes(await api("PUT", `/api/digitizer/reference-nodes/${encodeURIComponent(label)}`, { position_m: p }));
  return `reference node ${label} set`;
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

function renderOrientations() {
  $("#orientations").innerHTML = table(["node", "points", "residual RMS, mm", "uncertainty, °"],
    geo.orientations.map((r) => [r.node, r.n_points, mm(r.residual_rms_m), f(r.uncertainty_deg, 3)]));
}

function renderLoas() {
  $("#loas").innerHTML = table(["node", "direction (GCS)", "strike along", "perp. RMS, mm", "angle std, °"],
    geo.loas.map((l) => [l.node, l.direction.map((v) => v.toFixed(3)).join(", "), dirName(l.direction), mm(l.perpendicular_rms_m), f(l.angle_std_deg, 3)]));
}

/** After a reload: the session's points, jig orientations and lines of action as stored (the
 * setup can be built from them without digitizing again). */
async function loadGeometry() {
  const [points, orientations, loas] = await Promise.all([api("GET", "/api/digitizer/points"),
    api("GET", "/api/digitizer/orientations"), api("GET", "/api/digitizer/lines-of-action")]);
  Object.assign(geo, { points: items(points), orientations: items(orientations), loas: items(loas) });
  geo.triaxes = geo.orientations.map((o) => o.node);
  geo.inputs = geo.loas.map((l) => l.node);
  if (geo.points.length) renderPoints();
  if (geo.orientations.length) renderOrientations();
  if (geo.loas.length) renderLoas();
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
  renderReferenceNodes(await api("PUT", "/api/digitizer/reference-nodes", { nodes: refs }));
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
    renderOrientations();
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
    renderLoas();
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
  if (state.test) {
    // the setup joins the open test and is named after it
    body.test_id = state.test.id;
    body.name = `${state.test.article}${state.test.operator ? ` (${state.test.operator})` : ""} ${state.test.date}`.slice(0, 200);
  }
  const s = await api("POST", "/api/setups/from-geometry", body);
  await emit("setup-built", s.id);
  say(`setup ${s.id}: ${s.n_responses} responses, ${s.n_inputs} inputs, ${s.n_load_cells} load cell(s)`);
}

export function init() {
  $("#new-session").onclick = guard(async () => { await newSession(); say($("#test-state").textContent); });
  on("test-created", () => newSession());
  $("#ref-set").onclick = job("digitize", "#ref-set", "setting the reference node…", setReferenceNode);
  $("#digitize-all").onclick = guard(async () => {
    $("#digitize-all").disabled = true;
    try { await digitizeAll(); } finally { $("#digitize-all").disabled = false; }
  });
  $("#build-setup").onclick = guard(buildSetup);
}

/** At load: the reference nodes (no need to wait for the article) and, once the article is
 * known (``article``: the promise of setup.loadArticle), the simulated digitizing controls. */
export async function load(article) {
  await Promise.all([loadReferenceNodes(), loadGeometry().catch((e) => say(e.message, true)), article.then(() => {
    if (!state.article) $("#digitize-all").disabled = true;
    else $("#n-inputs").value = state.article.setup.inputs.length;
  })]);
}
