// Step 2b: photograph — geometry from photos of fiducial tags, as `dimacq geometry from-photos`:
// the photos (with tags.toml and camera.toml) uploaded into a photo folder of the service, or a
// folder already under data_dir/photos; the job's progress (photos read, the adjustment's
// evaluations); the triaxes and inputs it fixed with their 1σ, every photo that could not help
// with its fix, and a refusal naming each triax or input it cannot fix with the photos it needs.
// A fixed set is stored as digitized geometry is, with its setup: the setup opens in step 1.
import { $, api, emit, esc, f, job, jobEvents, on, state, status, table } from "/static/core.js";

const photos = { job: null, result: null, messages: [] };
state.photos = photos;

/** The setups the job can put the geometry into (step 1's list). */
function listSetups(setups) {
  const sel = $("#photo-setup");
  const keep = sel.value;
  sel.innerHTML = setups.map((s) => `<option value="${s.id}">${s.id}: ${esc(s.name)}</option>`).join("");
  if (keep && setups.some((s) => String(s.id) === keep)) sel.value = keep;
}

async function upload(folder, files) {
  let have = null;
  let k = 0;
  for (const file of files) {
    k += 1;
    status("photograph").update(`uploading ${k}/${files.length}: ${file.name}`);
    $("#photo-bar").style.width = `${(100 * k) / files.length}%`;
    const q = `folder=${encodeURIComponent(folder)}&name=${encodeURIComponent(file.name)}`;
    have = await api("POST", `/api/photo-geometry/files?${q}`, await file.arrayBuffer(), { raw: true });
  }
  return have;
}

function follow(jobId) {
  return new Promise((resolve, reject) => {
    const ev = jobEvents(jobId, (type, snap) => {
      photos.job = snap;
      $("#photo-bar").style.width = `${Math.round(100 * (snap.progress || 0))}%`;
      if (snap.message && photos.messages[photos.messages.length - 1] !== snap.message) {
        photos.messages.push(snap.message);
        status("photograph").update(snap.message);
      }
      if (type === "end") { ev.close(); resolve(snap); }
    }, (broken) => { if (broken) reject(new Error(`job ${jobId}: its progress stream broke; GET /api/jobs/${jobId} tells how it ended`)); });
  });
}

function renderResult(res) {
  const g = res.geometry;
  const deg = (v) => (v || []).map((x) => f(x, 2)).join(" / ");
  const parts = [];
  if (res.stored) {
    parts.push(`<p id="photo-verdict" class="ok">Stored: ${res.stored.orientations} triaxes, ${res.stored.lines_of_action} inputs, setup ${res.setup_id}
      (reprojection σ ${f(g.adjustment.sigma_px, 3)} px, ${g.photos.used} of ${g.photos.found} photos used).</p>`);
  } else {
    parts.push(`<div id="photo-refused" class="err"><p class="fail"><b>Refused:</b> these photos cannot fix every triax and input; nothing was stored. Take the photos named below and run again.</p>
      <ul>${res.unfixed.map((u) => `<li>${esc(u)}</li>`).join("")}</ul></div>`);
  }
  parts.push(`<div class="row"><div><h3>Triaxes</h3>${table(["node", "position, m", "1σ, mm", "axis 1σ, °", "corners"],
    g.orientations.map((o) => [o.node, o.origin_m.map((v) => v.toFixed(4)).join(", "), f(1e3 * o.origin_std_m, 3), deg(o.angle_std_deg), o.n_points]))}</div>
    <div><h3>Inputs</h3>${table(["node", "point, m", "direction", "1σ, mm", "LoA 1σ, °"],
    g.lines_of_action.map((a) => [a.node, a.point_m.map((v) => v.toFixed(4)).join(", "), a.direction.map((v) => v.toFixed(3)).join(", "), f(1e3 * a.point_std_m, 3), f(a.angle_std_deg, 3)]))}</div></div>`);
  if (res.issues.length) {
    parts.push(`<h3>Photos that could not help fully</h3><div id="photo-issues" class="scroll">${table(["photo", "", "problem", "fix"],
      res.issues.map((i) => [esc(i.photo), `<span class="${i.severity === "skipped" ? "fail" : "warn"}">${esc(i.severity)}</span>`, esc(i.problem), esc(i.fix)]))}</div>`);
  }
  $("#photo-result").innerHTML = parts.join("");
}

async function run() {
  const folder = $("#photo-folder").value.trim();
  const files = [...$("#photo-files").files];
  photos.result = null;
  photos.messages = [];
  $("#photo-result").innerHTML = "";
  $("#photo-bar").style.width = "0";
  if (files.length) await upload(folder, files);
  const body = { folder, setup_id: Number($("#photo-setup").value) || null };
  if (state.test) body.test_id = state.test.id;
  const tags = $("#photo-tags").files[0];
  const cam = $("#photo-camera").files[0];
  if (tags) body.tags_toml = await tags.text();
  if (cam) body.camera_toml = await cam.text();
  status("photograph").update(`adjusting the photos of folder ${folder}…`);
  const started = await api("POST", "/api/photo-geometry/jobs", body);
  const snap = await follow(started.id);
  if (snap.state !== "succeeded") throw new Error(`geometry from photos ${snap.state}: ${snap.error || snap.message}`);
  photos.result = snap.result;
  renderResult(snap.result);
  if (snap.result.setup_id) {
    await emit("setup-built", snap.result.setup_id);
    return `photographed geometry stored: setup ${snap.result.setup_id}`;
  }
  throw new Error(`refused: ${snap.result.unfixed.length} triaxes or inputs not fixed (see the list)`);
}

export function init() {
  $("#photo-folder").value = `photos-${new Date().toISOString().slice(0, 10)}`;
  $("#photo-run").onclick = job("photograph", "#photo-run", "geometry from photos…", run);
  on("setups", (setups) => listSetups(setups));
  on("setup-opened", (s) => { if ($("#photo-setup").querySelector(`option[value="${s.id}"]`)) $("#photo-setup").value = s.id; });
}
