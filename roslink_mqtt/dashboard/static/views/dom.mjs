// The page's elements by id, and the few helpers every view uses. Elements are built with createElement and
// textContent only: names and texts come from robots and the broker, never as HTML.
import { clock } from "../model.mjs";

const IDS = [
  "conn", "whoami", "logout", "estop", "stop-all", "driver", "take-over", "claim", "release", "notice", "login",
  "login-form", "ws-url", "username", "password", "connect", "login-error", "main", "fleet", "fleet-empty",
  "fleet-map", "map-mode", "map-note", "attention", "alerts", "alerts-count", "alerts-ack-all",
  "alert-rules", "rule-battery", "rule-stale", "rule-offline", "rule-failsafe", "rule-errors", "rule-notify",
  "robot-view", "robot-title", "robot-banner", "tabs", "tab-fleet", "tab-robot", "fleet-badge", "fleet-view", "plot", "pose", "waypoint-label", "waypoint-mode",
  "controls", "speed", "speed-out", "arm", "driving", "viewer-note", "services-box", "services", "service-result",
  "actions-box", "actions", "params-box", "params", "snapshot-box", "snapshot", "snapshot-status", "plot-zoom-in",
  "plot-zoom-out", "plot-follow", "plot-reset", "inspector", "inspector-head", "inspector-body", "inspector-raw", "charts",
  "rates", "uplink", "gps-box", "gps", "gps-text", "camera-box", "camera", "errors", "acks", "video-box",
  "video-stream", "video-watch", "video-stats", "video-canvas",
];

export const ui = {};
for (const id of IDS) ui[id.replace(/-(\w)/g, (_, c) => c.toUpperCase())] = document.getElementById(id);

export function show(element, on) { element.hidden = !on; }
export function setText(element, text) { if (element.textContent !== text) element.textContent = text; }
export function stamp() { return clock(Date.now()); }

/** The red line under the header (fixed: it never moves what is under a held pointer). */
export function notice(text) {
  ui.notice.textContent = text;
  show(ui.notice, Boolean(text));
}

const LOG_MAX = 30;  // list items kept in the error and ack lists
export function addLog(list, text, attrs) {
  const li = document.createElement("li");
  li.textContent = `${stamp()}  ${text}`;
  if (attrs) for (const [k, v] of Object.entries(attrs)) li.dataset[k] = v;
  list.prepend(li);
  while (list.childElementCount > LOG_MAX) list.lastElementChild.remove();
}

/** An element with attributes (data-* as dataset, class as className, others as properties) and text. */
export function el(tag, attrs, text) {
  const e = document.createElement(tag);
  if (attrs) for (const [k, v] of Object.entries(attrs)) {
    if (k.startsWith("data-")) e.dataset[k.slice(5).replace(/-(\w)/g, (_, c) => c.toUpperCase())] = v;
    else if (k === "class") e.className = v;
    else e[k] = v;
  }
  if (text !== undefined) e.textContent = text;
  return e;
}

export function randomHex(bytes) {
  const a = new Uint8Array(bytes);
  crypto.getRandomValues(a);
  return Array.from(a, (b) => b.toString(16).padStart(2, "0")).join("");
}
