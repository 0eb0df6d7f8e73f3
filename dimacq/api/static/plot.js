// Small canvas line plots: many series × many points, log or linear y, a band picked by dragging.
// Canvas rather than SVG: 30 series × 2048 lines are 60 000 vertices, one path per series.

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

function fmt(v) {
  const a = Math.abs(v);
  if (a !== 0 && (a < 1e-2 || a >= 1e4)) return v.toExponential(0);
  return String(+v.toPrecision(3));
}

/**
 * Draw series on a canvas.
 * opts: {x: Float64Array, series: [{y: Float64Array, label}], logY, yLabel, xLabel, yRange,
 *        band: [lo, hi] | null, onBand(lo, hi), title}
 * Returns {draw(), ms} where ms is the draw time of the last draw in milliseconds.
 */
export function linePlot(canvas, opts) {
  const plot = { opts, ms: 0 };
  const pad = { l: 62, r: 12, t: 22, b: 36 };
  const ctx = canvas.getContext("2d");
  let drag = null;

  function ranges() {
    const x = opts.x;
    const xr = [x[0], x[x.length - 1]];
    let yr = opts.yRange;
    if (!yr) {
      let lo = Infinity;
      let hi = -Infinity;
      for (const s of opts.series) {
        for (let i = 0; i < s.y.length; i++) {
          const v = s.y[i];
          if (opts.logY && !(v > 0)) continue;
          if (v < lo) lo = v;
          if (v > hi) hi = v;
        }
      }
      if (!isFinite(lo)) { lo = opts.logY ? 1e-6 : 0; hi = 1; }
      if (opts.logY) { lo = Math.max(lo, hi * 1e-8); }
      yr = [lo, hi];
    }
    return { xr, yr };
  }

  function draw() {
    const t0 = performance.now();
    const dpr = window.devicePixelRatio || 1;
    const w = canvas.clientWidth || 600;
    const h = canvas.clientHeight || 260;
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    const { xr, yr } = ranges();
    const ty = opts.logY ? Math.log10 : (v) => v;
    const y0 = ty(yr[0]);
    const y1 = ty(yr[1]);
    const sx = (w - pad.l - pad.r) / (xr[1] - xr[0] || 1);
    const sy = (h - pad.t - pad.b) / (y1 - y0 || 1);
    const X = (v) => pad.l + (v - xr[0]) * sx;
    const Y = (v) => h - pad.b - (ty(v) - y0) * sy;
    plot.X = X;
    plot.invX = (px) => xr[0] + (px - pad.l) / sx;
    // band
    if (opts.band) {
      ctx.fillStyle = "rgba(255, 200, 0, 0.25)";
      ctx.fillRect(X(opts.band[0]), pad.t, X(opts.band[1]) - X(opts.band[0]), h - pad.t - pad.b);
    }
    // axes and ticks
    ctx.strokeStyle = "#999";
    ctx.fillStyle = "#333";
    ctx.font = "11px sans-serif";
    ctx.lineWidth = 1;
    ctx.strokeRect(pad.l, pad.t, w - pad.l - pad.r, h - pad.t - pad.b);
    ctx.textAlign = "center";
    for (const v of niceTicks(xr[0], xr[1], 8)) ctx.fillText(fmt(v), X(v), h - pad.b + 14);
    ctx.textAlign = "right";
    if (opts.logY) {
      for (let e = Math.ceil(y0); e <= y1; e++) ctx.fillText(`1e${e}`, pad.l - 4, Y(10 ** e) + 4);
    } else {
      for (const v of niceTicks(yr[0], yr[1], 5)) ctx.fillText(fmt(v), pad.l - 4, Y(v) + 4);
    }
    ctx.textAlign = "center";
    if (opts.xLabel) ctx.fillText(opts.xLabel, pad.l + (w - pad.l - pad.r) / 2, h - 6);
    if (opts.title) ctx.fillText(opts.title, pad.l + (w - pad.l - pad.r) / 2, 14);
    if (opts.yLabel) {
      ctx.save();
      ctx.translate(12, pad.t + (h - pad.t - pad.b) / 2);
      ctx.rotate(-Math.PI / 2);
      ctx.fillText(opts.yLabel, 0, 0);
      ctx.restore();
    }
    // series (clipped to the frame)
    ctx.save();
    ctx.beginPath();
    ctx.rect(pad.l, pad.t, w - pad.l - pad.r, h - pad.t - pad.b);
    ctx.clip();
    const x = opts.x;
    const floor = opts.logY ? yr[0] * 1e-3 : -Infinity;
    opts.series.forEach((s, k) => {
      ctx.strokeStyle = s.color || COLORS[k % COLORS.length];
      ctx.beginPath();
      for (let i = 0; i < x.length; i++) {
        const v = Math.max(s.y[i], floor);
        if (i === 0) ctx.moveTo(X(x[i]), Y(v));
        else ctx.lineTo(X(x[i]), Y(v));
      }
      ctx.stroke();
    });
    ctx.restore();
    plot.ms = performance.now() - t0;
    canvas.dataset.drawMs = plot.ms.toFixed(1);
    return plot.ms;
  }

  if (opts.onBand) {
    canvas.style.cursor = "crosshair";
    const fx = (ev) => {
      const r = canvas.getBoundingClientRect();
      const v = plot.invX(ev.clientX - r.left);
      return Math.min(Math.max(v, opts.x[0]), opts.x[opts.x.length - 1]);
    };
    canvas.addEventListener("mousedown", (ev) => { drag = fx(ev); });
    canvas.addEventListener("mousemove", (ev) => {
      if (drag === null) return;
      const v = fx(ev);
      opts.band = [Math.min(drag, v), Math.max(drag, v)];
      draw();
    });
    window.addEventListener("mouseup", (ev) => {
      if (drag === null) return;
      const v = fx(ev);
      const band = [Math.min(drag, v), Math.max(drag, v)];
      drag = null;
      if (band[1] - band[0] > 0) {
        opts.band = band;
        draw();
        opts.onBand(band[0], band[1]);
      }
    });
  }
  plot.draw = draw;
  draw();
  return plot;
}
