// Step 3: acquire — "strike point 12 along −Z", each hit's force and response over time and
// their spectra, overload / double hit / drift / lost samples named, the operator's accept /
// reject / redo (the whole input) of each hit (a hit the checks rejected: Accept disabled with
// the reason, "accept anyway" for the checks an operator may overrule), per-input averages,
// strikes lost to DAQ gaps and coherence; "review every hit" switchable while it runs; stop
// keeping the accepted averages; redo one input or append the missing inputs into the FRF set.
import { $, api, dirName, emit, esc, f, guard, jobEvents, on, say, state, table } from "/static/core.js";
import { linePlot } from "/static/plot.js";

const acq = { id: null, job: null, events: null, poll: null, setup: null, perInput: 0, info: null,
  hitNumber: null, frfId: null, busy: false, reviewEpoch: 0 };
state.acq = acq;

function setupOf(id) { return state.setups.find((s) => s.id === id); }

function perInputRows(a) {
  const ex = acq.setup.setup.inputs;
  const per = ex.map(() => ({ acc: 0, rej: 0, reasons: [], coh: null, struck: false, lost: 0, lostWhy: [], state: "" }));
  (a.inputs || []).forEach((j, k) => {
    if (!per[j]) return;
    per[j].struck = true;
    per[j].coh = (a.input_coherence || [])[k] ?? null;
  });
  for (const st of a.input_states || []) {
    const p = per[st.input_index];
    if (!p) continue;
    Object.assign(p, { lost: st.lost, lostWhy: st.lost_reasons, state: st.state });
  }
  for (const av of a.averages) {
    const p = per[av.input_index];
    if (!p) continue;
    if (av.accepted) p.acc += 1;
    else { p.rej += 1; p.reasons.push(av.reason); }
  }
  return per;
}

function renderAcquisition(a, { review = true } = {}) {
  acq.info = a;
  const ex = acq.setup.setup.inputs;
  const per = perInputRows(a);
  const running = a.state === "running" || a.state === "pending";
  // what the run does, not what was asked; but not from a read older than the operator's last
  // change of the box (``review`` false): it re-ticked the box the operator had just unticked
  if (running && review) $("#acq-review").checked = !!a.review;
  const cur = (a.inputs || []).find((j) => per[j].acc < acq.perInput);
  const incomplete = (a.input_states || []).filter((st) => st.state === "incomplete").map((st) => st.name);
  if (running && a.pending_review) {
    const p = a.pending_review;
    $("#prompt").textContent = p.accept === "yes"
      ? `Hit ${p.number} on point ${ex[p.input_index].node}: accept, reject or redo the input`
      : `Hit ${p.number} on point ${ex[p.input_index].node} failed the checks (${p.reasons.join("; ")}): reject it or redo the input${p.accept === "override" ? ", or accept it anyway" : ""}`;
  } else if (running && cur !== undefined) {
    const e = ex[cur];
    $("#prompt").textContent = `Strike point ${e.node} along ${dirName(e.direction_gcs)} — input ${cur + 1}/${ex.length}, average ${per[cur].acc + 1}/${acq.perInput}`;
  } else {
    $("#prompt").textContent = `acquisition ${a.id} ${a.state}: ${a.averages_accepted} averages accepted, ${a.averages_rejected} rejected`
      + (!running && incomplete.length ? `; incomplete (no FRF): ${incomplete.join(", ")}` : "");
  }
  const done = !running && a.frf_id;
  $("#acq-inputs").innerHTML = table(["#", "node", "strike along", "accepted", "rejected", "strikes lost", "reasons", "coherence γ̄²", ""],
    per.map((p, i) => [i + 1, ex[i].node, dirName(ex[i].direction_gcs),
      p.struck ? (p.state === "incomplete" ? `<span class="fail">${p.acc}/${acq.perInput} incomplete</span>` : `${p.acc}/${acq.perInput}`) : "—",
      p.rej ? `<span class="rej">${p.rej}</span>` : 0,
      p.lost ? `<span class="warn" title="asked again; not counted against the strikes">${p.lost}</span>` : 0,
      `<span class="l small">${esc([...new Set([...p.reasons, ...p.lostWhy.map((r) => `strike lost: ${r}`)])].join("; "))}</span>`,
      p.coh === null ? "—" : `<span class="${p.coh < 0.9 ? "warn" : "ok"}">${f(p.coh, 3)}</span>`,
      done ? `<button data-redo-input="${i}">redo input</button>` : ""]));
  for (const b of document.querySelectorAll("[data-redo-input]")) {
    b.onclick = guard(() => start({ inputs: [+b.dataset.redoInput], merge: acq.frfId }));
  }
  $("#acq-state").textContent = `${a.state} — ${a.message || ""}`;
  $("#acq-state").className = `small ${["failed", "incomplete", "cancelled", "interrupted"].includes(a.state) ? "fail" : ""}`;
  $("#acq-bar").style.width = `${100 * (a.progress || 0)}%`;
  const pending = running && a.pending_review;
  for (const id of ["#hit-reject", "#hit-redo"]) $(id).disabled = !pending;
  // a hit the checks rejected is not accepted by a plain click: Accept is disabled, the reason
  // shown; "accept anyway" is there for the checks an operator may overrule (double hit,
  // overload, drift), never for samples lost (the record has holes)
  const verdict = pending ? a.pending_review.accept : "";
  $("#hit-accept").disabled = verdict !== "yes";
  $("#hit-override").hidden = verdict !== "override";
  $("#hit-override").disabled = verdict !== "override";
  $("#hit-why").textContent = !pending || verdict === "yes" ? ""
    : verdict === "override" ? `Accept is off: the checks rejected this hit (${a.pending_review.reasons.join("; ")}).`
      : `This hit cannot be accepted: ${a.pending_review.reasons.join("; ")} (the record has no data there); reject it or redo the input.`;
}

