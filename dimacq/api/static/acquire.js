// Step 3: acquire — "strike point 12 along −Z", each hit's force and response over time and
// their spectra, overload / double hit / drift / lost samples named, the operator's accept /
// reject / redo (the whole input) of each hit (a hit the checks rejected: Accept disabled with
// the reason, "accept anyway" for the checks an operator may overrule), per-input averages,
// strikes lost to DAQ gaps and coherence; "review every hit" switchable while it runs; stop
// keeping the accepted averages; redo one input or append the missing inputs into the FRF set.
import { $, UserError, api, conn, dirName, emit, esc, f, guard, items, job, jobEvents, on, say, state, status, table } from "/static/core.js";
import { linePlot } from "/static/plot.js";

const acq = { id: null, job: null, events: null, poll: null, setup: null, perInput: 0, info: null,
  hitNumber: null, frfId: null, busy: false, reviewEpoch: 0 };
state.acq = acq;

function setupOf(id) { return state.setups.find((s) => s.id === id); }

function perInputRows(a) {
  const ex = acq.setup.setup.inputs;
  const per = ex.map(() => ({ acc: 0, rej: 0, reasons: [], coh: null, struck: false, lost: 0, lostWhy: [], state: "", over: [] }));
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
    if (av.accepted) {
      p.acc += 1;
      // an average the operator accepted over the checks: its reasons stay on record
      if (av.reason) p.over.push(`hit ${av.number}: ${av.reason.replace(/; accepted by the operator over the checks$/, "")}`);
    } else { p.rej += 1; p.reasons.push(av.reason); }
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
      ? `Hit ${p.number} on point ${ex[p.input_index].node} ${dirName(ex[p.input_index].direction_gcs)}: accept, reject or redo the input`
      : `Hit ${p.number} on point ${ex[p.input_index].node} ${dirName(ex[p.input_index].direction_gcs)} failed the checks (${p.reasons.join("; ")}): reject it or redo the input${p.accept === "override" ? ", or accept it anyway" : ""}`;
  } else if (running && cur !== undefined) {
    const e = ex[cur];
    $("#prompt").textContent = `Strike point ${e.node} along ${dirName(e.direction_gcs)} — input ${cur + 1}/${ex.length}, average ${per[cur].acc + 1}/${acq.perInput}`;
  } else {
    $("#prompt").textContent = `acquisition ${a.id} ${a.state}: ${a.averages_accepted} averages accepted, ${a.averages_rejected} rejected`
      + (!running && incomplete.length ? `; incomplete (no FRF): ${incomplete.join(", ")}` : "");
  }
  const done = !running && a.frf_id;
  // the coherence in the band the solve will use, once the FRFs are stored (during the run:
  // the run's mean over every line, said so)
  const bc = acq.bandCoh && acq.bandCoh.acq === a.id ? acq.bandCoh : null;
  if (bc) per.forEach((p, i) => { if (bc.byInput[i] !== undefined) p.coh = bc.byInput[i]; });
  const cohHead = bc ? `coherence γ̄² in ${f(bc.band[0], 3)}–${f(bc.band[1], 3)} Hz` : "coherence γ̄² (all lines)";
  $("#acq-inputs").innerHTML = table(["#", "node", "strike along", "accepted", "rejected", "strikes lost", "reasons", "accepted over the checks", cohHead, ""],
    per.map((p, i) => [i + 1, ex[i].node, dirName(ex[i].direction_gcs),
      p.struck ? (p.state === "incomplete" ? `<span class="fail">${p.acc}/${acq.perInput} incomplete</span>` : `${p.acc}/${acq.perInput}`) : "—",
      p.rej ? `<span class="rej">${p.rej}</span>` : 0,
      p.lost ? `<span class="warn" title="asked again; not counted against the strikes">${p.lost}</span>` : 0,
      `<span class="l small">${esc([...new Set([...p.reasons, ...p.lostWhy.map((r) => `strike lost: ${r}`)])].join("; "))}</span>`,
      p.over.length ? `<span class="l small warn override">${esc(p.over.join("; "))}</span>` : "",
      p.coh === null ? "—" : `<span class="${p.coh < 0.9 ? "warn" : "ok"}">${f(p.coh, 3)}</span>`,
      done ? `<button data-redo-input="${i}">redo input</button>` : ""]));
  for (const b of document.querySelectorAll("[data-redo-input]")) {
    b.onclick = guard(() => start({ inputs: [+b.dataset.redoInput], merge: acq.frfId }));
  }
  $("#acq-state").textContent = `${a.state} — ${a.message || ""}`;
  if (running) status("acquire").update(`acquisition ${a.id} running: ${a.averages_accepted} averages accepted, ${a.averages_rejected} rejected${a.pending_review ? `; hit ${a.pending_review.number} waits for your decision` : ""}`);
  $("#acq-state").className = `small ${["failed", "incomplete", "cancelled", "interrupted"].includes(a.state) ? "fail" : ""}`;
  $("#acq-bar").style.width = `${100 * (a.progress || 0)}%`;
  // no decision while the service is unreachable: it could not be stored
  // a hit decided here stays off even when a poll sent before the decision still shows it
  const decided = a.pending_review && acq.decided && acq.decided.id === a.id && acq.decided.numbers.has(a.pending_review.number);
  const pending = running && a.pending_review && conn.online && !decided;
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
  const t = Float64Array.from(h.time_s);
  const force = Float64Array.from(h.force_n);
  // the time axis on the event: ms from the force peak, a window that holds the pulse (force)
  // and the response's first ring-down (response), not the whole record
  let ip = 0;
  for (let i = 1; i < force.length; i++) if (Math.abs(force[i]) > Math.abs(force[ip])) ip = i;
  const tp = t[ip];
  const ms = t.map((v) => 1e3 * (v - tp));
  const win = (lo, hi) => { let a = 0; while (a < ms.length - 1 && ms[a] < lo) a++; let b = a; while (b < ms.length - 1 && ms[b] <= hi) b++; return [a, b + 1]; };
  const [f0, f1] = win(-3, 12);
  const [r0, r1] = win(-20, 200);
  const resp = acq.setup && acq.setup.setup.responses[h.response];
  // "100+Z": the node and its UFF direction (±1..±3) as the setup names its channels
  const axis = (d) => (typeof d === "number" ? `${d < 0 ? "-" : "+"}${"XYZ"[Math.abs(d) - 1] || Math.abs(d)}` : String(d));
  const rname = resp ? `${resp.node}${axis(resp.direction)}` : `output ${h.response + 1}`;
  const ex = acq.setup && h.input_index !== null && h.input_index !== undefined ? acq.setup.setup.inputs[h.input_index] : null;
  const iname = ex ? `${ex.node} ${dirName(ex.direction_gcs)}` : "hammer";
  state.plots.hitForce = linePlot($("#hit-force"), { x: ms.subarray(f0, f1), xLabel: "time from the hit peak, ms", yLabel: "force, N", title: `hit ${h.number} on ${iname}: hammer force (peak ${f(h.peak_force_n, 3)} N)`,
    series: [{ y: force.subarray(f0, f1), color: "#d62728", label: `hammer (${iname})`, group: "load cells and hammer" }] });
  state.plots.hitResp = linePlot($("#hit-resp"), { x: ms.subarray(r0, r1), xLabel: "time from the hit peak, ms", yLabel: "acceleration, m/s²", title: `strongest response: ${rname}`,
    series: [{ y: Float64Array.from(h.response_ms2).subarray(r0, r1), label: rname, group: "accelerometers" }] });
  state.plots.hitSpec = linePlot($("#hit-spec"), { x: Float64Array.from(h.frequencies_hz), xLabel: "frequency, Hz", yLabel: "level, dB re peak", yRange: [-80, 3],
    title: "spectra, dB re their maximum",
    series: [{ y: Float64Array.from(h.force_db), color: "#d62728", label: "force", group: "hammer" }, { y: Float64Array.from(h.response_db), color: "#1f77b4", label: rname, group: "accelerometers" }] });
  const reasons = h.reasons || [];
  $("#hit-state").innerHTML = `hit ${h.number}${h.pending ? " waits for your decision" : (h.accepted ? ": accepted" : ": rejected")}; checks: `
    + (reasons.length ? reasons.map((r) => `<span class="rej">${esc(r)}</span>`).join("; ") : `<span class="ok">passed (no overload, double hit, drift or lost samples)</span>`);
  acq.hitNumber = h.pending ? h.number : null;
}

