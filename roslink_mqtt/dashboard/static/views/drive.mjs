// The drive pad and keys: hold to move (a twist every TWIST_PERIOD_MS), release to stop (one zero twist; the
// robot's dead-man would stop it too). Losing focus, hiding the page or closing it stops rather than drives blind.
import { isOperator } from "../model.mjs";
import { dash } from "../store.mjs";
import { ui } from "./dom.mjs";
import { sendTwist } from "./commands.mjs";
import { stopPresence } from "./session.mjs";

const TWIST_PERIOD_MS = 100;  // 10 Hz while a drive button or key is held
const DRIVE = {  // direction → twist, as a fraction of the chosen speed (angular 3× linear, capped by the robot)
  fwd: { lx: 1, az: 0 }, back: { lx: -1, az: 0 }, left: { lx: 0, az: 3 }, right: { lx: 0, az: -3 },
};
const KEYS = { ArrowUp: "fwd", w: "fwd", W: "fwd", ArrowDown: "back", s: "back", S: "back",
               ArrowLeft: "left", a: "left", A: "left", ArrowRight: "right", d: "right", D: "right" };

function twistFor(dir) {
  const v = parseFloat(ui.speed.value) || 0.3;
  const d = DRIVE[dir];
  return { lx: d.lx * v, az: d.az * v };
}

export function startDriving(dir) {
  const name = dash.selected;
  if (!name || !DRIVE[dir]) return;
  if (dash.driveDir === dir && dash.driveRobot === name) return;
  stopDriving(false);
  dash.driveDir = dir;
  dash.driveRobot = name;
  const send = () => {
    const t = twistFor(dash.driveDir);
    if (!sendTwist(dash.driveRobot, t.lx, t.az)) stopDriving(false);
  };
  send();
  if (dash.driveDir) dash.driveTimer = setInterval(send, TWIST_PERIOD_MS);
  ui.driving.textContent = `driving ${dir}`;
  ui.driving.dataset.driving = dir;
  const b = document.querySelector(`.pad button[data-dir="${dir}"]`);
  if (b) b.classList.add("held");
}

/** Release: end the stream and send one zero twist (the dead-man would stop it too, after command_timeout). */
export function stopDriving(sendZero = true) {
  const wasDriving = Boolean(dash.driveTimer || dash.driveDir);
  if (dash.driveTimer) clearInterval(dash.driveTimer);
  dash.driveTimer = null;
  const robot = dash.driveRobot || dash.selected;
  dash.driveDir = null;
  dash.driveRobot = null;
  document.querySelectorAll(".pad button.held").forEach((b) => b.classList.remove("held"));
  ui.driving.textContent = "";
  ui.driving.dataset.driving = "no";
  if (sendZero && (wasDriving || dash.commanding) && robot && dash.connected && isOperator(dash.robots.get(robot))) {
    sendTwist(robot, 0, 0);
  }
}

/** While the robot's motion is blocked (emergency stop, disarm) the pad's motion buttons and keys do nothing: the
 * robot would refuse every twist; only Resume (arm) unblocks it. */
export function blockPad(blocked) {
  ui.controls.dataset.blocked = blocked ? "yes" : "no";
  for (const b of document.querySelectorAll(".pad button")) if (b.dataset.dir !== "stop") b.disabled = blocked;
  if (blocked && dash.driveDir) stopDriving(false);
}

function padDown(ev) {
  const dir = ev.currentTarget.dataset.dir;
  ev.preventDefault();
  if (dir === "stop") { stopDriving(true); return; }
  startDriving(dir);
}

function padUp() { if (dash.driveDir && dash.heldKeys.size === 0) stopDriving(true); }

const typing = (t) => t && ((t.tagName === "INPUT" && t.type !== "range" && t.type !== "checkbox") ||
                            t.tagName === "TEXTAREA" || t.tagName === "SELECT" || t.isContentEditable);

export function installDrive() {
  for (const b of document.querySelectorAll(".pad button")) {
    b.addEventListener("pointerdown", padDown);
    b.addEventListener("pointerup", padUp);
    b.addEventListener("pointerleave", padUp);
    b.addEventListener("pointercancel", padUp);
    b.addEventListener("contextmenu", (e) => e.preventDefault());
  }
  document.addEventListener("keydown", (ev) => {
    // typing in a form drives nothing (text boxes and JSON areas of the service, goal and parameter forms)
    if (typing(ev.target) || ui.controls.hidden || ui.robotView.hidden) return;
    if (ev.key === " ") { ev.preventDefault(); dash.heldKeys.clear(); stopDriving(true); return; }
    const dir = KEYS[ev.key];
    if (!dir || ui.controls.dataset.blocked === "yes") return;
    ev.preventDefault();
    dash.heldKeys.add(ev.key);
    startDriving(dir);
  });
  document.addEventListener("keyup", (ev) => {
    if (!KEYS[ev.key]) return;
    dash.heldKeys.delete(ev.key);
    if (dash.heldKeys.size === 0 && dash.driveDir) stopDriving(true);
  });
  window.addEventListener("blur", () => { dash.heldKeys.clear(); if (dash.driveDir) stopDriving(true); });
  document.addEventListener("visibilitychange", () => {
    if (document.hidden && dash.driveDir) { dash.heldKeys.clear(); stopDriving(true); }
  });
  // Closing the tab: stop and sign off if the socket still carries it; the last-will covers the rest.
  window.addEventListener("pagehide", () => {
    if (dash.driveDir) stopDriving(true);
    stopPresence(true);
  });
  ui.speed.addEventListener("input", () => { ui.speedOut.textContent = `${parseFloat(ui.speed.value).toFixed(2)} m/s`; });
}
