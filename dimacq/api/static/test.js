// Step 0: the test — a new test (article, operator, date, notes: POST /api/tests), the tests
// listed (open ones, or archived too), opened, archived / reopened (PATCH) and deleted (DELETE,
// refused while it has setups). The open test ties the other steps together: its setups, FRF sets
// and solutions are the ones listed (?test_id=), and a setup built or imported joins it.
import { $, api, emit, esc, guard, items, say, state, table } from "/static/core.js";

const OPEN_KEY = "dimacq-test";

/** ?test_id=N for the lists of the other steps ("" when no test is open: everything). */
export const testQuery = (sep = "?") => (state.test ? `${sep}test_id=${state.test.id}` : "");

export async function loadTests() {
  const all = $("#tests-archived").checked;
  state.tests = items(await api("GET", `/api/tests${all ? "" : "?archived=false"}`));
  $("#tests").innerHTML = state.tests.length
    ? table(["id", "article", "operator", "date", "setups", "notes", ""], state.tests.map((t) => [
      t.id, `<span class="l">${esc(t.article)}</span>${t.archived ? ' <span class="small">(archived)</span>' : ""}`,
      esc(t.operator), esc(t.date), t.setup_ids.length, `<span class="l small">${esc(t.notes)}</span>`,
      `<button data-test-open="${t.id}">open</button> <button data-test-archive="${t.id}">${t.archived ? "reopen" : "archive"}</button>
       <button data-test-delete="${t.id}">delete</button>`]))
    : `<p class="small">No ${all ? "" : "open "}test yet: start one above.</p>`;
  for (const b of document.querySelectorAll("[data-test-open]")) b.onclick = guard(() => openTest(+b.dataset.testOpen));
  for (const b of document.querySelectorAll("[data-test-archive]")) b.onclick = guard(() => archiveTest(+b.dataset.testArchive));
  for (const b of document.querySelectorAll("[data-test-delete]")) b.onclick = guard(() => deleteTest(+b.dataset.testDelete));
}

function showOpen() {
  const t = state.test;
  $("#test-open").innerHTML = t
    ? `open: test ${t.id} <b>${esc(t.article)}</b>${t.operator ? `, ${esc(t.operator)}` : ""}, ${esc(t.date)}${t.archived ? " (archived)" : ""}
       <button id="test-close" type="button">close</button>`
    : "no test open: every setup, FRF set and solution is listed";
  if (t) $("#test-close").onclick = guard(() => openTest(null));
  $("#test-state").textContent = t ? `test ${t.id}: ${t.article}` : "no test open";
}

/** Open test ``id`` (null: none); the other steps list that test's setups, FRF sets and solutions. */
export async function openTest(id, { quiet = false } = {}) {
  state.test = id === null ? null : await api("GET", `/api/tests/${id}`);
  if (state.test) sessionStorage.setItem(OPEN_KEY, String(state.test.id));
  else sessionStorage.removeItem(OPEN_KEY);
  showOpen();
  await emit("test-opened", state.test);
  if (!quiet) say(state.test ? `test ${state.test.id} open: ${state.test.article}` : "no test open");
}

async function newTest() {
  const body = { article: $("#test-article").value.trim(), operator: $("#test-operator").value.trim(),
    notes: $("#test-notes").value.trim() };
  if (!body.article) throw new Error("article: give the name of the test article");
  if ($("#test-date").value) body.date = $("#test-date").value;
  const t = await api("POST", "/api/tests", body);
  $("#test-article").value = "";
  $("#test-notes").value = "";
  await loadTests();
  await openTest(t.id, { quiet: true });
  await emit("test-created", t);
  say(`new test ${t.id}: ${t.article}`);
}

async function archiveTest(id) {
  const t = state.tests.find((x) => x.id === id);
  const out = await api("PATCH", `/api/tests/${id}`, { archived: !(t && t.archived) });
  if (state.test && state.test.id === id) { state.test = out; showOpen(); }
  await loadTests();
  say(`test ${id} ${out.archived ? "archived" : "reopened"}`);
}

async function deleteTest(id) {
  await api("DELETE", `/api/tests/${id}`); // 409 while it has setups: the message says so
  if (state.test && state.test.id === id) await openTest(null, { quiet: true });
  await loadTests();
  say(`test ${id} deleted`);
}

/** The open test as stored now (its setup_ids grow as setups join it). */
export async function refreshTest() {
  if (!state.test) return;
  state.test = await api("GET", `/api/tests/${state.test.id}`);
  showOpen();
}

export function init() {
  const d = new Date();
  $("#test-date").value = `${d.getFullYear()}-${String(d.getMonth() + 1).padStart(2, "0")}-${String(d.getDate()).padStart(2, "0")}`;
  $("#new-test").onclick = guard(newTest);
  $("#tests-archived").onchange = guard(loadTests);
}

/** At load: the tests listed, and the test this tab had open (if it still exists). */
export async function load() {
  await loadTests();
  const kept = +sessionStorage.getItem(OPEN_KEY);
  const t = kept && (state.tests || []).find((x) => x.id === kept);
  state.test = t || null;
  showOpen();
}
