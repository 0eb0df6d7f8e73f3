// A 3-D view of a setup's nodes and directions on a canvas: response channels (blue arrows from
// each node along its measuring axis), inputs (red arrows along the line of action, ending at
// the impact point), load cells (green squares), the reference point P (black cross), and the
// GCS axes. Orthographic projection; drag to turn it, double-click to return to the start view.

const COL = { resp: "#1f77b4", input: "#d62728", cell: "#2ca02c", ref: "#000", axis: "#888" };

/**
 * geometry: {responses: [{node, direction, position_m, direction_gcs}], inputs: [same],
 *            load_cells: [{node, position_m}], reference_point_m, extra: [{label, position_m}]}
 * Returns {draw(), view: {yaw, pitch}}.
 */
export function view3d(canvas, geometry) {
  const view = { yaw: -0.6, pitch: 0.5 };
  const ctx = canvas.getContext("2d");
  const pts = [
    ...geometry.responses.map((c) => c.position_m),
    ...geometry.inputs.map((e) => e.position_m),
    ...(geometry.load_cells || []).map((c) => c.position_m),
    ...(geometry.extra || []).map((p) => p.position_m),
    geometry.reference_point_m || [0, 0, 0],
  ];
  const lo = [0, 1, 2].map((k) => Math.min(...pts.map((p) => p[k])));
  const hi = [0, 1, 2].map((k) => Math.max(...pts.map((p) => p[k])));
  const c = [0, 1, 2].map((k) => 0.5 * (lo[k] + hi[k]));
  const span = Math.max(...[0, 1, 2].map((k) => hi[k] - lo[k])) || 1;
  const arrow = 0.12 * span;

  function project(p, w, h) {
    // turn about Z (yaw), then tilt about the screen's horizontal (pitch); Z up on screen
    const x = p[0] - c[0];
    const y = p[1] - c[1];
    const z = p[2] - c[2];
    const cy = Math.cos(view.yaw);
    const sy = Math.sin(view.yaw);
    const xr = cy * x - sy * y;
    const yr = sy * x + cy * y;
    const cp = Math.cos(view.pitch);
    const sp = Math.sin(view.pitch);
    const up = cp * z - sp * yr; // screen up
    const depth = sp * z + cp * yr;
    const s = (0.5 * Math.min(w, h)) / span;
    return [w / 2 + s * xr, h / 2 - s * up, depth];
  }

  function arrowTo(a, b, color, w, h, width = 1.5) {
    const [x0, y0] = project(a, w, h);
    const [x1, y1] = project(b, w, h);
    ctx.strokeStyle = color;
    ctx.fillStyle = color;
    ctx.lineWidth = width;
    ctx.beginPath();
    ctx.moveTo(x0, y0);
    ctx.lineTo(x1, y1);
    ctx.stroke();
    const ang = Math.atan2(y1 - y0, x1 - x0);
    ctx.beginPath();
    ctx.moveTo(x1, y1);
    ctx.lineTo(x1 - 7 * Math.cos(ang - 0.4), y1 - 7 * Math.sin(ang - 0.4));
    ctx.lineTo(x1 - 7 * Math.cos(ang + 0.4), y1 - 7 * Math.sin(ang + 0.4));
    ctx.closePath();
    ctx.fill();
  }

  function draw() {
    const dpr = window.devicePixelRatio || 1;
    const w = canvas.clientWidth || 420;
    const h = canvas.clientHeight || 320;
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    ctx.font = "10px sans-serif";
    // GCS axes at the origin
    "XYZ".split("").forEach((name, k) => {
      const e = [0, 0, 0];
      e[k] = arrow;
      arrowTo([0, 0, 0], e, COL.axis, w, h, 1);
      const [x, y] = project(e, w, h);
      ctx.fillStyle = COL.axis;
      ctx.fillText(name, x + 3, y - 3);
    });
    for (const p of geometry.extra || []) {
      const [x, y] = project(p.position_m, w, h);
      ctx.fillStyle = "#aaa";
      ctx.fillRect(x - 1.5, y - 1.5, 3, 3);
    }
    const labelled = new Set();
    for (const ch of geometry.responses) {
      const p = ch.position_m;
      const d = ch.direction_gcs;
      arrowTo(p, p.map((v, k) => v + 0.5 * arrow * d[k]), COL.resp, w, h, 1.2);
      if (!labelled.has(ch.node)) {
        labelled.add(ch.node);
        const [x, y] = project(p, w, h);
        ctx.fillStyle = COL.resp;
        ctx.beginPath();
        ctx.arc(x, y, 3, 0, 2 * Math.PI);
        ctx.fill();
        ctx.fillText(String(ch.node), x + 4, y + 10);
      }
    }
    for (const e of geometry.inputs) {
      const p = e.position_m;
      const d = e.direction_gcs;
      arrowTo(p.map((v, k) => v - arrow * d[k]), p, COL.input, w, h, 2);
      const [x, y] = project(p.map((v, k) => v - arrow * d[k]), w, h);
      ctx.fillStyle = COL.input;
      ctx.fillText(String(e.node), x - 4, y - 4);
    }
    for (const lc of geometry.load_cells || []) {
      const [x, y] = project(lc.position_m, w, h);
      ctx.fillStyle = COL.cell;
      ctx.fillRect(x - 5, y - 5, 10, 10);
      ctx.fillText(`LC${lc.node}`, x + 7, y + 4);
    }
    const [px, py] = project(geometry.reference_point_m || [0, 0, 0], w, h);
    ctx.strokeStyle = COL.ref;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    ctx.moveTo(px - 5, py - 5); ctx.lineTo(px + 5, py + 5);
    ctx.moveTo(px + 5, py - 5); ctx.lineTo(px - 5, py + 5);
    ctx.stroke();
    ctx.fillStyle = COL.ref;
    ctx.fillText("P", px + 6, py - 4);
  }

  let drag = null;
  canvas.style.cursor = "grab";
  canvas.addEventListener("pointerdown", (ev) => { drag = [ev.clientX, ev.clientY, view.yaw, view.pitch]; canvas.setPointerCapture(ev.pointerId); });
  canvas.addEventListener("pointermove", (ev) => {
    if (!drag) return;
    view.yaw = drag[2] + (ev.clientX - drag[0]) * 0.01;
    view.pitch = Math.max(-1.5, Math.min(1.5, drag[3] + (ev.clientY - drag[1]) * 0.01));
    draw();
  });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("dblclick", () => { view.yaw = -0.6; view.pitch = 0.5; draw(); });
  draw();
  return { draw, view };
}
