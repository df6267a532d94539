// The alert list and its settings: rules the operator chose (kept in this browser's localStorage), alerts shown
// until acknowledged (acknowledgements kept for the session in sessionStorage), and, where the browser allows and
// the operator asked, a notification for each new alert.
import { AlertBook, DEFAULT_RULES, readRules } from "../alerts.mjs";
import { clock } from "../model.mjs";
import { dash } from "../store.mjs";
import { el, setText, ui } from "./dom.mjs";
import { openRobot } from "./fleet.mjs";

const RULES_KEY = "roslink.alert-rules";
const ACKED_KEY = "roslink.alerts-acked";
let listKey = "";

function stored(storage, key) {
  try { return JSON.parse(storage.getItem(key) || "null"); } catch (e) { return null; }
}

function save(storage, key, value) {
  try { storage.setItem(key, JSON.stringify(value)); } catch (e) { /* private mode: kept for this page only */ }
}

function notify(alerts) {
  if (!dash.rules.notify || !alerts.length || typeof Notification === "undefined" || Notification.permission !== "granted") return;
  for (const a of alerts) {
    try { new Notification(`roslink: ${a.robot}`, { body: a.text, tag: a.key }); } catch (e) { /* not allowed here */ }
  }
}

/** Conditions of every robot against the rules (every half second). */
export function evaluateAlerts(now) {
  notify(dash.alerts.evaluate(dash.robots.values(), dash.rules, now));
  renderAlerts();
}

export function onFailsafeAlert(robot, text, now) {
  if (!dash.rules || !dash.rules.failsafe) return;
  notify([dash.alerts.event(robot.name, "failsafe", `${robot.name}: failsafe stop — ${text}`, now, Math.round(now))].filter(Boolean));
  renderAlerts();
}

/** A refusal or error report: one alert per distinct text and minute (a refused stream of twists is one alert). */
export function onErrorAlert(robotName, text, now) {
  if (!dash.rules || !dash.rules.errors) return;
  notify([dash.alerts.event(robotName, "error", text, now, `${Math.floor(now / 60000)}:${text}`)].filter(Boolean));
  renderAlerts();
}

function acknowledge(key) {
  if (key === null) dash.alerts.acknowledgeAll();
  else dash.alerts.acknowledge(key);
  save(sessionStorage, ACKED_KEY, [...dash.alerts.acked]);
  renderAlerts();
}

function renderAlerts() {
  const list = dash.alerts.list();
  const key = list.map((a) => `${a.key}|${a.active}|${dash.alerts.isAcked(a)}|${a.text}`).join("\n");
  const pending = dash.alerts.pending();
  setText(ui.alertsCount, String(pending));
  ui.alertsCount.dataset.pending = pending ? "yes" : "no";
  ui.alertsAckAll.disabled = pending === 0;
  if (key === listKey) return;
  listKey = key;
  ui.alerts.replaceChildren(...list.map((a) => {
    const acked = dash.alerts.isAcked(a);
    const li = el("li", { "data-key": a.key, "data-robot": a.robot, "data-kind": a.kind, "data-severity": a.severity,
                          "data-state": acked ? "acknowledged" : a.active ? "active" : "resolved" });
    const time = clock(performance.timeOrigin + a.since);
    const text = el("button", { type: "button", class: "robot-link", title: `open ${a.robot}` }, `${time} ${a.text}` +
                    (a.active ? "" : " (resolved)"));
    text.addEventListener("click", () => openRobot(a.robot));
    li.append(text);
    if (!acked) {
      const ack = el("button", { type: "button", class: "ack" }, "Acknowledge");
      ack.setAttribute("aria-label", `acknowledge: ${a.text}`);
      ack.addEventListener("click", () => acknowledge(a.key));
      li.append(ack);
    }
    return li;
  }));
}

function showRules() {
  const r = dash.rules;
  ui.ruleBattery.value = String(r.battery_below);
  ui.ruleStale.checked = r.stale;
  ui.ruleOffline.checked = r.offline;
  ui.ruleFailsafe.checked = r.failsafe;
  ui.ruleErrors.checked = r.errors;
  ui.ruleNotify.checked = r.notify;
}

function rulesChanged() {
  const battery = Number(ui.ruleBattery.value);
  dash.rules = readRules({
    battery_below: Number.isFinite(battery) ? Math.max(0, Math.min(100, battery)) : DEFAULT_RULES.battery_below,
    stale: ui.ruleStale.checked, offline: ui.ruleOffline.checked, failsafe: ui.ruleFailsafe.checked,
    errors: ui.ruleErrors.checked, notify: ui.ruleNotify.checked,
  });
  save(localStorage, RULES_KEY, dash.rules);
  if (dash.rules.notify && typeof Notification !== "undefined" && Notification.permission === "default") {
    Notification.requestPermission().catch(() => {});
  }
  evaluateAlerts(performance.now());
}

export function installAlerts() {
  dash.rules = readRules(stored(localStorage, RULES_KEY));
  const acked = stored(sessionStorage, ACKED_KEY);
  dash.alerts = new AlertBook(Array.isArray(acked) ? acked.filter((k) => typeof k === "string") : []);
  showRules();
  ui.alertRules.addEventListener("change", rulesChanged);
  ui.alertsAckAll.addEventListener("click", () => acknowledge(null));
}
