// The robot view: one robot's banner, who drives it, its position readout, rates and state inspector, GPS,
// camera, and the panels built from its access report and description (drive, services, actions, parameters).
import { STATUS, parse } from "../decode.mjs";
import { isLayout } from "../forms.mjs";
import { driverText, fmt, heldByOther, isBlocked, isOperator, mayStop, uplinkText } from "../model.mjs";
import { dash, selectedRobot } from "../store.mjs";
import { addLog, notice, setText, show, ui } from "./dom.mjs";
import { blockPad, stopDriving } from "./drive.mjs";
import { startPresence } from "./session.mjs";
import { serviceControl } from "./services.mjs";
import { buildActions } from "./actions.mjs";
import { buildParams, clearParams } from "./params.mjs";
import { showSnapshot } from "./snapshot.mjs";
import { showVideo } from "./video.mjs";
import { markDirty } from "./plot.mjs";
import { showCharts } from "./charts.mjs";
import { clearFleet, updateRow } from "./fleet.mjs";
import { renderTabs } from "./pages.mjs";
import { caption, polyline } from "./canvas.mjs";

const decoder = new TextDecoder();
const INSPECT_MAX = 4000;  // characters of a message shown by the state inspector
const RAW_BYTES = 256;     // bytes of a binary payload shown in hex

export function selectRobot(name) {
  if (dash.driveRobot && dash.driveRobot !== name) stopDriving(true);
  const changed = dash.selected !== name;
  dash.selected = name;
  const robot = selectedRobot();
  renderTabs();
  if (!robot) { show(ui.estop, false); showVideo(null); return; }
  ui.robotTitle.textContent = `Robot ${name}`;
  ui.rates.tBodies[0].replaceChildren();
  dash.rateRows = new Map();
  dash.inspect = null;
  show(ui.inspector, false);
  ui.acks.replaceChildren();
  showUplink(robot);
  show(ui.gpsBox, false);
  if (robot.gpsFix) drawGps(robot);
  show(ui.cameraBox, false);
  ui.serviceResult.textContent = "";
  dash.waypoint = null;
  dash.builtFor = null;
  if (changed) {  // another robot: its own plot from the origin
    dash.view.reset();
    ui.plotFollow.checked = false;
  }
  buildControls(robot);
  updatePose(robot);
  updateBanner(robot);
  showCharts(robot);
  renderRates(performance.now());
  for (const r of dash.robots.values()) updateRow(r, performance.now());
  markDirty();
}

/** Logged out: every robot and everything shown of them goes. */
export function clearRobots() {
  dash.robots.clear();
  dash.selected = null;
  dash.builtFor = null;
  for (const g of dash.goals.values()) clearTimeout(g.timer);
  dash.goals.clear();
  clearParams();
  ui.services.replaceChildren();
  ui.actions.replaceChildren();
  clearFleet();
  ui.errors.replaceChildren();
  ui.acks.replaceChildren();
  dash.page = "robot";
  renderTabs();
}

/** Operator presence (heartbeat + last-will) is kept by operators, and by a viewer who may send goals (an action
 * open to viewers in the access report) or set parameters (an entry with set_by viewers): the robot accepts goals
 * and parameter sets only from users with a live presence, as commands. */
export function presenceIfNeeded(robot) {
  if (dash.operatorAnywhere || !robot.access) return;
  const d = robot.description;
  const viewerSets = Boolean(d && Array.isArray(d.parameters) &&
                             d.parameters.some((e) => isLayout(e) && e.set_by === "viewers"));
  const actions = Array.isArray(robot.access.actions) && robot.access.actions.length > 0;
  if (isOperator(robot) || actions || viewerSets) {
    dash.operatorAnywhere = true;
    startPresence();
  }
}

export function showControl(robot) {
  const who = driverText(robot);
  const line = who ? `driven by ${who}` : "nobody drives it: the first command claims control";
  // an emergency stop shows where people look for who drives (state/control's `blocked`; the heartbeat's status
  // from a bridge that does not send it)
  const blocked = robot.control && robot.control.blocked ? robot.control.blocked : (isBlocked(robot) ? "emergency stop" : "");
  setText(ui.driver, blocked ? `${line} · EMERGENCY STOP (${blocked}): an operator's Arm resumes` : line);
  ui.driver.classList.toggle("blocked", Boolean(blocked));
  ui.driver.dataset.holder = robot.control && robot.control.holder ? robot.control.holder : "";
  const other = heldByOther(robot, dash.user);
  const sup = robot.control && Array.isArray(robot.control.supervisors) && robot.control.supervisors.includes(dash.user);
  show(ui.takeOver, isOperator(robot) && other && (!robot.control.supervisor || sup));
  ui.takeOver.textContent = other ? `Take over from ${robot.control.holder}` : "Take over";
  show(ui.claim, isOperator(robot) && Boolean(robot.control) && robot.control.holder === null);
  show(ui.release, Boolean(robot.control) && robot.control.holder === dash.user);
}

