// The fleet overview: a map of every robot (each in its own local frame, or by GPS on optional map tiles), the
// attention list (robots by urgency, with why), and the table (presence, status, battery, link, who drives,
// your role). A click on a robot anywhere opens its view.
import { MODES, STATUS } from "../decode.mjs";
import { LEVELS, attention, attentionOf, batteryOf, driverText, fmt, linkQuality, presenceOf,
         sessionText } from "../model.mjs";
import { TILE, fitPoints, mercator, tileUrl, tilesFor, zoomToFit } from "../geometry.mjs";
import { dash } from "../store.mjs";
import { el, setText, show, ui } from "./dom.mjs";
import { selectRobot } from "./robot.mjs";
import { axes, caption, polyline } from "./canvas.mjs";
import { showPage } from "./pages.mjs";

const COLUMNS = ["name", "presence", "status", "session", "age", "battery", "link", "mode", "owner", "role"];
const LABELS = { age: "heartbeat", owner: "driven by", role: "your role" };  // a phone's cards label each cell
const MAP_PERIOD_MS = 200;  // the map is redrawn at most 5 times a second
const MAP_TRAIL = 600;      // trail points drawn per robot on the map
const TILES_MAX = 96;       // map tiles kept in memory
const LEVEL_COLOURS = ["#22313f", "#4a6fa5", "#b36b00", "#c4161c"];
const rows = new Map();     // robot name → {tr, cells}
const tiles = new Map();    // tile URL → Image (insertion order: the oldest is dropped first)
let mapDrawnAt = 0;
let mapPending = false;
let placed = [];            // [name, px, py] where the map drew each robot (for clicks)
let attentionKey = "";
const attentionItems = new Map();  // robot name → {li, why}: kept while listed

export function addFleetRow(robot) {
  const tr = el("tr", { "data-robot": robot.name });
  const cells = {};
  for (const key of COLUMNS) {
    const td = el("td", { class: key, "data-label": LABELS[key] || key });
    tr.append(td);
    cells[key] = td;
  }
  cells.name.textContent = robot.name;
  tr.tabIndex = 0;
  tr.addEventListener("click", () => openRobot(robot.name));
  tr.addEventListener("keydown", (ev) => { if (ev.key === "Enter") openRobot(robot.name); });
  rows.set(robot.name, { tr, cells });
  const body = ui.fleet.tBodies[0];
  const before = Array.from(body.rows).find((r) => r.dataset.robot > robot.name);
  body.insertBefore(tr, before || null);
  show(ui.fleetEmpty, false);
}

export function removeFleetRow(robot) {
  if (!robot) return;
  const row = rows.get(robot.name);
  if (row) row.tr.remove();
  rows.delete(robot.name);
}

export function clearFleet() {
  rows.clear();
  ui.fleet.tBodies[0].replaceChildren();
  ui.attention.replaceChildren();
  attentionItems.clear();
  attentionKey = "";
  placed = [];
}

/** Select a robot and show its view. */
export function openRobot(name) {
  selectRobot(name);
  showPage("robot");
  window.scrollTo(0, 0);
}

export function updateRow(robot, now) {
  const row = rows.get(robot.name);
  if (!row) return;
  const c = row.cells, hb = robot.hb;
  const presence = presenceOf(robot, now);
  c.presence.dataset.presence = presence;
  row.tr.dataset.presence = presence;
  row.tr.dataset.level = LEVELS[attentionOf(robot, now).level];
  setText(c.presence, presence);
  setText(c.status, hb ? (STATUS[hb.system_status] || String(hb.system_status)) : "–");
  setText(c.session, hb && hb.session !== undefined ? sessionText(hb.session) : "–");
  setText(c.age, hb ? `${((now - robot.hbAt) / 1000).toFixed(1)} s` : "–");
  const st = robot.status, b = batteryOf(robot);
  setText(c.battery, st ? `${b !== null ? `${Math.round(b)} %` : "?"} ${fmt(st.voltage_battery, 1)} V` : "–");
  const q = linkQuality(robot.link);
  setText(c.link, q === null ? "–" : `${Math.round(q * 100)} %`);
  setText(c.mode, hb ? (MODES[hb.mode] || String(hb.mode)) : "–");
  setText(c.owner, driverText(robot) || "–");
  setText(c.role, robot.access ? robot.access.role : (robot.access === null ? "none" : "–"));
  row.tr.classList.toggle("selected", dash.selected === robot.name);
}

/** The attention list: every robot, most urgent first, with why; changed in place only when what it says changed.
 * Each robot keeps its own item for as long as it is listed: an item rebuilt between a press and its release (the
 * reasons change while a robot's link is down) would swallow the click that was meant to open that robot. */
export function updateAttention(now) {
  const list = attention(dash.robots.values(), now, dash.rules ? dash.rules.battery_below || 0 : undefined);
  const key = list.map((a) => `${a.robot.name}|${a.level}|${a.reasons.join(";")}`).join("\n");
  if (key === attentionKey) return;
  attentionKey = key;
  const listed = new Set();
  let next = ui.attention.firstChild;
  for (const { robot, level, reasons } of list) {
    const item = attentionItem(robot.name);
    item.li.dataset.level = LEVELS[level];
    setText(item.why, reasons.length ? reasons.join(" · ") : "ok");
    if (item.li === next) next = next.nextSibling;
    else ui.attention.insertBefore(item.li, next);  // moved only when the order changed
    listed.add(robot.name);
  }
  for (const [name, item] of attentionItems) {
    if (!listed.has(name)) { item.li.remove(); attentionItems.delete(name); }
  }
}

