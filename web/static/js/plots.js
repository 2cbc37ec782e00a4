// plotly.js figures: schedule heatmap, best so far, relevance, slices, trajectories.
import { CHAMBER_NAMES, PLOT_CONFIG, plotlyAvailable } from "./ui.js";

const LAYOUT = { margin: { l: 55, r: 15, t: 30, b: 40 }, font: { size: 12 }, paper_bgcolor: "#fff", plot_bgcolor: "#fff" };

function draw(node, data, layout) {
  if (!plotlyAvailable()) {
    node.textContent = "Plots are unavailable: plotly.js did not load from /vendor/plotly.min.js.";
    return;
  }
  window.Plotly.react(node, data, { ...LAYOUT, ...layout }, PLOT_CONFIG);
}

/** 12 chambers × H steps, kPa. schedule: (H, 12) Pa. */
export function scheduleHeatmap(node, schedule, { title = "", releaseStep = null, lowerPa = null, upperPa = null } = {}) {
  const h = schedule.length;
  const z = CHAMBER_NAMES.map((_, c) => schedule.map((row) => row[c] / 1000));
  const shapes = [];
  if (releaseStep) {
    shapes.push({ type: "line", x0: releaseStep + 0.5, x1: releaseStep + 0.5, y0: -0.5, y1: 11.5, line: { color: "#111", width: 2, dash: "dot" } });
  }
  draw(node, [{
    type: "heatmap", z, x: Array.from({ length: h }, (_, i) => i + 1), y: CHAMBER_NAMES,
    colorscale: "Viridis", zmin: lowerPa !== null ? lowerPa / 1000 : undefined, zmax: upperPa !== null ? upperPa / 1000 : undefined,
    colorbar: { title: { text: "kPa" } },
    hovertemplate: "step %{x}, chamber %{y}: %{z:.1f} kPa<extra></extra>",
  }], {
    title: { text: title, font: { size: 13 } },
    xaxis: { title: { text: `control step (each ${(5 / h).toFixed(2)} s)${releaseStep ? `; dotted: release after step ${releaseStep}` : ""}` }, dtick: 1 },
    yaxis: { autorange: "reversed" },
    shapes,
  });
}

/** Each completed trial's objective ± SEM and the running best. */
export function bestSoFar(node, trials) {
  const done = trials.filter((t) => t.status === "completed" && t.objective !== null && t.objective !== undefined)
    .sort((a, b) => a.index - b.index);
  let best = -Infinity;
  const bestY = done.map((t) => (best = Math.max(best, t.objective)));
  draw(node, [
    { type: "scatter", mode: "markers", name: "trial (± SEM)", x: done.map((t) => t.index), y: done.map((t) => t.objective),
      error_y: { type: "data", array: done.map((t) => t.objective_sem ?? 0), visible: true },
      text: done.map((t) => `trial ${t.index}`), marker: { size: 8, color: "#1f5eea" } },
    { type: "scatter", mode: "lines", name: "best so far", x: done.map((t) => t.index), y: bestY, line: { shape: "hv", color: "#d9480f", width: 2 } },
  ], {
    xaxis: { title: { text: "trial" } }, yaxis: { title: { text: "objective" } },
    legend: { orientation: "h", y: 1.12 },
    annotations: done.length ? [] : [{ text: "no completed trial yet", showarrow: false, xref: "paper", yref: "paper", x: 0.5, y: 0.5 }],
  });
  return done.length;
}

export function relevance(node, lengthscales) {
  const rel = lengthscales.map((l) => 1 / l);
  draw(node, [{ type: "bar", x: rel.map((_, i) => `θ${i}`), y: rel, marker: { color: "#1f5eea" },
    hovertemplate: "%{x}: relevance %{y:.3g}<extra></extra>" }],
  { title: { text: "relevance (1 / lengthscale)", font: { size: 13 } }, yaxis: { title: { text: "1 / ℓ" } } });
}

/** slices: [{dim, theta, mean, std}] posterior slices through the incumbent; the three most
 * relevant dimensions (shortest lengthscales) are shown, the others one click away. */
export function slices(node, sl, incumbent, lengthscales = null) {
  const data = [];
  const order = lengthscales ? lengthscales.map((l, i) => [l, i]).sort((a, b) => a[0] - b[0]).map((p) => p[1]) : [];
  const shown = new Set(order.slice(0, 3));
  sl.forEach((s) => {
    const { theta: x, mean, std, dim } = s; // SliceRead
    const visible = !lengthscales || shown.has(dim) ? true : "legendonly";
    data.push({ type: "scatter", mode: "lines", name: `θ${dim}`, x, y: mean, legendgroup: `d${dim}`, visible,
      hovertemplate: `θ${dim}=%{x:.3f}: mean %{y:.3g}<extra></extra>` });
    data.push({ type: "scatter", mode: "lines", visible, x: [...x, ...x.slice().reverse()],
      y: [...mean.map((m, j) => m + 2 * std[j]), ...mean.map((m, j) => m - 2 * std[j]).reverse()],
      fill: "toself", opacity: 0.12, line: { width: 0 }, showlegend: false, legendgroup: `d${dim}`, hoverinfo: "skip" });
  });
  draw(node, data, { title: { text: "posterior mean ± 2 std along θ, through the best trial (click the legend for more)", font: { size: 12 } },
    xaxis: { title: { text: "θ value" }, range: [0, 1] }, yaxis: { title: { text: "predicted objective" } },
    legend: { font: { size: 10 } }, shapes: [] , meta: incumbent });
}

export function line(node, x, y, { title, ytitle }) {
  draw(node, [{ type: "scatter", mode: "lines", x, y, line: { color: "#1f5eea" } }],
    { title: { text: title, font: { size: 13 } }, xaxis: { title: { text: "time (s)" } }, yaxis: { title: { text: ytitle } } });
}