async function refresh() {
  if (acq.busy || !acq.id) return acq.info;
  // no reads while the service is unreachable: the banner's probe backs off, and on its return
  // the "online" handler reads again
  if (!conn.online) return acq.info;
  acq.busy = true;
  const id = acq.id;
  const epoch = acq.reviewEpoch;
  let endedNow = false;
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
    // ended while the event stream was gone (the service restarted, the stream broke)
    endedNow = !["running", "pending"].includes(a.state) && !acq.events;
    return a;
  } finally {
    acq.busy = false;
    if (endedNow) await ended();
  }
}

/** Settings as typed, checked before they are sent (the field named, the box marked). */
function formSettings() {
  const sid = +$("#acq-setup").value;
  const setup = setupOf(sid);
  if (!setup) throw new UserError("setup: build or import a setup first (step 1 or 2)", { selector: "#acq-setup" });
  const raw = $("#averages").value.trim();
  const n = Number(raw);
  if (!/^\d+$/.test(raw) || n < 1 || n > 100) {
    throw new UserError(`averages per input: give a whole number from 1 to 100 (got "${raw}")`, { field: "averages per input", selector: "#averages" });
  }
  return { sid, setup, n };
}

/** Follow acquisition ``a`` (started here, reattached or resumed): its job's events drive the
 * page and a light poll catches hits waiting for review. */
