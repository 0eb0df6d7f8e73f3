// Step 1: the test setup — setups (list, open, import, export), a 3-D view of the nodes and
// directions, the simulated article (where its sensors and impact points are) and the rig's
// channel map (rig.toml, with the sensitivities: shown, checked and saved with the token).
import { $, api, dirName, emit, esc, f, guard, items, on, say, state, table, wireDownloads } from "/static/core.js";
import { refreshTest, testQuery } from "/static/test.js";
import { view3d } from "/static/view3d.js";

export async function loadSetups() {
  state.setups = items(await api("GET", `/api/setups${testQuery()}`));
  $("#setups tbody").innerHTML = state.setups.map((s) => `<tr><td>${s.id}</td><td class="l">${esc(s.name)}</td>
    <td>${s.n_responses}</td><td>${s.n_inputs}</td><td>${s.n_load_cells}</td>
    <td><button data-setup="${s.id}">open</button>
    <a href="/api/setups/${s.id}/export?format=toml" data-download="setup-${s.id}.toml">TOML</a></td></tr>`).join("");
  for (const b of document.querySelectorAll("[data-setup]")) {
    b.onclick = guard(() => openSetup(+b.dataset.setup));
  }
  wireDownloads($("#setups"));
  await emit("setups", state.setups);
}

export async function openSetup(id) {
  const s = state.setups.find((x) => x.id === id);
  if (!s) return;
  state.setup = s;
  const st = s.setup;
  const v = (p) => (p || []).map((x) => f(x, 4)).join(", ");
  $("#setup-detail").innerHTML = `<h3>Setup ${s.id}: ${esc(s.name)}</h3><div class="row">
    <div><h4>Responses (${st.responses.length})</h4><div class="scroll">${table(["node", "dir", "position, m", "direction (GCS)"],
      st.responses.map((c) => [c.node, c.direction, v(c.position_m), v(c.direction_gcs)]))}</div></div>
    <div><h4>Inputs (${st.inputs.length})</h4><div class="scroll">${table(["#", "node", "strike along", "position, m"],
      st.inputs.map((e, i) => [i + 1, e.node, dirName(e.direction_gcs), v(e.position_m)]))}</div></div>
    <div><h4>Load cells (${(st.load_cells || []).length})</h4>${table(["node", "position, m", "sign"],
      (st.load_cells || []).map((c) => [c.node, v(c.position_m), esc(c.sign || "")]))}</div></div>`;
  show3d(st, `setup ${s.id}`);
  await emit("setup-opened", s);
}

function show3d(geometry, what) {
  $("#view3d-what").textContent = what;
  state.view3d = view3d($("#view3d"), geometry);
}

async function importSetupFile(file) {
  const name = file.name.toLowerCase();
  const format = name.endsWith(".toml") ? "toml" : name.endsWith(".json") ? "json" : "uff";
  const out = await api("POST", `/api/setups/import?format=${format}&name=${encodeURIComponent(file.name)}${testQuery("&")}`,
    await file.arrayBuffer(), { raw: true });
  const sid = out.setup_id ?? out.id;
  await refreshTest();
  await loadSetups();
  await openSetup(sid);
  if (out.frf_id) await emit("frf-stored", out.frf_id);
  say(`imported ${file.name} as setup ${sid}${out.frf_id ? ` with FRF set ${out.frf_id}` : ""}`);
}

export async function loadArticle() {
  try {
    state.article = await api("GET", "/api/simulation/article");
  } catch {
    $("#sim-article").hidden = true;
    return false;
  }
  const a = state.article.setup;
  $("#scenario").textContent = `(${state.article.scenario})`;
  const v = (p) => p.map((x) => f(x, 3)).join(", ");
  const nodes = [...new Set(a.responses.map((c) => c.node))];
  $("#article-table").innerHTML = `<p class="small">${nodes.length} triaxial sensors (nodes ${esc(nodes.join(", "))}),
    ${a.inputs.length} impact points, ${(a.load_cells || []).length} load cell(s); GCS metres.</p>`
    + table(["input", "node", "impact point, m", "strike along"],
      a.inputs.map((e, i) => [i + 1, e.node, v(e.position_m), dirName(e.direction_gcs)]));
  if (!state.setup) show3d(a, `simulated article ${state.article.scenario}`);
  return true;
}

// ------------------------------------------------------------------ the rig's channel map
export async function loadRig() {
  const r = await api("GET", "/api/rig");
  $("#rig-path").textContent = r.path;
  $("#rig-text").value = r.text;
  showRig(r.rig, r.error);
}

function showRig(rig, error) {
  if (!rig) {
    $("#rig-table").innerHTML = `<p class="fail">${esc(error || "no rig file")}</p>`;
    return;
  }
  const chain = (x) => (x.chain_calibration ? ` × ${f(x.chain_calibration.factor, 6)} (chain calibration ±${f(100 * x.chain_calibration.u_rel, 2)} %, ${esc(x.chain_calibration.date || "")})` : "");
  const h = rig.hammers.map((x, i) => [`hammer ${i}`, "—", x.physical_channel, `${f(x.sensitivity_mv_per_n, 5)} mV/N${chain(x)}`, esc((x.inputs || []).join(", ") || "every input")]);
  const r = rig.responses.map((x) => [esc(x.key), x.node, x.physical_channel, `${f(x.sensitivity_mv_per_g, 5)} mV/g`, `±${x.range_v} V`]);
  const lc = rig.load_cells.map((x) => [`load cell ${x.node}`, x.node, `CAN id ${x.node_id}`, esc(x.calibration_file), esc(x.channel || "default")]);
  $("#rig-table").innerHTML = `<p class="small">DAQ ${f(rig.daq.sample_rate_hz, 5)} Hz; ${rig.hammers.length} hammer(s), ${rig.responses.length} accelerometer channels, ${rig.load_cells.length} load cell(s)${error ? ` — <span class="fail">${esc(error)}</span>` : ""}</p>`
    + `<div class="scroll">${table(["channel", "node", "DAQ input", "sensitivity", "range / inputs"], [...h, ...r, ...lc])}</div>`;
}

async function checkRig() {
  const out = await api("POST", "/api/rig/check", { text: $("#rig-text").value });
  showRig(out.rig, "");
  say("rig file checked: valid (not saved)");
}

async function saveRig() {
  const out = await api("PUT", "/api/rig", { text: $("#rig-text").value });
  showRig(out.rig, out.error);
  say(`rig file saved to ${out.path} (the previous one kept as ${out.path.split("/").pop()}.previous)`);
}

export function init() {
  $("#setup-file").onchange = guard(async (ev) => { if (ev.target.files[0]) await importSetupFile(ev.target.files[0]); });
  $("#rig-check").onclick = guard(checkRig);
  $("#rig-save").onclick = guard(saveRig);
  $("#show-article").onclick = () => state.article && show3d(state.article.setup, `simulated article ${state.article.scenario}`);
  on("setup-built", async (sid) => { await refreshTest(); await loadSetups(); await openSetup(sid); });
  on("test-opened", async () => {
    await loadSetups();
    // a setup of another test is closed
    if (state.setup && !state.setups.some((x) => x.id === state.setup.id)) {
      state.setup = null;
      $("#setup-detail").innerHTML = "";
      if (state.article) show3d(state.article.setup, `simulated article ${state.article.scenario}`);
    }
  });
  on("open-setup", async (sid) => openSetup(sid));
}
