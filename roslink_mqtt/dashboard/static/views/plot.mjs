// The robot view's plot: world metres (x right, y up) with grid and axis labels, the trail kept while the page is
// open, the laser scan placed where it was taken, the waypoint and the robot. Wheel or +/− zooms, a drag pans,
// "follow" keeps the robot centred; a click sends go-to-waypoint when that box is ticked. Redrawn at most once
// per animation frame, only when something of the shown robot or the view changed.
import { gridStep, gridValues } from "../geometry.mjs";
import { isBlocked, poseAt } from "../model.mjs";
import { dash, selectedRobot } from "../store.mjs";
import { addLog, ui } from "./dom.mjs";
import { axes, caption, polyline } from "./canvas.mjs";
import { command } from "./commands.mjs";

let dirty = false;
let drag = null;  // {x, y, cx, cy, moved}: a pan in progress

export function markDirty() { dirty = true; }

const toPx = (x, y) => dash.view.toPx(ui.plot.width, ui.plot.height, x, y);
const fromPx = (px, py) => dash.view.fromPx(ui.plot.width, ui.plot.height, px, py);

function draw() {
  const robot = selectedRobot();
  const c = ui.plot, g = c.getContext("2d"), view = dash.view;
  g.clearRect(0, 0, c.width, c.height);
  if (!robot) return;
  const p = robot.pose;
  view.track(p);
  const step = gridStep(view.half);
  const xs = gridValues(view.cx - view.half, view.cx + view.half, step);
  const ys = gridValues(view.cy - view.half, view.cy + view.half, step);
  g.strokeStyle = "#eef0f3";
  g.lineWidth = 1;
  g.beginPath();
  for (const v of xs) { const [x] = toPx(v, 0); g.moveTo(x, 0); g.lineTo(x, c.height); }
  for (const v of ys) { const [, y] = toPx(0, v); g.moveTo(0, y); g.lineTo(c.width, y); }
  g.stroke();
  axes(g, c, toPx(0, 0), "#c9ced4");
  caption(g, `grid ${step} m`, 6, c.height - 6);
  // axis labels: metres along the bottom (x) and the left edge (y), on the grid lines
  const labels = [];
  for (const v of xs) {
    const [x] = toPx(v, 0);
    if (x > 40 && x < c.width - 20) { g.fillText(`${v}`, x + 2, c.height - 20); labels.push(`x${v}`); }
  }
  for (const v of ys) {
    const [, y] = toPx(0, v);
    if (y > 12 && y < c.height - 30) { g.fillText(`${v}`, 4, y - 2); labels.push(`y${v}`); }
  }
  g.fillText("x (m) →", c.width - 52, c.height - 6);
  g.fillText("↑ y (m)", 4, 12);
  c.dataset.labels = labels.join(" ");
  polyline(g, robot.trail, toPx, "#4a90d9", 2);  // the trail since the page saw this robot first
  if (p && robot.scan) {  // laser scan, around the robot in its heading (the scanner is taken to sit on base_link)
    const s = robot.scan, at = poseAt(robot, typeof s.time_usec === "number" ? s.time_usec / 1000 : 0) || p;
    g.fillStyle = "#d9534f";
    for (let i = 0; i < s.ranges.length; i++) {
      const r = s.ranges[i];
      if (typeof r !== "number") continue;
      const a = at.yaw + s.angle_min + i * s.angle_increment;
      const [px, py] = toPx(at.x + r * Math.cos(a), at.y + r * Math.sin(a));
      g.fillRect(px - 1.5, py - 1.5, 3, 3);
    }
  }
  if (dash.waypoint) {
    const [wx, wy] = toPx(dash.waypoint[0], dash.waypoint[1]);
    g.strokeStyle = "#2b9a4a";
    g.lineWidth = 2;
    g.beginPath();
    g.arc(wx, wy, 7, 0, 2 * Math.PI);
    g.moveTo(wx - 10, wy); g.lineTo(wx + 10, wy); g.moveTo(wx, wy - 10); g.lineTo(wx, wy + 10);
    g.stroke();
  }
  if (p) {  // the robot: a triangle pointing along its yaw
    const [px, py] = toPx(p.x, p.y);
    g.save();
    g.translate(px, py);
    g.rotate(-p.yaw);
    g.fillStyle = isBlocked(robot) ? "#c4161c" : "#22313f";
    g.beginPath();
    g.moveTo(14, 0); g.lineTo(-9, 8); g.lineTo(-9, -8); g.closePath();
    g.fill();
    g.restore();
  }
}

function frame() {
  if (dirty) {
    dirty = false;
    if (!ui.robotView.hidden) draw();  // the tab's switch marks it dirty again
  }
  requestAnimationFrame(frame);
}

function canvasPoint(ev) {
  const rect = ui.plot.getBoundingClientRect();
  return [(ev.clientX - rect.left) * ui.plot.width / rect.width, (ev.clientY - rect.top) * ui.plot.height / rect.height];
}

function zoom(factor, px, py) {
  dash.view.zoom(factor, px === undefined ? undefined : fromPx(px, py));  // the point under the cursor stays
  dirty = true;
}

function onPlotClick(ev) {
  if (drag && drag.moved) return;  // the end of a pan, not a waypoint
  if (!ui.waypointMode.checked || !dash.selected) return;
  const [x, y] = fromPx(...canvasPoint(ev));
  if (command(dash.selected, "go_to_waypoint", { frame_type: 0, x: +x.toFixed(3), y: +y.toFixed(3), z: 0 }, 101)) {
    dash.waypoint = [x, y];
    addLog(ui.acks, `sent go-to-waypoint (${x.toFixed(2)}, ${y.toFixed(2)}) to ${dash.selected}`);
    dirty = true;
  }
}

export function installPlot() {
  const plot = ui.plot, view = dash.view;
  plot.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const [px, py] = canvasPoint(ev);
    zoom(ev.deltaY > 0 ? 1.25 : 0.8, px, py);
  }, { passive: false });
  plot.addEventListener("pointerdown", (ev) => {
    const [px, py] = canvasPoint(ev);
    drag = { x: px, y: py, cx: view.cx, cy: view.cy, moved: false };
  });
  plot.addEventListener("pointermove", (ev) => {
    if (!drag || !(ev.buttons & 1)) return;
    const [px, py] = canvasPoint(ev);
    const s = view.scale(plot.width);
    if (!drag.moved && Math.hypot(px - drag.x, py - drag.y) < 4) return;  // a click, not a drag
    drag.moved = true;
    view.follow = false;
    ui.plotFollow.checked = false;
    view.cx = drag.cx - (px - drag.x) / s;
    view.cy = drag.cy + (py - drag.y) / s;
    view.manual = true;
    dirty = true;
  });
  plot.addEventListener("pointerup", () => { setTimeout(() => { drag = null; }, 0); });
  plot.addEventListener("click", onPlotClick);
  ui.plotZoomIn.addEventListener("click", () => zoom(0.5));
  ui.plotZoomOut.addEventListener("click", () => zoom(2));
  ui.plotFollow.addEventListener("change", () => { view.follow = ui.plotFollow.checked; view.manual = true; dirty = true; });
  ui.plotReset.addEventListener("click", () => {
    view.reset();
    ui.plotFollow.checked = false;
    dirty = true;
  });
  requestAnimationFrame(frame);
}