async function showHit() {
  let h;
  try { h = await api("GET", `/api/acquisitions/${acq.id}/hit`); } catch (err) { console.warn(`hit: ${err.message}`); return; }
  const x = Float64Array.from(h.time_s);
  // the force pulse lasts milliseconds: its plot shows the first 1/16 of the record
  const nF = Math.max(16, Math.floor(x.length / 16));
  state.plots.hitForce = linePlot($("#hit-force"), { x: x.subarray(0, nF), xLabel: "time, s", yLabel: "N", title: `hit ${h.number}: hammer force (peak ${f(h.peak_force_n, 3)} N)`,
    series: [{ y: Float64Array.from(h.force_n.slice(0, nF)), color: "#d62728" }] });
  state.plots.hitResp = linePlot($("#hit-resp"), { x, xLabel: "time, s", yLabel: "m/s²", title: `strongest response (output ${h.response + 1})`,
    series: [{ y: Float64Array.from(h.response_ms2) }] });
  state.plots.hitSpec = linePlot($("#hit-spec"), { x: Float64Array.from(h.frequencies_hz), xLabel: "frequency, Hz", yLabel: "dB", yRange: [-80, 3],
    title: "spectra, dB re their maximum (force red, response blue)",
    series: [{ y: Float64Array.from(h.force_db), color: "#d62728" }, { y: Float64Array.from(h.response_db), color: "#1f77b4" }] });
  const reasons = h.reasons || [];
  $("#hit-state").innerHTML = `hit ${h.number}${h.pending ? " waits for your decision" : (h.accepted ? ": accepted" : ": rejected")}; checks: `
    + (reasons.length ? reasons.map((r) => `<span class="rej">${esc(r)}</span>`).join("; ") : `<span class="ok">passed (no overload, double hit, drift or lost samples)</span>`);
  acq.hitNumber = h.pending ? h.number : null;
}

async function refresh() {
  if (acq.busy) return acq.info;
  acq.busy = true;
  const id = acq.id;
  const epoch = acq.reviewEpoch;
  try {
    const a = await api("GET", `/api/acquisitions/${id}`);
    // a read that was under way when the acquisition ended (or another started) is stale: the
    // final state, rendered by ended(), stays
    if (id !== acq.id || acq.endedId === id) return acq.info;
    const wasPending = acq.info && acq.info.pending_review ? acq.info.pending_review.number : null;
    renderAcquisition(a, { review: epoch === acq.reviewEpoch });
    const nowPending = a.pending_review ? a.pending_review.number : null;
    // the hit waiting until it is shown (a read that failed is tried again at the next poll)
    if (nowPending !== null && (nowPending !== wasPending || nowPending !== acq.hitNumber)) await showHit();
    else if (nowPending === null && a.averages.length && (!acq.lastShown || acq.lastShown !== a.averages.length)) {
      acq.lastShown = a.averages.length;
      if (!$("#acq-review").checked) await showHit();
    }
    return a;
  } finally { acq.busy = false; }
}

async function start({ inputs = null, merge = null } = {}) {
  const sid = +$("#acq-setup").value;
  acq.setup = setupOf(sid);
  if (!acq.setup) throw new Error("setup: build or import a setup first (step 1 or 2)");
  acq.perInput = +$("#averages").value;
  const body = { setup_id: sid, averages_per_input: acq.perInput, review: $("#acq-review").checked };
  if (inputs) body.inputs = inputs;
  if (merge) body.merge_frf_id = merge;
  const a = await api("POST", "/api/acquisitions", body);
  Object.assign(acq, { id: a.id, job: a.job_id, info: null, lastShown: 0 });
  $("#acq-finish").disabled = false;
  $("#acq-cancel").disabled = false;
  $("#acq-start").disabled = true;
  renderAcquisition({ ...a, averages: a.averages || [] });
  say(`acquisition ${a.id} started${inputs ? ` (inputs ${inputs.map((j) => j + 1).join(", ")}${merge ? `, into FRF set ${merge}` : ""})` : ""}`);
  // the job's server-sent events drive the page; a light poll catches hits waiting for review
  acq.events = jobEvents(a.job_id, async (type, snap) => {
    $("#acq-bar").style.width = `${100 * snap.progress}%`;
    if (type === "end" || !["pending", "running"].includes(snap.state)) await ended();
    else await refresh();
  });
  acq.poll = setInterval(guard(refresh), 400);
}

