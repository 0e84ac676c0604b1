"use strict";
// The comparison page: images side by side, flipped or wiped, with one
// zoom and pan for all; exposure; error maps; the speed plot; the tables.
// Everything it shows comes from the JSON block of the page.

const data = JSON.parse(document.getElementById("data").textContent);
const [imageHeight, imageWidth] = data.results.reference.size;
const SVG = "http://www.w3.org/2000/svg";
const ZOOM_STEP = 0.0015;   // zoom factor per pixel of wheel movement, in the exponent
const MAX_SCALE = 256;      // screen pixels per image pixel, at most
const PATH_COLOURS = ["#1f77b4", "#17becf", "#9467bd"];
const WHITTED_COLOURS = ["#d62728", "#ff7f0e", "#2ca02c", "#8c564b", "#e377c2", "#bcbd22",
                         "#7f7f7f", "#aec7e8", "#ff9896", "#98df8a", "#c5b0d5"];

const state = {
  mode: "side",
  first: Math.min(1, data.images.length - 1),  // the first Whitted setting
  second: 0,                                   // the reference
  layer: "image",
  exposure: 0,
  wipe: 50,
  view: null,                                  // {scale, x, y} in screen pixels
  plotMetric: data.results.metrics[0],
};

const byId = (id) => document.getElementById(id);

// ------------------------------------------------------------- helpers

function element(tag, className, parent) {
  const made = document.createElement(tag);
  if (className) made.className = className;
  if (parent) parent.appendChild(made);
  return made;
}

function svgElement(tag, attributes, parent) {
  const made = document.createElementNS(SVG, tag);
  for (const [name, value] of Object.entries(attributes)) made.setAttribute(name, value);
  parent.appendChild(made);
  return made;
}

