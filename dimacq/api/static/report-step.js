// Step 6: the report of the last solution (one printable HTML page; print it to PDF) and the
// downloads (through fetch with the token: they work on a non-loopback bind too).
import { $, on, wireDownloads } from "/static/core.js";

export function init() {
  on("solved", (s) => {
    // the report opens in a new tab: the token goes along in the fragment (never sent to the
    // server), as in the address `dimacq serve` prints
    const tok = sessionStorage.getItem("dimacq-token");
    const frag = tok ? `#token=${encodeURIComponent(tok)}` : "";
    $("#report-links").innerHTML = `<a id="report-link" href="/report?solution=${s.id}${frag}" target="_blank" rel="noopener">HTML report of solution ${s.id}</a> (print it to PDF from the browser) ·
      <a href="/api/frfs/${s.frf_id}/uff" data-download="frf-${s.frf_id}.uff">FRFs as UFF</a> ·
      <a href="/api/solutions/${s.id}" data-download="solution-${s.id}.json">solution as JSON</a>`;
    wireDownloads($("#report-links"));
  });
}