async function attach(a, what) {
  let setup = setupOf(a.setup_id);
  if (!setup && a.setup_id) setup = await api("GET", `/api/setups/${a.setup_id}`);
  if (setup) acq.setup = setup;
  if (!acq.setup) throw new UserError(`acquisition ${a.id}: its setup ${a.setup_id} is gone`);
  if (acq.events) { acq.events.close(); acq.events = null; }
  Object.assign(acq, { id: a.id, job: a.job_id, info: null, lastShown: 0, hitNumber: null,
    perInput: (a.config && a.config.averages_per_input) || acq.perInput || +$("#averages").value });
  $("#acq-setup").value = acq.setup.id;
  hold(true);
  renderAcquisition({ ...a, averages: a.averages || [] });
  status("acquire").busy(`acquisition ${a.id} ${what}`);
  say(`acquisition ${a.id} ${what}`);
  follow();
  await refresh();
  await loadRecovery();
}

function follow() {
  if (acq.events) acq.events.close();
  const id = acq.id;
  if (acq.job) {
    acq.events = jobEvents(acq.job, async (type, snap) => {
      if (id !== acq.id) return;
      $("#acq-bar").style.width = `${100 * snap.progress}%`;
      if (type === "end" || !["pending", "running"].includes(snap.state)) await ended();
      else await refresh();
    }, () => { if (id === acq.id) acq.events = null; });
  }
  if (!acq.poll) acq.poll = setInterval(guard(refresh), 400);
}

/** Start off while an acquisition runs here; Stop and Cancel on. */
function hold(running) {
  $("#acq-start").dataset.hold = running ? "1" : "";
  $("#acq-start").disabled = running || !conn.online;
  $("#acq-finish").disabled = !running || !conn.online;
  $("#acq-cancel").disabled = !running || !conn.online;
}

async function start({ inputs = null, merge = null } = {}) {
  const { sid, setup, n } = formSettings();
  acq.setup = setup;
  acq.perInput = n;
  const body = { setup_id: sid, averages_per_input: n, review: $("#acq-review").checked };
  if (inputs) body.inputs = inputs;
  if (merge) body.merge_frf_id = merge;
  const a = await api("POST", "/api/acquisitions", body);
  await attach(a, `started${inputs ? ` (inputs ${inputs.map((j) => j + 1).join(", ")}${merge ? `, into FRF set ${merge}` : ""})` : ""}`);
  return `acquisition ${a.id} running`;
}