// Text with the report's Markdown spans: `code` and *emphasis*.
function setText(target, text) {
  for (const part of String(text).split(/(`[^`]*`|\*[^*]+\*)/)) {
    if (/^`.*`$/.test(part)) element("code", "", target).textContent = part.slice(1, -1);
    else if (/^\*.*\*$/.test(part)) element("em", "", target).textContent = part.slice(1, -1);
    else target.appendChild(document.createTextNode(part));
  }
}

function formatNumber(value, digits = 2) {
  if (value === null) return "∞";
  return Number(value.toPrecision(digits)).toString();
}

// An Estimate of results.json as "median (low-high)", as in the tables.
function estimateText(estimate, unit = "") {
  const prefix = { "=": "", "<": "< ", ">": "> " }[estimate.relation];
  return `${prefix}${formatNumber(estimate.median)}${unit} ` +
         `(${formatNumber(estimate.low)}-${formatNumber(estimate.high)})`;
}

function fillSelect(select, options, selected) {
  select.replaceChildren();
  for (const [value, text] of options) {
    const option = element("option", "", select);
    option.value = value;
    option.textContent = text;
  }
  select.value = selected;
}

// ------------------------------------------------------------- viewer

function shownImages() {
  if (state.mode === "side") return [[state.first], [state.second]];
  if (state.mode === "wipe") return [[state.first, state.second]];
  return [[state.first]];
}

// The file a pane shows for an image: the image, or its error map.
function sourceOf(index) {
  const item = data.images[index];
  const map = state.layer !== "image" && item.maps[state.layer];
  return { src: map || item.src, isMap: Boolean(map) };
}

function captionOf(index) {
  const item = data.images[index];
  if (state.layer === "image") return `${index + 1}: ${item.label}`;
  const metric = data.metricNames[state.layer];
  return item.maps[state.layer] ? `${index + 1}: ${item.label}, ${metric}`
                                : `${index + 1}: ${item.label} (no ${metric} map)`;
}

function buildStage() {
  const stage = byId("stage");
  stage.replaceChildren();
  for (const indices of shownImages()) {
    const pane = element("div", "pane", stage);
    indices.forEach((index, depth) => {
      const layer = element("div", "layer", pane);
      const { src, isMap } = sourceOf(index);
      const img = element("img", "", layer);
      img.src = src;
      img.alt = data.images[index].label;
      img.draggable = false;
      layer.dataset.map = isMap ? "yes" : "no";
      if (depth === 1) layer.classList.add("top");
      const caption = element("span", depth === 1 ? "caption right" : "caption", pane);
      caption.textContent = captionOf(index);
    });
    if (indices.length === 2) element("div", "wipe-line", pane);
    listenForZoomAndPan(pane);
  }
  byId("second-label").hidden = state.mode === "flip";
  byId("wipe").hidden = state.mode !== "wipe";
  if (!state.view) state.view = fittedView();
  applyView();
  applyExposure();
  applyWipe();
  updateColourBar();
}

function paneSize() {
  const pane = document.querySelector(".pane");
  return [pane.clientWidth, pane.clientHeight];
}

function fittedView() {
  const [width, height] = paneSize();
  const scale = Math.min(width / imageWidth, height / imageHeight);
  return { scale, x: (width - imageWidth * scale) / 2, y: (height - imageHeight * scale) / 2 };
}

function applyView() {
  const { scale, x, y } = state.view;
  for (const img of document.querySelectorAll(".layer img")) {
    img.style.left = `${x}px`;
    img.style.top = `${y}px`;
    img.style.width = `${imageWidth * scale}px`;
    img.style.height = `${imageHeight * scale}px`;
  }
  byId("zoom").textContent = `zoom ${formatNumber(scale, 3)}x`;
}

// Zoom by `factor` about the pane point (px, py), which stays in place.
function zoomAt(px, py, factor) {
  const view = state.view;
  const scale = Math.min(Math.max(view.scale * factor, fittedView().scale / 4), MAX_SCALE);
  const ratio = scale / view.scale;
  state.view = { scale, x: px - (px - view.x) * ratio, y: py - (py - view.y) * ratio };
  applyView();
}

function listenForZoomAndPan(pane) {
  pane.addEventListener("wheel", (event) => {
    event.preventDefault();
    const box = pane.getBoundingClientRect();
    zoomAt(event.clientX - box.left, event.clientY - box.top, Math.exp(-event.deltaY * ZOOM_STEP));
  }, { passive: false });
  pane.addEventListener("pointerdown", (event) => {
    pane.setPointerCapture(event.pointerId);
    pane.classList.add("dragging");
    let last = [event.clientX, event.clientY];
    const move = (moved) => {
      state.view.x += moved.clientX - last[0];
      state.view.y += moved.clientY - last[1];
      last = [moved.clientX, moved.clientY];
      applyView();
    };
    const stop = () => {
      pane.classList.remove("dragging");
      pane.removeEventListener("pointermove", move);
      pane.removeEventListener("pointerup", stop);
    };
    pane.addEventListener("pointermove", move);
    pane.addEventListener("pointerup", stop);
  });
}

function srgbToLinear(value) {
  return value <= 0.04045 ? value / 12.92 : ((value + 0.055) / 1.055) ** 2.4;
}

function linearToSrgb(value) {
  const v = Math.min(Math.max(value, 0), 1);
  return v <= 0.0031308 ? 12.92 * v : 1.055 * v ** (1 / 2.4) - 0.055;
}

// Exposure in linear light, on images only (an error map keeps its
// colours): each of the 256 sRGB levels of a channel decoded, scaled by
// 2^stops and encoded again, as the filter's lookup table.
function applyExposure() {
  const gain = 2 ** state.exposure;
  const table = Array.from({ length: 256 },
    (_, level) => linearToSrgb(gain * srgbToLinear(level / 255)).toFixed(5)).join(" ");
  for (const func of document.querySelectorAll("#exposure-filter feComponentTransfer > *")) {
    func.setAttribute("tableValues", table);
  }
  for (const layer of document.querySelectorAll(".layer")) {
    const exposed = state.exposure !== 0 && layer.dataset.map === "no";
    layer.style.filter = exposed ? "url(#exposure-filter)" : "";
  }
  byId("exposure-value").textContent = `${state.exposure.toFixed(1)} stops`;
}

// In wipe: the left image left of the slider, the right image right of it.
function applyWipe() {
  const top = document.querySelector(".layer.top");
  if (!top) return;
  top.style.clipPath = `inset(0 0 0 ${state.wipe}%)`;
  document.querySelector(".wipe-line").style.left = `${state.wipe}%`;
}

function updateColourBar() {
  const scale = data.scales[state.layer];
  const bar = byId("colour-bar");
  bar.hidden = !scale;
  if (!scale) return;
  bar.querySelector(".bar").style.background =
    `linear-gradient(to right, ${scale.colours.join(", ")})`;
  bar.querySelector(".bar-max").textContent = `${formatNumber(scale.max, 3)} and above`;
  bar.querySelector(".bar-label").textContent = scale.label;
}

function setUpViewer() {
  const names = data.images.map((item, index) => [index, `${index + 1}: ${item.label}`]);
  fillSelect(byId("first"), names, state.first);
  fillSelect(byId("second"), names, state.second);
  const layers = [["image", "image"]].concat(
    Object.keys(data.scales).map((metric) => [metric, `${data.metricNames[metric]} map`]));
  fillSelect(byId("layer"), layers, state.layer);
  if (!data.scales.flip) {
    byId("note").textContent = "FLIP is not available here (the flip-evaluator package is " +
                               "not installed): only relMSE maps are shown.";
  }
  const rebuild = (key, read) => (event) => { state[key] = read(event.target.value); buildStage(); };
  byId("mode").addEventListener("change", (event) => {
    state.mode = event.target.value;
    state.view = null;  // the panes change size
    buildStage();
  });
  byId("first").addEventListener("change", rebuild("first", Number));
  byId("second").addEventListener("change", rebuild("second", Number));
  byId("layer").addEventListener("change", rebuild("layer", String));
  byId("exposure").addEventListener("input", (event) => {
    state.exposure = Number(event.target.value);
    applyExposure();
  });
  byId("wipe").addEventListener("input", (event) => {
    state.wipe = Number(event.target.value);
    applyWipe();
  });
  byId("reset").addEventListener("click", resetView);
  document.addEventListener("keydown", onKey);
  window.addEventListener("resize", resetView);
  buildStage();
}

function resetView() {
  state.view = fittedView();
  applyView();
}

function showFirst(index) {
  state.first = index;
  byId("first").value = index;
  buildStage();
}

function onKey(event) {
  if (event.target.tagName === "SELECT" || event.target.tagName === "INPUT") return;
  if (event.key === "0") resetView();
  const index = Number(event.key) - 1;
  if (index >= 0 && index < Math.min(9, data.images.length)) showFirst(index);
}

// ------------------------------------------------------------- speed plot

const PLOT = { left: 62, right: 540, top: 16, bottom: 370, legendX: 556 };

function imageIndex(key) {
  return data.images.findIndex((item) => item.key === key);
}

function errorOf(figures, metric) {
  return metric === "relmse" ? figures.rel_mse : figures.flip;
}

// The plot's series: path's curves, then each Whitted setting's two points.
function plotSeries(metric) {
  const results = data.results;
  const series = Object.entries(results.path).map(([sampler, rungs], index) => ({
    colour: PATH_COLOURS[index % PATH_COLOURS.length],
    label: `path, ${sampler}`,
    points: rungs.map((rung) => ({ figures: rung, error: errorOf(rung, metric), filled: true,
                                   label: `path, ${sampler}, ${rung.spp} spp` })),
  }));
  Object.entries(results.whitted).forEach(([label, entry], index) => {
    const point = { figures: entry, label: `whitted: ${label}` };
    series.push({
      colour: WHITTED_COLOURS[index % WHITTED_COLOURS.length],
      label: `whitted: ${label}`,
      points: [{ ...point, error: errorOf(entry, metric), filled: true },
               { ...point, error: entry.sampling_error[metric], filled: false,
                 label: `${point.label} (sampling error)` }],
    });
  });
  for (const each of series) each.points = each.points.filter((p) => p.error > 0);
  return series;
}

function logRange(values) {
  const logs = values.map(Math.log10);
  const low = Math.min(...logs), high = Math.max(...logs);
  const pad = Math.max(0.1, 0.05 * (high - low));
  return [low - pad, high + pad];
}

function drawPlot() {
  const svg = byId("plot");
  svg.replaceChildren();
  const metric = state.plotMetric;
  const series = plotSeries(metric);
  const points = series.flatMap((each) => each.points);
  const floor = metric === "relmse" ? data.results.reference.noise_rel_mse : null;
  const xs = logRange(points.map((p) => p.figures.seconds.median));
  const ys = logRange(points.map((p) => p.error).concat(floor ? [floor] : []));
  const toX = (v) => PLOT.left + (Math.log10(v) - xs[0]) / (xs[1] - xs[0]) * (PLOT.right - PLOT.left);
  const toY = (v) => PLOT.bottom - (Math.log10(v) - ys[0]) / (ys[1] - ys[0]) * (PLOT.bottom - PLOT.top);
  drawAxes(svg, xs, ys, toX, toY, metric);
  if (floor) {
    svgElement("line", { x1: PLOT.left, x2: PLOT.right, y1: toY(floor), y2: toY(floor),
                         stroke: "#888", "stroke-dasharray": "4 3" }, svg);
    svgElement("text", { x: PLOT.right - 4, y: toY(floor) - 4, "text-anchor": "end" }, svg)
      .textContent = "reference's own noise";
  }
  series.forEach((each, index) => {
    if (each.points.length > 1) {
      svgElement("polyline", {
        points: each.points.map((p) => `${toX(p.figures.seconds.median)},${toY(p.error)}`).join(" "),
        fill: "none", stroke: each.colour, "stroke-width": 1.5, opacity: 0.7 }, svg);
    }
    for (const point of each.points) {
      const dot = svgElement("circle", {
        cx: toX(point.figures.seconds.median), cy: toY(point.error), r: 5, class: "point",
        fill: point.filled ? each.colour : "#fff", stroke: each.colour, "stroke-width": 1.5 }, svg);
      dot.addEventListener("mouseenter", () => showTip(point, dot));
      dot.addEventListener("mouseleave", () => { byId("tip").hidden = true; });
      dot.addEventListener("click", () => {
        const found = imageIndex(point.figures.image);
        if (found >= 0) showFirst(found);
      });
    }
    drawLegendEntry(svg, each, index);
  });
}

// Powers of ten in a log range; 2 and 5 times them too where it spans
// less than two decades, so that every axis has a few labels.
function tickValues(range) {
  const steps = range[1] - range[0] < 2 ? [1, 2, 5] : [1];
  const values = [];
  for (let power = Math.floor(range[0]); power <= Math.ceil(range[1]); power++) {
    for (const step of steps) values.push(step * 10 ** power);
  }
  return values.filter((v) => Math.log10(v) >= range[0] && Math.log10(v) <= range[1]);
}

function drawAxes(svg, xs, ys, toX, toY, metric) {
  for (const [range, horizontal] of [[xs, true], [ys, false]]) {
    for (const value of tickValues(range)) {
      const at = horizontal ? toX(value) : toY(value);
      const line = horizontal ? { x1: at, x2: at, y1: PLOT.top, y2: PLOT.bottom }
                              : { x1: PLOT.left, x2: PLOT.right, y1: at, y2: at };
      svgElement("line", { ...line, class: "grid" }, svg);
      const label = horizontal ? { x: at, y: PLOT.bottom + 16, "text-anchor": "middle" }
                               : { x: PLOT.left - 6, y: at + 4, "text-anchor": "end" };
      svgElement("text", label, svg).textContent = formatNumber(value);
    }
  }
  svgElement("rect", { x: PLOT.left, y: PLOT.top, width: PLOT.right - PLOT.left,
                       height: PLOT.bottom - PLOT.top, fill: "none", class: "axis" }, svg);
  svgElement("text", { x: (PLOT.left + PLOT.right) / 2, y: PLOT.bottom + 36,
                       "text-anchor": "middle" }, svg)
    .textContent = "warm render time (s), median of the rounds";
  svgElement("text", { x: 14, y: (PLOT.top + PLOT.bottom) / 2, "text-anchor": "middle",
                       transform: `rotate(-90 14 ${(PLOT.top + PLOT.bottom) / 2})` }, svg)
    .textContent = `${data.metricNames[metric]} against the reference`;
}

function drawLegendEntry(svg, series, index) {
  const y = PLOT.top + 8 + 18 * index;
  svgElement("circle", { cx: PLOT.legendX + 6, cy: y, r: 5, fill: series.colour }, svg);
  svgElement("text", { x: PLOT.legendX + 16, y: y + 4 }, svg).textContent = series.label;
}

function showTip(point, dot) {
  const tip = byId("tip");
  tip.replaceChildren();
  const figures = point.figures;
  element("strong", "", tip).textContent = point.label;
  element("div", "", tip).textContent = `time ${estimateText(figures.seconds, " s")}`;
  element("div", "", tip).textContent =
    `${data.metricNames[state.plotMetric]} ${formatNumber(point.error, 3)}`;
  const found = imageIndex(figures.image);
  if (found >= 0) {
    const img = element("img", "", tip);
    img.src = data.images[found].src;
    img.alt = data.images[found].label;
    img.style.filter = state.exposure !== 0 ? "url(#exposure-filter)" : "";
  } else {
    element("div", "", tip).textContent = "(no image kept for this rung)";
  }
  const box = byId("plot-box").getBoundingClientRect();
  const at = dot.getBoundingClientRect();
  tip.style.left = `${at.right - box.left + 8}px`;
  tip.style.top = `${at.top - box.top}px`;
  tip.hidden = false;
}

function setUpPlot() {
  const metrics = data.results.metrics.map((metric) => [metric, data.metricNames[metric]]);
  fillSelect(byId("plot-metric"), metrics, state.plotMetric);
  byId("plot-metric").addEventListener("change", (event) => {
    state.plotMetric = event.target.value;
    drawPlot();
  });
  drawPlot();
}

// ------------------------------------------------------------- tables

function drawTables() {
  const section = byId("tables");
  for (const table of data.tables) {
    element("h2", "", section).textContent = table.title;
    const body = element("table", "", section);
    const head = element("tr", "", element("thead", "", body));
    for (const cell of table.header) setText(element("th", "", head), cell);
    const rows = element("tbody", "", body);
    for (const row of table.rows) {
      const line = element("tr", "", rows);
      for (const cell of row) setText(element("td", "", line), cell);
    }
  }
}

setText(byId("title"), data.title);
setText(byId("summary"), data.summary);
document.title = data.title;
setUpViewer();
setUpPlot();
drawTables();
