// Every command the page sends goes through here: refused at once (and said so) when the page knows the broker
// or the robot would drop it, so nothing vanishes silently.
import { heldByOther, driverText, isOperator, mayStop, presenceOf } from "../model.mjs";
import { dash, nextSeq, selectedRobot } from "../store.mjs";
import { addLog, notice, ui } from "./dom.mjs";
import { becomeCommanding, publishUser } from "./session.mjs";
import { stopDriving } from "./drive.mjs";

const CALL_TIMEOUT_MS = 10000;
const STOP_ACK_MS = 1000;  // STOP ALL says which robots acknowledged within this
export const ESTOP_ID = 108;

function refuse(robotName, why) {
  addLog(ui.errors, why, { robot: robotName });
  notice(why);
  return false;
}

export function command(robotName, name, payload, messageId) {
  const robot = dash.robots.get(robotName);
  if (!dash.client || !dash.connected) { notice(`not sent (${name}): not connected to the broker`); return false; }
  const estop = name === "emergency_stop";
  if (!isOperator(robot) && !(estop && mayStop(robot))) {
    return refuse(robotName, `not sent (${name}): ${dash.user} is ` +
      `${robot && robot.access ? "a " + robot.access.role : "not an operator"} of ${robotName}; the broker would drop it`);
  }
  if (!estop && heldByOther(robot, dash.user)) {  // the robot would refuse it: say who drives at once
    return refuse(robotName, `not sent (${name}): ${robotName} is driven by ${driverText(robot)}; take over to drive it`);
  }
  if (!estop && robot && robot.control && robot.control.holder === null) claimControl(robotName, "claim");
  if (isOperator(robot)) becomeCommanding();
  const body = { message_id: messageId, sequence_number: nextSeq(), client_id: dash.clientId, payload };
  publishUser(robotName, "cmd", name, body, name === "twist" ? 0 : 1);
  return true;
}

export const sendTwist = (robotName, lx, az) => command(robotName, "twist", { lx, ly: 0, lz: 0, ax: 0, ay: 0, az }, 100);

/** control/claim (the drive pad claims a free robot before its first twist) and control/take_over (confirmed). */
export function claimControl(robotName, op) {
  if (!dash.client || !dash.connected) return;
  becomeCommanding();
  publishUser(robotName, "control", op, { client_id: dash.clientId });
}

// explicit claim and release: hold control before driving (nobody else's commands move the robot meanwhile), and
// give it back when done (the lease also ends with this page's presence)
export function claimSelected() { if (dash.selected) claimControl(dash.selected, "claim"); }

export function releaseSelected() {
  if (!dash.client || !dash.connected || !dash.selected) return;
  publishUser(dash.selected, "control", "release", { client_id: dash.clientId });
}

export function takeOver() {
  const robot = selectedRobot();
  if (!robot || !heldByOther(robot, dash.user)) return;
  if (!window.confirm(`Take control of ${robot.name} from ${robot.control.holder}? The robot stops, and ` +
                      `${robot.control.holder} is told.`)) return;
  claimControl(robot.name, "take_over");
  addLog(ui.acks, `asked to take over ${robot.name} from ${robot.control.holder}`);
}

/** STOP ALL: an emergency stop to every robot this login may stop, then per robot whether its bridge acknowledged
 * it (state/ack, command 108, our sequence number) within STOP_ACK_MS. */
export function stopAll() {
  stopDriving(false);
  const round = { sent: new Map(), acked: new Map() };
  dash.stopRound = round;
  for (const robot of dash.robots.values()) {
    if (!mayStop(robot) || presenceOf(robot, performance.now()) !== "online") continue;
    const seq = nextSeq();
    publishUser(robot.name, "cmd", "emergency_stop", { message_id: ESTOP_ID, sequence_number: seq,
      client_id: dash.clientId, payload: { reason: `STOP ALL (dashboard, ${dash.user})` } });
    round.sent.set(robot.name, { seq, at: performance.now() });
  }
  addLog(ui.acks, `STOP ALL sent to ${[...round.sent.keys()].join(", ") || "no robot"}`);
  setTimeout(() => {
    const lines = [...round.sent.keys()].map((name) => round.acked.has(name)
      ? `${name} stopped (acknowledged in ${round.acked.get(name)} ms)` : `${name} NOT ACKNOWLEDGED — stop it another way`);
    for (const line of lines) addLog(ui.acks, line, { stop: round.acked.size === round.sent.size ? "all" : "missing" });
    notice(lines.join("; "));
    ui.stopAll.dataset.result = round.acked.size === round.sent.size ? "acknowledged" : "missing";
  }, STOP_ACK_MS);
}

export function noteStopAck(robot, a) {
  const round = dash.stopRound;
  const sent = round && round.sent.get(robot.name);
  if (sent && a.command === ESTOP_ID && a.command_sequence === sent.seq && a.result === 0 && !round.acked.has(robot.name)) {
    round.acked.set(robot.name, Math.round(performance.now() - sent.at));
  }
}

export function emergencyStop() {
  const name = dash.selected;
  if (!name) return;
  stopDriving(false);
  if (command(name, "emergency_stop", { reason: `emergency stop button (dashboard, ${dash.user})` }, ESTOP_ID)) {
    addLog(ui.acks, `sent emergency stop to ${name}`);
  }
}

export function arm() {
  const name = dash.selected;
  if (name && command(name, "arm", {}, 104)) addLog(ui.acks, `sent arm (resume) to ${name}`);
}

export function callService(robotName, service, args) {
  if (!dash.client || !dash.connected) { notice(`not called (${service}): not connected`); return; }
  const id = `${dash.clientId}-${++dash.callCounter}`;
  const timer = setTimeout(() => {
    dash.pendingCalls.delete(id);
    const text = `${service}: no reply within ${CALL_TIMEOUT_MS / 1000} s (robot offline, or the broker dropped the call)`;
    ui.serviceResult.textContent = text;
    ui.serviceResult.dataset.result = "timeout";
    addLog(ui.errors, `${robotName} ${text}`, { robot: robotName });
  }, CALL_TIMEOUT_MS);
  dash.pendingCalls.set(id, { service, timer });
  ui.serviceResult.textContent = `${service}: calling …`;
  ui.serviceResult.dataset.result = "pending";
  publishUser(robotName, "call", service, { id, args, client_id: dash.clientId });
}

export function onCallReply(name, r) {
  if (!r || !dash.pendingCalls.has(r.id)) return;
  const call = dash.pendingCalls.get(r.id);
  clearTimeout(call.timer);
  dash.pendingCalls.delete(r.id);
  const text = r.result ? `${call.service}: ${JSON.stringify(r.values)}` : `${call.service} failed: ${r.error}`;
  ui.serviceResult.textContent = text;
  ui.serviceResult.dataset.result = r.result ? "ok" : "failed";
  if (!r.result) addLog(ui.errors, `${name} call ${call.service}: ${r.error}`, { robot: name });
}

// for the browser tests (and the curious): the same paths the buttons take
dash.command = command;
dash.sendTwist = sendTwist;
dash.claimControl = claimControl;
dash.callService = callService;