export function buildControls(robot) {
  const op = isOperator(robot);
  show(ui.controls, op);
  showControl(robot);
  showSnapshot(robot);
  showVideo(robot);
  show(ui.stopAll, [...dash.robots.values()].some(mayStop));
  show(ui.estop, mayStop(robot));
  ui.estop.textContent = mayStop(robot) ? `EMERGENCY STOP ${robot.name}` : "EMERGENCY STOP";
  show(ui.waypointLabel, op);
  if (!op) ui.waypointMode.checked = false;
  ui.viewerNote.textContent = robot.access === undefined
    ? "Waiting for this robot's access report (retained on to/<you>/access): no controls until it says you operate it."
    : robot.access === null ? "You have no access report from this robot: no controls."
    : op ? "" : `You are a ${robot.access.role} of ${robot.name}: you may watch it, not command it.`;
  show(ui.viewerNote, !op);
  // Forms, action and parameter panels: rebuilt only when the access report or the description changed
  // (rebuilding would lose what the user typed and the parameter values read).
  const key = `${JSON.stringify([robot.name, robot.access])}\n${robot.descRaw}`;
  if (dash.builtFor === key) return;
  dash.builtFor = key;
  const services = robot.access && Array.isArray(robot.access.services) ? robot.access.services : [];
  ui.services.replaceChildren();
  for (const svc of services) if (typeof svc === "string") ui.services.append(serviceControl(robot, svc));
  show(ui.servicesBox, services.length > 0);
  buildActions(robot);
  buildParams(robot);
}

export function updateBanner(robot) {
  const hb = robot.hb;
  const blocked = isBlocked(robot);
  if (dash.selected === robot.name) blockPad(blocked);
  // the stop was lifted (Resume): the refusals it caused are resolved, their red line goes
  if (robot.blocked && !blocked && ui.notice.textContent.startsWith(`${robot.name} refused`)) notice("");
  robot.blocked = blocked;
  let text = "";
  if (blocked) text = `Motion blocked on ${robot.name} (emergency stop or disarm)` +
    (isOperator(robot) ? ": press Resume (arm) to drive again." : ".");
  else if (hb && STATUS[hb.system_status] === "offline") text = `${robot.name} is offline (its bridge is gone).`;
  setText(ui.robotBanner, text);
  show(ui.robotBanner, Boolean(text));
}

export function updatePose(robot) {
  const p = robot.pose;
  if (!p) { ui.pose.textContent = "no position yet"; ui.pose.dataset.n = "0"; return; }
  ui.pose.textContent = `x ${fmt(p.x, 2)} m  y ${fmt(p.y, 2)} m  yaw ${fmt(p.yaw * 180 / Math.PI, 0)}°  ` +
    `v ${fmt(p.vx, 2)} m/s  ω ${fmt(p.wz, 2)} rad/s`;
  ui.pose.dataset.x = p.x.toFixed(3);
  ui.pose.dataset.y = p.y.toFixed(3);
  ui.pose.dataset.yaw = p.yaw.toFixed(3);
  ui.pose.dataset.n = String(robot.poses);
}

export function showUplink(robot) { setText(ui.uplink, uplinkText(robot.link)); }

/** The rates table of the selected robot (once a second); a click on a row opens the state inspector on it. */
export function renderRates(now) {
  const robot = selectedRobot();
  if (!robot) return;
  const body = ui.rates.tBodies[0];
  for (const [name, rate] of [...robot.rates.entries()].sort()) {
    let row = dash.rateRows.get(name);
    if (!row) {
      row = document.createElement("tr");
      row.dataset.topic = name;
      row.append(document.createElement("td"), document.createElement("td"), document.createElement("td"));
      row.cells[0].textContent = name;
      row.title = "show its latest message";
      row.tabIndex = 0;
      const open = () => { dash.inspect = name; inspect(robot); };
      row.addEventListener("click", open);
      row.addEventListener("keydown", (ev) => { if (ev.key === "Enter") open(); });
      body.append(row);
      dash.rateRows.set(name, row);
    }
    setText(row.cells[1], rate.hz.toFixed(1));
    setText(row.cells[2], `${((now - rate.last) / 1000).toFixed(1)} s ago`);
    row.dataset.hz = rate.hz.toFixed(1);
  }
  inspect(robot);
}

/** The state inspector: the latest message of the row clicked in "Message rates", raw and decoded, with its age. */
function inspect(robot) {
  const name = dash.inspect;
  const rate = robot && name ? robot.rates.get(name) : null;
  show(ui.inspector, Boolean(rate));
  if (!rate) return;
  const payload = rate.payload;
  const encoding = name === "heartbeat" ? "json" : (entryOf(robot, "state", name) || {}).encoding || "json";
  const age = `${((performance.now() - rate.last) / 1000).toFixed(1)} s ago`;
  let body = "";
  if (!payload) body = "(no payload kept)";
  else if (encoding === "json") {
    const value = parse(payload);
    body = value === undefined ? decoder.decode(payload) : JSON.stringify(value, null, 2);
  } else body = `${encoding}: ${payload.length} bytes, not shown as text`;
  const head = `${name === "heartbeat" ? name : `state/${name}`} · ${encoding} · ` +
    `${payload ? payload.length : 0} bytes · ${rate.hz.toFixed(1)} Hz · ${age}`;
  setText(ui.inspectorHead, head);
  setText(ui.inspectorBody, body.length > INSPECT_MAX ? `${body.slice(0, INSPECT_MAX)}…` : body);
  setText(ui.inspectorRaw, rawText(payload, encoding));
  ui.inspector.dataset.topic = name;
}

