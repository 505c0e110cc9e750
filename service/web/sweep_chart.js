// A sweep's chart in inline SVG (no library): x the swept value, y the quality in dB in one panel and the time in
// seconds in the other. Predicted quality and estimated time are hollow points on a dashed line; measured quality
// (where a job was evaluated) and actual time are filled points on a solid line. Numeric values lie on a linear
// axis, others (encoder, preset) one step apart in the sweep's order.

const NS = "http://www.w3.org/2000/svg";
const W = 420, H = 260, PAD = { l: 56, r: 14, t: 26, b: 46 };

function svg(tag, attrs = {}, text = null) {
  const n = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) if (v !== null && v !== undefined) n.setAttribute(k, String(v));
  if (text !== null) n.textContent = String(text);
  return n;
}

// Round tick values over [lo, hi] (about five).
function ticks(lo, hi) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / 5;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(+v.toFixed(10));
  return out;
}

const fmt = (v) => (Math.abs(v) >= 100 || Number.isInteger(v) ? String(Math.round(v)) : v.toFixed(1));

// The x positions of the values: linear when every value is a number, else evenly spaced.
function xScale(values) {
  const numeric = values.every((v) => typeof v === "number" && isFinite(v));
  const x0 = PAD.l + 12, x1 = W - PAD.r - 12;
  if (!numeric || values.length < 2) {
    const step = values.length > 1 ? (x1 - x0) / (values.length - 1) : 0;
    return { at: (v) => x0 + step * values.indexOf(v), ticks: values };
  }
  const lo = Math.min(...values), hi = Math.max(...values);
  return { at: (v) => (hi > lo ? x0 + (x1 - x0) * (v - lo) / (hi - lo) : (x0 + x1) / 2), ticks: values };
}

function yScale(numbers) {
  let lo = Math.min(...numbers), hi = Math.max(...numbers);
  if (!numbers.length) { lo = 0; hi = 1; }
  if (hi - lo < 1e-9) { lo -= 1; hi += 1; }
  const pad = (hi - lo) * 0.1;
  lo -= pad; hi += pad;
  const y0 = H - PAD.b, y1 = PAD.t;
  return { at: (v) => y0 + (y1 - y0) * (v - lo) / (hi - lo), ticks: ticks(lo, hi) };
}

// One panel: series = [{name, points: [{value, y}], filled, dashed}], the axes' labels.
function panel(id, title, xLabel, yLabel, values, series) {
  const root = svg("svg", { id, viewBox: `0 0 ${W} ${H}`, class: "sweep-panel", role: "img", "aria-label": title });
  const x = xScale(values);
  const y = yScale(series.flatMap((s) => s.points.map((p) => p.y)));
  root.append(svg("line", { x1: PAD.l, y1: H - PAD.b, x2: W - PAD.r, y2: H - PAD.b, class: "axis" }));
  root.append(svg("line", { x1: PAD.l, y1: PAD.t, x2: PAD.l, y2: H - PAD.b, class: "axis" }));
  for (const v of x.ticks) {
    const px = x.at(v);
    root.append(svg("line", { x1: px, y1: H - PAD.b, x2: px, y2: H - PAD.b + 4, class: "axis" }));
    root.append(svg("text", { x: px, y: H - PAD.b + 16, "text-anchor": "middle", class: "tick" }, String(v)));
  }
  for (const v of y.ticks) {
    const py = y.at(v);
    root.append(svg("line", { x1: PAD.l, y1: py, x2: W - PAD.r, y2: py, class: "grid" }));
    root.append(svg("text", { x: PAD.l - 6, y: py + 4, "text-anchor": "end", class: "tick" }, fmt(v)));
  }
  root.append(svg("text", { x: (PAD.l + W - PAD.r) / 2, y: H - 8, "text-anchor": "middle", class: "axis-label" },
                  xLabel));
  root.append(svg("text", { x: 14, y: (PAD.t + H - PAD.b) / 2, "text-anchor": "middle", class: "axis-label",
                            transform: `rotate(-90 14 ${(PAD.t + H - PAD.b) / 2})` }, yLabel));
  for (const s of series) {
    const pts = s.points.map((p) => ({ ...p, px: x.at(p.value), py: y.at(p.y) }));
    if (pts.length > 1) {
      root.append(svg("polyline", { points: pts.map((p) => `${p.px.toFixed(1)},${p.py.toFixed(1)}`).join(" "),
                                    class: `line ${s.cls}${s.dashed ? " dashed" : ""}` }));
    }
    for (const p of pts) {
      const dot = svg("circle", { cx: p.px.toFixed(1), cy: p.py.toFixed(1), r: 4.5, class: `dot ${s.cls}`,
                                  "data-series": s.name, "data-value": JSON.stringify(p.value),
                                  fill: s.filled ? "currentColor" : "#fff" });
      dot.append(svg("title", {}, `${s.label} at ${xLabel.split(",")[0]} ${p.value}: ${fmt(p.y)}`));
      root.append(dot);
    }
  }
  let lx = PAD.l + 8;
  for (const s of series) {  // the legend, along the top
    const g = svg("g", { class: `legend ${s.cls}` });
    g.append(svg("circle", { cx: lx, cy: 12, r: 4, fill: s.filled ? "currentColor" : "#fff", class: "dot" }));
    g.append(svg("text", { x: lx + 8, y: 16, class: "tick" }, s.label));
    root.append(g);
    lx += 110;
  }
  return root;
}

const UNITS = { frames: "count", spp: "rays per pixel", iterations: "encoder iterations", max_spp: "rays per pixel",
                render_time_limit_s: "s", quality_db: "dB target", wrp_planes: "recording planes" };

// The chart of a sweep (GET /v1/sweeps/{id}): two panels in a container.
export function sweepChart(sweep) {
  const values = sweep.jobs.map((j) => j.value);
  const xLabel = UNITS[sweep.option] ? `${sweep.option}, ${UNITS[sweep.option]}` : sweep.option;
  const pick = (key) => sweep.jobs.filter((j) => typeof j[key] === "number")
    .map((j) => ({ value: j.value, y: j[key] }));
  const quality = panel("sweep-quality", "Quality (viewer-faithful PSNR)", xLabel, "quality, dB", values, [
    { name: "predicted", label: "predicted", cls: "predicted", points: pick("predicted_psnr_db"), dashed: true },
    { name: "measured", label: "measured", cls: "measured", points: pick("measured_psnr_db"), filled: true }]);
  const time = panel("sweep-time", "Time", xLabel, "time, s", values, [
    { name: "estimated", label: "estimated", cls: "predicted", points: pick("estimate_s"), dashed: true },
    { name: "actual", label: "actual", cls: "measured", points: pick("run_s"), filled: true }]);
  const box = document.createElement("div");
  box.className = "sweep-chart";
  for (const [chart, caption] of [[quality, "Quality: the predicted viewer-faithful PSNR; measured where evaluated"],
                                  [time, "Time: estimated and actual run time"]]) {
    const fig = document.createElement("figure");
    const cap = document.createElement("figcaption");
    cap.textContent = caption;
    fig.append(chart, cap);
    box.append(fig);
  }
  return box;
}
