// The selected robot's time series (model.mjs keeps them per robot while the page is open): battery, speed and
// uplink quality, drawn by uPlot (npm `uplot`, served from the install like MQTT.js). Updated once a second.
import uPlot from "../vendor/uPlot.esm.js";
import { SERIES } from "../model.mjs";
import { selectedRobot } from "../store.mjs";
import { el, setText, ui } from "./dom.mjs";

const CHARTS = {
  battery: { title: "battery", unit: "%", stroke: "#2b9a4a", range: [0, 100] },
  speed: { title: "speed", unit: "m/s", stroke: "#4a90d9", range: null },
  link: { title: "uplink carries", unit: "% of its streams", stroke: "#b36b00", range: [0, 100] },
};
const HEIGHT = 110;
const charts = new Map();  // series key → {plot, latest, box}
let shownFor = null;

const toSeconds = (ms) => (performance.timeOrigin + ms) / 1000;

/** Two charts side by side where they fit (the plot's 560 px), one per row on a phone. */
function width() {
  const w = ui.charts.clientWidth || 560;
  return Math.floor(Math.max(180, w >= 500 ? (w - 40) / 2 : w - 12));
}

function build() {
  ui.charts.replaceChildren();
  for (const key of SERIES) {
    const spec = CHARTS[key];
    const box = el("div", { class: "chart", "data-series": key });
    const head = el("p", { class: "chart-head" });
    const latest = el("span", { class: "latest" }, "no data yet");
    head.append(el("strong", null, `${spec.title} `), latest);
    const area = el("div", { class: "chart-area" });
    area.setAttribute("role", "img");
    area.setAttribute("aria-label", `${spec.title} (${spec.unit}) over time`);
    box.append(head, area);
    ui.charts.append(box);
    const plot = new uPlot({
      width: width(), height: HEIGHT, legend: { show: false }, cursor: { drag: { x: false, y: false } },
      scales: { x: { time: true }, y: spec.range ? { range: spec.range } : { range: (u, lo, hi) => [0, Math.max(0.1, hi * 1.1)] } },
      axes: [{ size: 30, font: "11px sans-serif" }, { size: 42, font: "11px sans-serif", label: spec.unit, labelSize: 14, labelFont: "11px sans-serif" }],
      series: [{}, { label: spec.title, stroke: spec.stroke, width: 1.5, points: { show: false } }],
    }, [[], []], area);
    charts.set(key, { plot, latest, box, spec });
  }
}

/** Show the charts of `robot` (called when a robot is selected). */
export function showCharts(robot) {
  if (!charts.size) build();
  shownFor = robot ? robot.name : null;
  updateCharts();
}

/** Fresh data into each chart (once a second, and on selection). */
export function updateCharts() {
  const robot = selectedRobot();
  if (!robot || robot.name !== shownFor || !charts.size) return;
  for (const [key, c] of charts) {
    const s = robot.series[key];
    c.plot.setData([s.t.map(toSeconds), s.v.slice()]);
    const last = s.last();
    setText(c.latest, last === null ? "no data yet" : `${key === "speed" ? last.toFixed(2) : Math.round(last)} ${c.spec.unit}`);
    c.box.dataset.points = String(s.length);
  }
}

export function installCharts() {
  window.addEventListener("resize", () => { for (const c of charts.values()) c.plot.setSize({ width: width(), height: HEIGHT }); });
}