function attentionItem(name) {
  let item = attentionItems.get(name);
  if (!item) {
    const li = el("li", { "data-robot": name });
    const b = el("button", { type: "button", class: "robot-link" }, name);
    b.addEventListener("click", () => openRobot(name));
    const why = el("span", { class: "why" });
    li.append(b, why);
    item = { li, why };
    attentionItems.set(name, item);
  }
  return item;
}

// ---------------------------------------------------------------------------------------------------- the map
function mapMode() { return ui.mapMode.value === "gps" ? "gps" : "local"; }

/** Redraw the map (throttled: at most every MAP_PERIOD_MS, the last call is never lost). */
export function drawFleetMap() {
  const now = performance.now();
  if (now - mapDrawnAt < MAP_PERIOD_MS) {
    if (!mapPending) {
      mapPending = true;
      setTimeout(() => { mapPending = false; drawFleetMap(); }, MAP_PERIOD_MS - (now - mapDrawnAt));
    }
    return;
  }
  if (ui.fleetView.hidden) return;  // drawn when shown (the tab's click redraws)
  mapDrawnAt = now;
  const c = ui.fleetMap, g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  placed = [];
  if (mapMode() === "gps") drawGpsMap(c, g, now);
  else drawLocalMap(c, g, now);
  c.dataset.robots = placed.map(([name]) => name).join(" ");
}

function robotMark(g, name, px, py, yaw, level) {
  g.save();
  g.translate(px, py);
  if (yaw !== null) {
    g.rotate(-yaw);
    g.beginPath();
    g.moveTo(10, 0); g.lineTo(-7, 6); g.lineTo(-7, -6); g.closePath();
  } else {
    g.beginPath();
    g.arc(0, 0, 6, 0, 2 * Math.PI);
  }
  g.fillStyle = LEVEL_COLOURS[level];
  g.fill();
  g.restore();
  g.fillStyle = "#1d2327";
  g.font = "12px sans-serif";
  g.fillText(name, px + 9, py - 8);
  placed.push([name, px, py]);
}

function drawLocalMap(c, g, now) {
  const robots = [...dash.robots.values()].filter((r) => r.pose);
  setText(ui.mapNote, robots.length ? "each robot in its own odometry frame (x right, y up, metres)"
    : "no robot has reported a position yet");
  const { cx, cy, half } = fitPoints(robots.map((r) => [r.pose.x, r.pose.y]));
  const s = Math.min(c.width, c.height) / (2 * half);
  const px = (x, y) => [c.width / 2 + (x - cx) * s, c.height / 2 - (y - cy) * s];
  axes(g, c, px(0, 0), "#dde1e6");
  caption(g, `±${half.toFixed(0)} m`, 6, c.height - 6);
  for (const r of robots) {
    polyline(g, r.trail.length > MAP_TRAIL ? r.trail.slice(-MAP_TRAIL) : r.trail, px, "#a8c3e6", 1.5);
    const [a, b] = px(r.pose.x, r.pose.y);
    robotMark(g, r.name, a, b, r.pose.yaw, attentionOf(r, now).level);
  }
}

function tile(url) {
  let im = tiles.get(url);
  if (!im) {
    im = new Image();
    im.onload = () => drawFleetMap();
    im.src = url;
    tiles.set(url, im);
    while (tiles.size > TILES_MAX) tiles.delete(tiles.keys().next().value);
  }
  return im;
}

function drawGpsMap(c, g, now) {
  const robots = [...dash.robots.values()].filter((r) => r.gpsFix);
  const template = dash.config && dash.config.tiles;
  if (!robots.length) {
    setText(ui.mapNote, "no robot reports a GPS fix");
    return;
  }
  const points = robots.map((r) => [r.gpsFix.lat, r.gpsFix.lon]);
  const z = zoomToFit(points, c.width, c.height);
  const px = points.map(([la, lo]) => mercator(la, lo, z));
  const mx = (Math.min(...px.map((p) => p[0])) + Math.max(...px.map((p) => p[0]))) / 2;
  const my = (Math.min(...px.map((p) => p[1])) + Math.max(...px.map((p) => p[1]))) / 2;
  const left = mx - c.width / 2, top = my - c.height / 2;
  if (template) {
    for (const t of tilesFor(left, top, c.width, c.height, z)) {
      const im = tile(tileUrl(template, t));
      if (im.complete && im.naturalWidth) g.drawImage(im, t.px, t.py, TILE, TILE);
    }
  }
  setText(ui.mapNote, `GPS, zoom ${z}` + (template ? ` — ${dash.config.tiles_attribution || "map tiles"}` : " (no map tiles configured)"));
  robots.forEach((r, i) => {
    const onMap = (la, lo) => { const [x, y] = mercator(la, lo, z); return [x - left, y - top]; };
    polyline(g, r.gps.slice(-MAP_TRAIL), onMap, "#8a6d3b", 1.5);
    robotMark(g, r.name, px[i][0] - left, px[i][1] - top, null, attentionOf(r, now).level);
  });
}

export function installFleet() {
  ui.mapMode.addEventListener("change", () => { mapDrawnAt = 0; drawFleetMap(); });
  ui.fleetMap.addEventListener("click", (ev) => {
    const rect = ui.fleetMap.getBoundingClientRect();
    const x = (ev.clientX - rect.left) * ui.fleetMap.width / rect.width;
    const y = (ev.clientY - rect.top) * ui.fleetMap.height / rect.height;
    let best = null, bestD = 24;
    for (const [name, px, py] of placed) {
      const d = Math.hypot(px - x, py - y);
      if (d < bestD) { best = name; bestD = d; }
    }
    if (best) openRobot(best);
  });
}
