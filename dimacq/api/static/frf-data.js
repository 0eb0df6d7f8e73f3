// FRF values of a set as typed arrays: GET /api/frfs/{id}/data.f32 (float32 little-endian
// behind a small JSON header; dimacq/io/frf_binary.py) instead of every value as JSON.
import { authHeaders } from "/static/core.js";

/** The set's values: ``{frequencies_hz, responses, inputs, layout, real, imag, coherence,
 * nLines, nResponses, nInputs, at(l, o, j)}``; ``real``, ``imag`` and ``coherence`` are
 * Float32Array in ``[line][response][input]`` order (``coherence`` null when the set has none,
 * NaN where one average gives none); ``at`` is the flat index of (line, response, input).
 * ``query``: the selection of ``/data`` (e.g. ``"?input=0"``); ``onProgress(got, total)`` is
 * called as the bytes arrive (``total`` 0 when the answer has no length). */
export async function fetchFrfData(id, query = "", onProgress = null) {
  const path = `/api/frfs/${id}/data.f32${query}`;
  const r = await fetch(path, { headers: authHeaders() });
  if (!r.ok) {
    let detail = `HTTP ${r.status}`;
    try { const d = await r.json(); if (d && d.detail) detail = typeof d.detail === "string" ? d.detail : JSON.stringify(d.detail); } catch { /* not JSON */ }
    throw new Error(`GET ${path}: ${detail}`);
  }
  const buf = onProgress && r.body ? await readAll(r, onProgress) : await r.arrayBuffer();
  const magic = String.fromCharCode(...new Uint8Array(buf, 0, 4));
  if (magic !== "DFRF") throw new Error(`GET ${path}: not an FRF float32 message (${magic})`);
  const n = new DataView(buf).getUint32(4, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 8, n)));
  const arrays = {};
  for (const a of head.arrays) {
    const count = a.shape.reduce((p, k) => p * k, 1);
    arrays[a.name] = new Float32Array(buf, a.offset, count); // offsets are multiples of 4
  }
  const nLines = head.frequencies_hz.length;
  const nResponses = head.responses.length;
  const nInputs = head.inputs.length;
  return {
    frf_id: head.frf_id,
    layout: head.layout,
    frequencies_hz: head.frequencies_hz,
    responses: head.responses,
    inputs: head.inputs,
    real: arrays.real,
    imag: arrays.imag,
    coherence: arrays.coherence || null,
    nLines,
    nResponses,
    nInputs,
    at: (l, o, j) => (l * nResponses + o) * nInputs + j,
  };
}

/** The whole body as an ArrayBuffer, reporting the bytes read. */
async function readAll(r, onProgress) {
  const total = +r.headers.get("Content-Length") || 0;
  const reader = r.body.getReader();
  const parts = [];
  let got = 0;
  for (;;) {
    const { value, done } = await reader.read();
    if (done) break;
    parts.push(value);
    got += value.length;
    onProgress(got, total);
  }
  const out = new Uint8Array(got);
  let k = 0;
  for (const part of parts) { out.set(part, k); k += part.length; }
  return out.buffer;
}