async function ended() {
  if (acq.endedId === acq.id) return;
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
  hold(false);
  say(`acquisition ${a.id} ${a.state}: ${a.message}`, a.state !== "succeeded");
  if (a.state === "succeeded") status("acquire").done(`acquisition ${a.id} succeeded: ${a.message}`);
  else status("acquire").fail(new Error(`acquisition ${a.id} ${a.state}: ${a.message}`));
  await loadRecovery();
  if (a.frf_id) {
    acq.frfId = a.frf_id;
    await emit("frf-stored", a.frf_id);
    renderAppend(a);
    await bandCoherence(a).catch((e) => console.warn(`coherence in band: ${e.message}`));
  }
}

/** The solve's band: the one picked (step 4 / 5), else the simulated article's recommended one,
 * else the FRF set's span. */
function solveBand(frf) {
  if (state.band) return state.band;
  if (state.article && state.article.band_hz) return state.article.band_hz;
  return [frf.f_min_hz, frf.f_max_hz];
}

/** Mean ordinary coherence of each input over the accelerometers and the solve's band (one
 * envelope point of the stored set), shown in the table in place of the all-lines mean. */
async function bandCoherence(a) {
  const frf = await api("GET", `/api/frfs/${a.frf_id}`);
  const band = solveBand(frf).map((v, k) => (k === 0 ? Math.max(v, frf.f_min_hz) : Math.min(v, frf.f_max_hz)));
  const e = await api("GET", `/api/frfs/${a.frf_id}/envelope?points=1&f_min_hz=${band[0]}&f_max_hz=${band[1]}`);
  if (!e.coherence_mean) return;
  const acc = e.responses.map((o, i) => [o, i]).filter(([o]) => o.kind !== "reaction").map(([, i]) => i);
  const byInput = {};
  acq.setup.setup.inputs.forEach((inp, j) => {
    const k = e.inputs.findIndex((x) => x.node === inp.node && x.direction === inp.direction);
    if (k < 0) return;
    const v = acc.map((o) => e.coherence_mean[o][k]).filter((c) => c !== null);
    if (v.length) byInput[j] = v.reduce((s, c) => s + c, 0) / v.length;
  });
  acq.bandCoh = { acq: a.id, band, byInput };
  renderAcquisition(acq.info);
}

// --- runs never lost: the open test's running and interrupted acquisitions, with what to do
const OPEN_STATES = ["running", "pending", "interrupted", "cancelled", "failed", "incomplete"];

/** The open test's acquisitions that are running or ended short (not yet resumed or finished):
 * Reattach / Finish / Cancel a running one, Resume / Finish one that ended short. */
export async function loadRecovery() {
  if (!conn.online) return;
  const all = items(await api("GET", "/api/acquisitions"));
  const mine = state.test ? new Set(state.test.setup_ids || []) : null;
  // an ended one counts while nothing after it covers it: its kept averages are reachable here
  const open = all.filter((a) => OPEN_STATES.includes(a.state) && (!mine || mine.has(a.setup_id))
    && !(a.state === "incomplete" && !a.incomplete_inputs.length) && !(a.frf_id && a.state !== "incomplete"));
  const shown = open.filter((a) => a.id !== acq.id || a.state !== "running" || acq.endedId === a.id || !acq.poll).slice(-6);
  state.recovery = shown.map((a) => ({ id: a.id, state: a.state }));
  $("#acq-recover").innerHTML = shown.length ? `<div class="recover"><b>Acquisitions to pick up</b> ${table(["id", "setup", "state", "accepted", "message", ""], shown.map((a) => {
    const running = a.state === "running" || a.state === "pending";
    const ownStand = !a.stand || !state.stand || a.stand === state.stand;
    const acts = running
      ? `<button class="decision" data-rec="reattach" data-id="${a.id}"${ownStand ? "" : " disabled"}>Reattach</button>
         <button class="decision" data-rec="finish" data-id="${a.id}">Finish (keep accepted)</button>
         <button class="decision" data-rec="cancel" data-id="${a.id}">Cancel</button>`
      : `<button class="decision" data-rec="resume" data-id="${a.id}">Resume</button>
         <button class="decision" data-rec="finish" data-id="${a.id}">Finish (keep accepted)</button>`;
    return [a.id, a.setup_id, `<span class="${running ? "ok" : "fail"}">${esc(a.state)}</span>`,
      `${a.averages_accepted} (${a.accepted_per_input.join("/")})`, `<span class="l small">${esc(a.message || "")}</span>`, acts];
  }))}</div>` : "";
  for (const b of document.querySelectorAll("[data-rec]")) {
    b.disabled = b.disabled || !conn.online;
    b.onclick = job("acquire", b, `${b.dataset.rec} acquisition ${b.dataset.id}…`, () => recoverAction(b.dataset.rec, +b.dataset.id));
  }
}