/** The drift check (DriftRead): each scored reference's objective ± SEM by trial number, the
 * band drawn from the first m (shaded, centre dashed), points beyond it in red, references of
 * an earlier reference θ in grey. */
export function driftChart(node, drift) {
  const pts = drift.points || [];
  const earlier = drift.earlier || [];
  const unit = drift.objective_unit || "";
  const colour = (p) => (p.outside ? "#c92a2a" : p.baseline ? "#748ffc" : "#1f5eea");
  const data = [];
  if (earlier.length) {
    data.push({ type: "scatter", mode: "markers", name: "earlier reference θ", x: earlier.map((p) => p.index), y: earlier.map((p) => p.objective),
      marker: { size: 7, color: "#adb5bd", symbol: "circle-open" }, hovertemplate: `trial %{x}: %{y:.4g} ${unit}<extra>earlier θ</extra>` });
  }
  data.push({ type: "scatter", mode: "lines+markers", name: "reference (± SEM)", x: pts.map((p) => p.index), y: pts.map((p) => p.objective),
    error_y: { type: "data", array: pts.map((p) => p.objective_sem ?? 0), visible: true },
    text: pts.map((p) => `${p.baseline ? "baseline" : p.outside ? "beyond the band" : "in band"}${p.finished_at ? `, ${new Date(p.finished_at).toLocaleString()}` : ""}`),
    marker: { size: 9, color: pts.map(colour) }, line: { color: "#1f5eea", width: 1 },
    hovertemplate: `trial %{x}: %{y:.4g} ${unit} (%{text})<extra></extra>` });
  const shapes = [];
  const b = drift.band;
  if (b) {
    shapes.push({ type: "rect", xref: "paper", x0: 0, x1: 1, y0: b.low, y1: b.high, fillcolor: "#1f5eea", opacity: 0.1, line: { width: 0 }, layer: "below" });
    shapes.push({ type: "line", xref: "paper", x0: 0, x1: 1, y0: b.center, y1: b.center, line: { color: "#1f5eea", width: 1, dash: "dash" } });
  }
  const ys = [...pts, ...earlier].flatMap((p) => [p.objective - (p.objective_sem ?? 0), p.objective + (p.objective_sem ?? 0)]);
  if (b) ys.push(b.low, b.high);
  const pad = ys.length ? Math.max((Math.max(...ys) - Math.min(...ys)) * 0.12, 1e-6) : 0;
  draw(node, data, {
    title: { text: b ? `band ${b.center.toPrecision(4)} ± ${b.half_width.toPrecision(3)} ${unit}: ${b.rule}` : "the band forms once the first references are scored", font: { size: 12 } },
    xaxis: { title: { text: "trial number (the robot's use)" }, dtick: pts.length + earlier.length < 15 ? 1 : undefined },
    yaxis: { title: { text: `objective (${unit})` }, range: ys.length ? [Math.min(...ys) - pad, Math.max(...ys) + pad] : undefined },
    showlegend: earlier.length > 0, legend: { orientation: "h", y: 1.15 }, shapes,
    annotations: pts.length || earlier.length ? [] : [{ text: "no reference scored yet", showarrow: false, xref: "paper", yref: "paper", x: 0.5, y: 0.5 }],
  });
  return pts.length;
}

/** Hardware vs sim twin per trial (TwinComparisonRead rows): the robot's objective ± SEM and
 * the twin's prediction (of what ran, else of the plan) above, their discrepancy below. */
export function hardwareVsTwin(node, rows, unit = "") {
  const sorted = rows.slice().sort((a, b) => a.index - b.index);
  const hw = sorted.filter((r) => r.objective !== null && r.objective !== undefined);
  const twin = sorted.filter((r) => r.twin && r.twin.status === "done" && r.twin.predicted_objective !== null);
  const gap = sorted.filter((r) => r.discrepancy !== null && r.discrepancy !== undefined);
  draw(node, [
    { type: "scatter", mode: "markers", name: "hardware (± SEM)", x: hw.map((r) => r.index), y: hw.map((r) => r.objective),
      error_y: { type: "data", array: hw.map((r) => r.objective_sem ?? 0), visible: true }, marker: { size: 9, color: "#1f5eea" },
      hovertemplate: `trial %{x}: hardware %{y:.4g} ${unit}<extra></extra>` },
    { type: "scatter", mode: "markers", name: "sim twin", x: twin.map((r) => r.index), y: twin.map((r) => r.twin.predicted_objective),
      marker: { size: 9, symbol: "diamond-open", color: "#d9480f", line: { width: 2 } },
      hovertemplate: `trial %{x}: twin %{y:.4g} ${unit}<extra></extra>` },
    { type: "bar", name: "hardware − twin", x: gap.map((r) => r.index), y: gap.map((r) => r.discrepancy), yaxis: "y2", width: 0.6,
      marker: { color: gap.map((r) => (r.discrepancy >= 0 ? "#2b8a3e" : "#c92a2a")) },
      hovertemplate: `trial %{x}: hardware − twin %{y:.3g} ${unit}<extra></extra>` },
  ], {
    xaxis: { title: { text: "trial" }, anchor: "y2", tickformat: "d" },
    yaxis: { title: { text: `objective${unit ? ` (${unit})` : ""}` }, domain: [0.4, 1] },
    yaxis2: { title: { text: "hardware − twin" }, domain: [0, 0.28], zeroline: true },
    legend: { orientation: "h", y: 1.14 },
    annotations: sorted.length ? [] : [{ text: "no hardware trial yet", showarrow: false, xref: "paper", yref: "paper", x: 0.5, y: 0.7 }],
  });
  return gap.length;
}