async function ended() {
  acq.endedId = acq.id;
  if (acq.events) { acq.events.close(); acq.events = null; }
  if (acq.poll) { clearInterval(acq.poll); acq.poll = null; }
  let a = await api("GET", `/api/acquisitions/${acq.id}`);
  for (let k = 0; k < 10 && a.state === "running"; k++) {
    // a job can end just before the acquisition row says so: read it again
    await new Promise((r) => setTimeout(r, 200));
    a = await api("GET", `/api/acquisitions/${acq.id}`);
  }
  renderAcquisition(a);
  $("#acq-finish").disabled = true;
  $("#acq-cancel").disabled = true;
  $("#acq-start").disabled = false;
  say(`acquisition ${a.id} ${a.state}: ${a.message}`, a.state !== "succeeded");
  if (a.frf_id) {
    acq.frfId = a.frf_id;
    await emit("frf-stored", a.frf_id);
    renderAppend(a);
  }
}

function renderAppend(a) {
  // inputs of the setup without FRFs in the set (opened by the FRF step): strike them into it
  const have = new Set((state.frfData ? state.frfData.inputs : []).map((i) => `${i.node}/${i.direction}`));
  const missing = acq.setup.setup.inputs.map((e, j) => [e, j]).filter(([e]) => !have.has(`${e.node}/${e.direction}`)).map(([, j]) => j);
  $("#acq-append").hidden = missing.length === 0;
  $("#acq-append").textContent = `Append the ${missing.length} missing input(s) to FRF set ${a.frf_id}`;
  $("#acq-append").onclick = guard(() => start({ inputs: missing, merge: a.frf_id }));
}

async function decide(decision, override = false) {
  const p = acq.info && acq.info.pending_review;
  if (!p) throw new Error("no hit waits for a decision");
  const body = { number: p.number, decision };
  if (override) body.override = true;
  await api("POST", `/api/acquisitions/${acq.id}/review`, body);
  for (const id of ["#hit-accept", "#hit-override", "#hit-reject", "#hit-redo"]) $(id).disabled = true;
  say(`hit ${p.number}: ${decision === "redo" ? "input redone (its averages dropped)" : override ? `accepted over the checks (${p.reasons.join("; ")})` : `${decision}ed`}`);
  acq.decisions = [...(acq.decisions || []), [p.number, decision]];
  await refresh();
}

export function init() {
  $("#acq-start").onclick = guard(() => start());
  $("#acq-finish").onclick = guard(async () => {
    await api("POST", `/api/acquisitions/${acq.id}/finish`);
    say(`acquisition ${acq.id}: stopping; the accepted averages are kept and their FRFs stored`);
  });
  $("#acq-cancel").onclick = guard(async () => {
    await api("POST", `/api/acquisitions/${acq.id}/stop`);
    say(`acquisition ${acq.id}: cancelled (the averages stay on disk; no FRF set)`);
  });
  $("#hit-accept").onclick = guard(() => decide("accept"));
  $("#hit-override").onclick = guard(() => decide("accept", true));
  // unticked (or ticked) while an acquisition runs: the running acquisition follows
  $("#acq-review").onchange = guard(async () => {
    const a = acq.info;
    if (!acq.id || !a || !["running", "pending"].includes(a.state)) return;
    const review = $("#acq-review").checked;
    acq.reviewEpoch += 1; // reads under way now predate the change: they leave the box alone
    const changed = await api("PATCH", `/api/acquisitions/${acq.id}`, { review });
    acq.reviewEpoch += 1; // and so do the ones that started before the change was stored
    renderAcquisition(changed);
    say(`acquisition ${acq.id}: ${review ? "every hit waits for your decision" : "the checks decide every hit from now on"}`);
  });
  $("#hit-reject").onclick = guard(() => decide("reject"));
  $("#hit-redo").onclick = guard(() => decide("redo"));
  $("#acq-setup").onchange = () => emit("open-setup", +$("#acq-setup").value);
  on("setups", (setups) => {
    $("#acq-setup").innerHTML = setups.map((s) => `<option value="${s.id}">${s.id} ${esc(s.name)}</option>`).join("");
    if (state.setup) $("#acq-setup").value = state.setup.id;
  });
  on("setup-opened", (s) => { $("#acq-setup").value = s.id; });
}