/** The payload as it came: its text when JSON, else the first bytes in hex. */
function rawText(payload, encoding) {
  if (!payload) return "";
  if (encoding === "json") {
    const text = decoder.decode(payload);
    return text.length > INSPECT_MAX ? `${text.slice(0, INSPECT_MAX)}…` : text;
  }
  const head = Array.from(payload.subarray(0, RAW_BYTES), (b) => b.toString(16).padStart(2, "0")).join(" ");
  return payload.length > RAW_BYTES ? `${head} … (${payload.length} bytes)` : head;
}

export function drawGps(robot) {
  show(ui.gpsBox, true);
  const c = ui.gps, g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  const fix = robot.gpsFix;
  ui.gpsText.textContent = `lat ${fix.lat.toFixed(6)}  lon ${fix.lon.toFixed(6)}  alt ${fmt(fix.alt, 1)} m  ` +
    `fix ${fix.fix_type}D  sats ${fix.satellites_visible ? fix.satellites_visible : "–"}`;  // 0: not reported
  // local equirectangular metres around the first fix: no map tiles, nothing fetched
  const [lat0, lon0] = robot.gps[0];
  const k = Math.cos(lat0 * Math.PI / 180) * 111320;
  const pts = robot.gps.map(([la, lo]) => [(lo - lon0) * k, (la - lat0) * 110540]);
  let half = 5;
  for (const [x, y] of pts) half = Math.max(half, Math.abs(x) + 1, Math.abs(y) + 1);
  const s = c.width / (2 * half);
  const px = ([x, y]) => [c.width / 2 + x * s, c.height / 2 - y * s];
  g.strokeStyle = "#e6e2cf";
  g.strokeRect(0.5, 0.5, c.width - 1, c.height - 1);
  polyline(g, pts, (x, y) => px([x, y]), "#8a6d3b", 2);
  const [lx, ly] = px(pts[pts.length - 1]);
  g.fillStyle = "#8a6d3b";
  g.beginPath();
  g.arc(lx, ly, 4, 0, 2 * Math.PI);
  g.fill();
  caption(g, `N ↑   ±${half.toFixed(0)} m`, 6, 14);
}

/** A ROSLink image message (base64 in JSON) in the camera box. */
export function showImage(im) {
  if (!/^[a-z0-9.+-]+$/i.test(im.format)) return;
  ui.camera.src = `data:image/${im.format.toLowerCase()};base64,${im.data}`;
  show(ui.cameraBox, true);
}

/** A rule with `encoding: raw` sends a CompressedImage's JPEG or PNG itself (docs/protocol.md, "State encodings"):
 * shown from a blob URL, the previous one released. What the page cannot decode (CBOR) is said once, not hidden. */
export function showImageBytes(robot, name, b) {
  const type = b.length > 3 && b[0] === 0xff && b[1] === 0xd8 && b[2] === 0xff ? "image/jpeg"
    : b.length > 4 && b[0] === 0x89 && b[1] === 0x50 && b[2] === 0x4e && b[3] === 0x47 ? "image/png" : null;
  if (!type) { notDecoded(robot, name, "raw bytes that are neither JPEG nor PNG"); return; }
  const url = URL.createObjectURL(new Blob([b], { type }));
  if (dash.cameraUrl) URL.revokeObjectURL(dash.cameraUrl);
  dash.cameraUrl = url;
  ui.camera.src = url;
  ui.camera.dataset.state = name;
  show(ui.cameraBox, true);
}

export function notDecoded(robot, name, what) {
  const key = `${robot.name}/${name}`;
  if (dash.undecoded.has(key)) return;
  dash.undecoded.add(key);
  addLog(ui.errors, `${robot.name} state/${name} is ${what}: this page does not show it (the SDK decodes it)`,
         { robot: robot.name });
}

/** The description's layout of a ROS type (for forms), or undefined. */
export function typeLayout(robot, rosType) {
  const d = robot.description;
  const t = d && isLayout(d.types) && typeof rosType === "string" ? d.types[rosType] : undefined;
  return isLayout(t) ? t : undefined;
}

/** The description's entry `name` in its list `kind` (state, services, actions, parameters), or undefined. */
export function entryOf(robot, kind, name) {
  const d = robot.description;
  const list = d && Array.isArray(d[kind]) ? d[kind] : [];
  return list.find((e) => isLayout(e) && e.name === name);
}

