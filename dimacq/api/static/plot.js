// Canvas line plots for a lab: many series × many points; linear or log frequency, linear, log or
// dB value axis; wheel zoom, drag pan, double-click reset; a cursor readout (x, value, channel);
// a legend by channel name grouped by kind (accelerometers apart from load cells); a band picked
// by dragging. Canvas rather than SVG: 30 series × 2048 lines are 60 000 vertices, one path each.
// The data are plain arrays (Float64Array or Array): any fetch (JSON, binary) can feed them.
//
// The plot's state is readable: plot.view() returns the axis ranges and scales, and the canvas
// carries them as data attributes (data-x-min, data-x-max, data-x-scale, data-y-min, data-y-max,
// data-y-scale), for a test or the curious engineer.

const COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2",
  "#17becf", "#7f7f7f", "#bcbd22"];

function niceTicks(lo, hi, n) {
  const span = hi - lo || 1;
  const step0 = span / n;
  const mag = 10 ** Math.floor(Math.log10(step0));
  const step = [1, 2, 5, 10].map((k) => k * mag).find((s) => s >= step0) || mag * 10;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * span; v += step) out.push(v);
  return out;
}

/** Ticks of a log axis: 1, 2, 5 × decades when few decades, decades otherwise. */
function logTicks(lo, hi) {
  const out = [];
  const e0 = Math.floor(Math.log10(lo));
  const e1 = Math.ceil(Math.log10(hi));
  const mults = e1 - e0 <= 3 ? [1, 2, 5] : [1];
  for (let e = e0; e <= e1; e++) for (const m of mults) { const v = m * 10 ** e; if (v >= lo && v <= hi) out.push(v); }
  return out;
}

export function fmt(v) {
  const a = Math.abs(v);
  if (a !== 0 && (a < 1e-2 || a >= 1e4)) return v.toExponential(a < 1e-2 || a >= 1e5 ? 1 : 0).replace("e+", "e");
  return String(+v.toPrecision(3));
}

/**
 * Draw series on a canvas.
 * opts: {x, series: [{y, label, group, color}], logX, logY, db, yLabel, xLabel, xUnit, yUnit,
 *        yRange, band: [lo, hi] | null, onBand(lo, hi), title, legend (default: when labelled)}
 * ``db``: the values are magnitudes drawn as 20 log10(|y|) (dB re 1 in ``yUnit``).
 * Returns the plot: {draw(), view(), reset(), zoomX(f, about), setScale({logX, logY, db}), ms}.
 */