async function recoverAction(what, id) {
  if (what === "reattach") {
    const a = await api("GET", `/api/acquisitions/${id}`);
    acq.endedId = null;
    await attach(a, "reattached: the hit waiting for a decision is back");
    return `acquisition ${id} reattached`;
  }
  if (what === "resume") {
    const a = await api("POST", `/api/acquisitions/${id}/resume`);
    acq.endedId = null;
    await attach(a, `resumes acquisition ${id}: only what it is missing is struck`);
    return `acquisition ${a.id} resumes ${id}`;
  }
  if (what === "cancel") {
    await api("POST", `/api/acquisitions/${id}/stop`);
    if (id === acq.id) { await refresh(); } else await loadRecovery();
    return `acquisition ${id} cancelled (its averages stay on disk; Resume strikes the rest)`;
  }
  // finish: a running one stops striking and keeps what was accepted; an ended one stores the
  // FRFs of its complete inputs
  const a = await api("POST", `/api/acquisitions/${id}/finish`);
  if (id !== acq.id && a.frf_id) {
    acq.setup = setupOf(a.setup_id) || acq.setup;
    acq.frfId = a.frf_id;
    await emit("frf-stored", a.frf_id);
  }
  await loadRecovery();
  return `acquisition ${id}: ${a.state === "running" ? "stopping; the accepted averages are kept" : `${a.state}: ${a.message}`}`;
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
  if (!conn.online) throw new UserError("the service is unreachable: the decision cannot be stored now");
  // one decision per hit: the buttons go off before the call (a double-click sends one)
  for (const id of ["#hit-accept", "#hit-override", "#hit-reject", "#hit-redo"]) $(id).disabled = true;
  const body = { number: p.number, decision };
  if (override) body.override = true;
  if (!acq.decided || acq.decided.id !== acq.id) acq.decided = { id: acq.id, numbers: new Set() };
  acq.decided.numbers.add(p.number);
  try {
    await api("POST", `/api/acquisitions/${acq.id}/review`, body);
  } catch (e) {
    acq.decided.numbers.delete(p.number); // not stored: the hit can be decided again
    throw e;
  }
  say(`hit ${p.number}: ${decision === "redo" ? "input redone (its averages dropped)" : override ? `accepted over the checks (${p.reasons.join("; ")})` : `${decision}ed`}`);
  await refresh();
}

export function init() {
  $("#acq-start").onclick = job("acquire", "#acq-start", "starting the acquisition…", () => start());
  $("#acq-finish").onclick = guard(async () => {
    $("#acq-finish").disabled = true;
    await api("POST", `/api/acquisitions/${acq.id}/finish`);
    say(`acquisition ${acq.id}: stopping; the accepted averages are kept and their FRFs stored`);
  });
  $("#acq-cancel").onclick = guard(async () => {
    $("#acq-cancel").disabled = true;
    await api("POST", `/api/acquisitions/${acq.id}/stop`);
    say(`acquisition ${acq.id}: cancelled (the averages stay on disk; no FRF set)`);
  });
  // the service gone: no decision can be stored; back: what ran is read again, what ended
  // short is offered for Resume / Finish
  on("offline", () => {
    for (const id of ["#hit-accept", "#hit-override", "#hit-reject", "#hit-redo", "#acq-start", "#acq-finish", "#acq-cancel"]) $(id).disabled = true;
    for (const b of document.querySelectorAll("[data-rec]")) b.disabled = true;
    if (acq.events) { acq.events.close(); acq.events = null; }
    status("acquire").fail(new Error("the service is unreachable: decisions are off until it answers again"));
  });
  on("online", async () => {
    if (acq.id && acq.endedId !== acq.id) {
      const a = await refresh();
      if (a && ["running", "pending"].includes(a.state)) { follow(); hold(true); }
    } else hold(false);
    await loadRecovery();
  });
  on("test-opened", () => guard(loadRecovery)());
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
