// The lab page: a small vanilla-JS app over the REST API (no build step, no outside asset).
// One module per step (test, setup, digitize, photograph, acquire, FRFs, solve, report); they share core.js and
// meet through its events (on/emit), so a new step is one more module and one more <section>.
import { $, api, guard, on, say, startHeartbeat, state, takeTokenFromFragment } from "/static/core.js";
import * as acquire from "/static/acquire.js";
import * as digitize from "/static/digitize.js";
import * as frfs from "/static/frfs.js";
import * as photograph from "/static/photograph.js";
import * as reportStep from "/static/report-step.js";
import * as setup from "/static/setup.js";
import * as solve from "/static/solve.js";
import * as test from "/static/test.js";

async function loadStatus() {
  const st = await api("GET", "/api/status");
  state.stand = st.stand || (st.lab && st.lab.stand) || null;
  $("#devices").textContent = Object.entries(st.devices).map(([k, v]) => `${k} ${v.connected ? "●" : "○"}`).join("  ");
}

async function init() {
  const t0 = performance.now();
  takeTokenFromFragment();
  $("#token-form").onsubmit = (ev) => {
    ev.preventDefault();
    sessionStorage.setItem("dimacq-token", $("#token").value.trim());
    $("#token").value = "";
    takeTokenFromFragment();
  };
  for (const step of [test, setup, digitize, photograph, acquire, frfs, solve, reportStep]) step.init();
  // the test this tab had open first: the other steps list its setups, FRF sets and solutions
  const article = setup.loadArticle();
  await Promise.all([loadStatus(), article, digitize.load(article), setup.loadRig().catch((e) => say(e.message, true)),
    test.load().then(() => Promise.all([setup.loadSetups(), frfs.loadFrfSets(), solve.load()]))
      .then(() => acquire.loadRecovery())]);
  startHeartbeat();
  on("online", () => loadStatus().catch(() => {}));
  // back to the step this tab was at (the last one it worked in)
  const step = sessionStorage.getItem("dimacq-step");
  if (step && document.getElementById(step) && !location.hash) document.getElementById(step).scrollIntoView();
  for (const sec of document.querySelectorAll("main > section")) {
    sec.addEventListener("click", () => sessionStorage.setItem("dimacq-step", sec.id));
  }
  state.timings.init_ms = performance.now() - t0;
  state.timings.ready_ms = performance.now();
  document.body.dataset.ready = "1";
  // then the results this tab had open (a large FRF set takes seconds: the page answers meanwhile)
  await Promise.all([frfs.restore().catch((e) => say(e.message, true)), solve.restore().catch((e) => say(e.message, true))]);
}

guard(init)();