export function linePlot(canvas, opts) {
  const plot = { opts, ms: 0, zoom: null, cursor: null };
  // one plot per canvas: the previous one's listeners go, its zoom stays when asked (keepView)
  const prev = canvas._plot;
  if (prev) prev.abort.abort();
  if (prev && opts.keepView) plot.zoom = prev.zoom;
  plot.abort = new AbortController();
  const sig = { signal: plot.abort.signal };
  canvas._plot = plot;
  const pad = { l: 66, r: 12, t: 22, b: 36 };
  const ctx = canvas.getContext("2d");
  let drag = null;
  let pan = null;

  const vy = (v) => (opts.db ? (v > 0 ? 20 * Math.log10(v) : NaN) : v);

  function autoRanges() {
    const x = opts.x;
    let xlo = x[0];
    if (opts.logX && !(xlo > 0)) { let i = 0; while (i < x.length && !(x[i] > 0)) i++; xlo = x[Math.min(i, x.length - 1)]; }
    const xr = [xlo, x[x.length - 1]];
    let yr = opts.db ? null : opts.yRange;
    if (!yr) {
      let lo = Infinity;
      let hi = -Infinity;
      for (const s of opts.series) {
        for (let i = 0; i < s.y.length; i++) {
          const v = vy(s.y[i]);
          if (!Number.isFinite(v) || (opts.logY && !opts.db && !(v > 0))) continue;
          if (v < lo) lo = v;
          if (v > hi) hi = v;
        }
      }
      if (!isFinite(lo)) { lo = opts.logY && !opts.db ? 1e-6 : 0; hi = 1; }
      if (opts.logY && !opts.db) lo = Math.max(lo, hi * 1e-8);
      if (opts.db) lo = Math.max(lo, hi - 160);
      if (lo === hi) { lo -= 1; hi += 1; }
      yr = [lo, hi];
    }
    return { xr, yr };
  }

  /** The axes' ranges and scales as drawn now. */
  plot.view = () => {
    const a = autoRanges();
    const z = plot.zoom || {};
    return { x: z.x || a.xr, y: z.y || a.yr, xScale: opts.logX ? "log" : "linear",
      yScale: opts.db ? "dB" : opts.logY ? "log" : "linear", zoomed: !!plot.zoom };
  };

  function draw() {
    const t0 = performance.now();
    const dpr = window.devicePixelRatio || 1;
    const w = canvas.clientWidth || 600;
    const h = canvas.clientHeight || 260;
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    const v = plot.view();
    const xr = v.x;
    const yr = v.y;
    const logY = opts.logY && !opts.db;
    const tx = opts.logX ? (u) => Math.log10(u) : (u) => u;
    const ty = logY ? (u) => Math.log10(u) : (u) => u;
    const x0 = tx(xr[0]);
    const x1 = tx(xr[1]);
    const y0 = ty(yr[0]);
    const y1 = ty(yr[1]);
    const sx = (w - pad.l - pad.r) / (x1 - x0 || 1);
    const sy = (h - pad.t - pad.b) / (y1 - y0 || 1);
    const X = (u) => pad.l + (tx(u) - x0) * sx;
    const Y = (u) => h - pad.b - (ty(u) - y0) * sy;
    plot.X = X;
    plot.invX = (px) => { const t = x0 + (px - pad.l) / sx; return opts.logX ? 10 ** t : t; };
    plot.invY = (py) => { const t = y0 + (h - pad.b - py) / sy; return logY ? 10 ** t : t; };
    plot.frame = { l: pad.l, r: w - pad.r, t: pad.t, b: h - pad.b };
    // band
    if (opts.band) {
      ctx.fillStyle = "rgba(255, 200, 0, 0.25)";
      const a = Math.max(X(opts.band[0]), pad.l);
      const b = Math.min(X(opts.band[1]), w - pad.r);
      if (b > a) ctx.fillRect(a, pad.t, b - a, h - pad.t - pad.b);
    }
    // axes, grid and ticks
    ctx.strokeStyle = "#999";
    ctx.fillStyle = "#333";
    ctx.font = "11px sans-serif";
    ctx.lineWidth = 1;
    ctx.strokeRect(pad.l, pad.t, w - pad.l - pad.r, h - pad.t - pad.b);
    ctx.textAlign = "center";
    const xt = opts.logX ? logTicks(xr[0], xr[1]) : niceTicks(xr[0], xr[1], 8);
    ctx.strokeStyle = "#eee";
    for (const t of xt) {
      ctx.beginPath(); ctx.moveTo(X(t), pad.t); ctx.lineTo(X(t), h - pad.b); ctx.stroke();
      ctx.fillText(fmt(t), X(t), h - pad.b + 14);
    }
    ctx.textAlign = "right";
    const yt = logY ? logTicks(yr[0], yr[1]).filter((t, i, all) => all.length < 12 || Math.abs(Math.log10(t) % 1) < 1e-9) : niceTicks(yr[0], yr[1], 5);
    for (const t of yt) {
      ctx.beginPath(); ctx.moveTo(pad.l, Y(t)); ctx.lineTo(w - pad.r, Y(t)); ctx.stroke();
      ctx.fillText(fmt(t), pad.l - 4, Y(t) + 4);
    }
    ctx.strokeStyle = "#999";
    ctx.textAlign = "center";
    const xLab = opts.xLabel ? `${opts.xLabel}${opts.logX ? " (log)" : ""}` : "";
    if (xLab) ctx.fillText(xLab, pad.l + (w - pad.l - pad.r) / 2, h - 6);
    if (opts.title) ctx.fillText(opts.title, pad.l + (w - pad.l - pad.r) / 2, 14);
    const yLab = plot.yLabel();
    if (yLab) {
      ctx.save();
      ctx.translate(12, pad.t + (h - pad.t - pad.b) / 2);
      ctx.rotate(-Math.PI / 2);
      ctx.fillText(yLab, 0, 0);
      ctx.restore();
    }
    // series (clipped to the frame)
    ctx.save();
    ctx.beginPath();
    ctx.rect(pad.l, pad.t, w - pad.l - pad.r, h - pad.t - pad.b);
    ctx.clip();
    const x = opts.x;
    const floor = logY ? yr[0] * 1e-3 : -Infinity;
    opts.series.forEach((s, k) => {
      ctx.strokeStyle = colorOf(s, k);
      ctx.beginPath();
      let pen = false;
      for (let i = 0; i < x.length; i++) {
        if (opts.logX && !(x[i] > 0)) continue;
        const u = vy(s.y[i]);
        if (!Number.isFinite(u)) { pen = false; continue; }
        const yy = Y(Math.max(u, floor));
        if (!pen) { ctx.moveTo(X(x[i]), yy); pen = true; } else ctx.lineTo(X(x[i]), yy);
      }
      ctx.stroke();
    });
    // the cursor: a vertical line at the nearest line, the value of the nearest series
    if (plot.cursor) {
      const c = plot.cursor;
      ctx.strokeStyle = "rgba(0,0,0,0.5)";
      ctx.setLineDash([4, 3]);
      ctx.beginPath(); ctx.moveTo(X(c.x), pad.t); ctx.lineTo(X(c.x), h - pad.b); ctx.stroke();
      ctx.setLineDash([]);
      if (Number.isFinite(c.value)) {
        ctx.fillStyle = c.color;
        ctx.beginPath(); ctx.arc(X(c.x), Y(Math.max(c.value, floor)), 3.5, 0, 2 * Math.PI); ctx.fill();
        const text = c.text;
        ctx.font = "12px sans-serif";
        const tw = ctx.measureText(text).width + 8;
        const bx = Math.min(X(c.x) + 8, w - pad.r - tw);
        ctx.fillStyle = "rgba(255,255,255,0.92)";
        ctx.fillRect(bx, pad.t + 2, tw, 17);
        ctx.strokeStyle = "#999";
        ctx.strokeRect(bx, pad.t + 2, tw, 17);
        ctx.fillStyle = "#111";
        ctx.textAlign = "left";
        ctx.fillText(text, bx + 4, pad.t + 15);
      }
    }
    ctx.restore();
    plot.ms = performance.now() - t0;
    const d = canvas.dataset;
    d.drawMs = plot.ms.toFixed(1);
    d.xMin = String(xr[0]); d.xMax = String(xr[1]); d.xScale = v.xScale;
    d.yMin = String(yr[0]); d.yMax = String(yr[1]); d.yScale = v.yScale;
    d.zoomed = v.zoomed ? "1" : "";
    legend();
    return plot.ms;
  }

  function colorOf(s, k) { return s.color || COLORS[k % COLORS.length]; }

  /** The value axis' label with its unit: "|H|, (m/s²)/N", "|H|, dB re 1 (m/s²)/N". */
  plot.yLabel = () => {
    const base = opts.yLabel || "";
    if (!opts.yUnit) return base + (opts.db ? " (dB)" : "");
    return opts.db ? `${base}, dB re 1 ${opts.yUnit}` : `${base}, ${opts.yUnit}`;
  };

  /** An HTML legend below the canvas, by channel name, one line per group (kind). */
  function legend() {
    const labelled = opts.series.some((s) => s.label);
    let el = canvas.nextElementSibling;
    if (!(el && el.classList.contains("legend"))) {
      if (!labelled || opts.legend === false) return;
      el = document.createElement("div");
      el.className = "legend";
      canvas.after(el);
    }
    if (!labelled || opts.legend === false) { el.innerHTML = ""; return; }
    // nodes, not markup: the page's style policy allows no inline style attribute
    const groups = new Map();
    opts.series.forEach((s, k) => {
      const g = s.group || "";
      if (!groups.has(g)) groups.set(g, []);
      groups.get(g).push([colorOf(s, k), s.label || `series ${k + 1}`]);
    });
    el.replaceChildren(...[...groups].map(([g, list]) => {
      const row = document.createElement("div");
      if (g) {
        const name = document.createElement("span");
        name.className = "grp";
        name.textContent = `${g} (${list.length}):`;
        row.append(name);
      }
      for (const [color, label] of list) {
        const sw = document.createElement("span");
        sw.className = "sw";
        sw.style.background = color;
        row.append(sw, document.createTextNode(`${label} `));
      }
      return row;
    }));
  }

  /** The readout at pixel (px, py): the nearest line and the series nearest in value. */
  function readout(px, py) {
    const x = opts.x;
    const fx = plot.invX(px);
    let lo = 0; let hi = x.length - 1;
    while (hi - lo > 1) { const m = (lo + hi) >> 1; if (x[m] < fx) lo = m; else hi = m; }
    const i = Math.abs(x[lo] - fx) <= Math.abs(x[hi] - fx) ? lo : hi;
    const fy = plot.invY(py);
    const logY = opts.logY && !opts.db;
    let best = null;
    opts.series.forEach((s, k) => {
      const u = vy(s.y[i]);
      if (!Number.isFinite(u)) return;
      const dist = logY ? Math.abs(Math.log10(Math.max(u, 1e-300)) - Math.log10(Math.max(fy, 1e-300))) : Math.abs(u - fy);
      if (!best || dist < best.dist) best = { dist, k, u };
    });
    const xu = opts.xUnit ? ` ${opts.xUnit}` : "";
    const base = { x: x[i], index: i };
    if (!best) return { ...base, value: NaN, text: `${fmt(x[i])}${xu}`, color: "#333", label: "" };
    const s = opts.series[best.k];
    const label = s.label || `series ${best.k + 1}`;
    const unit = opts.db ? " dB" : opts.yUnit ? ` ${opts.yUnit}` : "";
    return { ...base, value: best.u, series: best.k, label, color: colorOf(s, best.k),
      text: `${fmt(x[i])}${xu}: ${fmt(best.u)}${unit} — ${label}` };
  }

  const local = (ev) => { const r = canvas.getBoundingClientRect(); return [ev.clientX - r.left, ev.clientY - r.top]; };
  const inside = (px, py) => plot.frame && px >= plot.frame.l && px <= plot.frame.r && py >= plot.frame.t && py <= plot.frame.b;

  /** Zoom the frequency axis by ``k`` (< 1: in) about the value ``about``. */
  plot.zoomX = (k, about) => {
    const v = plot.view();
    const t = opts.logX ? Math.log10 : (u) => u;
    const it = opts.logX ? (u) => 10 ** u : (u) => u;
    const c = t(about === undefined ? (opts.logX ? Math.sqrt(v.x[0] * v.x[1]) : (v.x[0] + v.x[1]) / 2) : about);
    const a = it(c + (t(v.x[0]) - c) * k);
    const b = it(c + (t(v.x[1]) - c) * k);
    plot.zoom = { x: [a, b], y: (plot.zoom && plot.zoom.y) || null };
    draw();
  };
  plot.zoomY = (k, about) => {
    const v = plot.view();
    const logY = opts.logY && !opts.db;
    const t = logY ? Math.log10 : (u) => u;
    const it = logY ? (u) => 10 ** u : (u) => u;
    const c = t(about === undefined ? (v.y[0] + v.y[1]) / 2 : about);
    plot.zoom = { x: (plot.zoom && plot.zoom.x) || null, y: [it(c + (t(v.y[0]) - c) * k), it(c + (t(v.y[1]) - c) * k)] };
    draw();
  };
  plot.reset = () => { plot.zoom = null; draw(); };
  /** Switch scales (the zoom is kept on x, the value axis rescaled). */
  plot.setScale = ({ logX, logY, db } = {}) => {
    if (logX !== undefined) opts.logX = logX;
    if (logY !== undefined) opts.logY = logY;
    if (db !== undefined) opts.db = db;
    if (plot.zoom) plot.zoom = { x: plot.zoom.x && opts.logX && !(plot.zoom.x[0] > 0) ? null : plot.zoom.x, y: null };
    draw();
  };

  canvas.addEventListener("wheel", (ev) => {
    const [px, py] = local(ev);
    if (!inside(px, py)) return;
    ev.preventDefault(); // the wheel zooms the plot, not the page
    const k = ev.deltaY > 0 ? 1.25 : 0.8;
    if (ev.shiftKey) plot.zoomY(k, plot.invY(py)); else plot.zoomX(k, plot.invX(px));
  }, { passive: false, signal: plot.abort.signal });
  canvas.addEventListener("dblclick", () => plot.reset(), sig);
  canvas.addEventListener("mousedown", (ev) => {
    const [px, py] = local(ev);
    if (!inside(px, py)) return;
    if (!opts.onBand || ev.shiftKey || ev.button === 1) {
      ev.preventDefault();
      const v = plot.view();
      pan = { px, py, x: v.x, y: v.y };
      return;
    }
    drag = clampX(plot.invX(px));
  }, sig);
  function clampX(u) { return Math.min(Math.max(u, opts.x[0]), opts.x[opts.x.length - 1]); }
  canvas.addEventListener("mousemove", (ev) => {
    const [px, py] = local(ev);
    if (pan) {
      const t = opts.logX ? Math.log10 : (u) => u;
      const it = opts.logX ? (u) => 10 ** u : (u) => u;
      const f = plot.frame;
      const dx = ((px - pan.px) / (f.r - f.l)) * (t(pan.x[1]) - t(pan.x[0]));
      const logY = opts.logY && !opts.db;
      const ty = logY ? Math.log10 : (u) => u;
      const ity = logY ? (u) => 10 ** u : (u) => u;
      const dy = ((py - pan.py) / (f.b - f.t)) * (ty(pan.y[1]) - ty(pan.y[0]));
      plot.zoom = { x: [it(t(pan.x[0]) - dx), it(t(pan.x[1]) - dx)], y: [ity(ty(pan.y[0]) + dy), ity(ty(pan.y[1]) + dy)] };
      draw();
      return;
    }
    if (drag !== null) {
      const u = clampX(plot.invX(px));
      opts.band = [Math.min(drag, u), Math.max(drag, u)];
      draw();
      return;
    }
    plot.cursor = inside(px, py) ? readout(px, py) : null;
    canvas.dataset.cursor = plot.cursor ? plot.cursor.text : "";
    draw();
  }, sig);
  canvas.addEventListener("mouseleave", () => { plot.cursor = null; canvas.dataset.cursor = ""; draw(); }, sig);
  window.addEventListener("mouseup", (ev) => {
    if (pan) { pan = null; return; }
    if (drag === null) return;
    const [px] = local(ev);
    const u = clampX(plot.invX(px));
    const band = [Math.min(drag, u), Math.max(drag, u)];
    drag = null;
    if (band[1] - band[0] > 0) {
      opts.band = band;
      draw();
      opts.onBand(band[0], band[1]);
    }
  }, sig);
  canvas.style.cursor = opts.onBand ? "crosshair" : "grab";
  plot.draw = draw;
  draw();
  return plot;
}
