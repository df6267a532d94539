// What arrives from the broker, by topic kind (topics.mjs parses, decode.mjs reads): heartbeats and state for
// every robot (counted; the selected robot's parsed and drawn), and the replies addressed to this user.
import { KINDS, message, read, readDescription } from "../decode.mjs";
import { leafOf, paramEventsNode } from "../topics.mjs";
import { addGps, addLink, addPose, addStatus, count, newRobot } from "../model.mjs";
import { dash } from "../store.mjs";
import { addLog, notice, ui } from "./dom.mjs";
import { noteStopAck, onCallReply } from "./commands.mjs";
import { addFleetRow, drawFleetMap, removeFleetRow, updateRow } from "./fleet.mjs";
import { buildControls, drawGps, entryOf, notDecoded, presenceIfNeeded, selectRobot, showControl, showImage,
         showImageBytes, showUplink, updateBanner, updatePose } from "./robot.mjs";
import { markDirty } from "./plot.mjs";
import { endGoal, onGoalMessage, renderGoal } from "./actions.mjs";
import { onParamEvent, onParamReply, refuseParamRequest } from "./params.mjs";
import { endSnapshot, onSnapshotChunk } from "./snapshot.mjs";
import { isWatched, onVideoFrame } from "./video.mjs";
import { onErrorAlert, onFailsafeAlert } from "./alerts.mjs";

const decoder = new TextDecoder();
const ACK_RESULTS = ["accepted", "rejected", "failed", "failsafe"];
const FAILSAFE = 3;

function robotFor(name) {
  let robot = dash.robots.get(name);
  if (!robot) {
    robot = newRobot(name);
    dash.robots.set(name, robot);
    addFleetRow(robot);
  }
  return robot;
}

export function onMessage(t, payload) {
  const p = dash.tree.parse(t);
  if (!p || p.kind === KINDS.operator) return;
  const name = p.robot;
  if (p.kind === KINDS.heartbeat) { onHeartbeat(name, payload); return; }
  if (p.kind === KINDS.state) {
    // the retained description may come before the heartbeat: keep it; other state counts from the heartbeat on
    const robot = p.name === "description" && payload.length ? robotFor(name) : dash.robots.get(name);
    if (robot) onState(robot, p.name, payload);
  } else if (p.kind === KINDS.to && p.user === dash.user) {
    onPersonal(name, p, payload);
  }
}

function onHeartbeat(name, payload) {
  if (!payload.length) {  // a cleared retained heartbeat: the robot left the fleet
    removeFleetRow(dash.robots.get(name));
    dash.robots.delete(name);
    if (dash.selected === name) selectRobot(null);
    return;
  }
  const hb = message("heartbeat", payload);
  if (!hb) return;
  const robot = robotFor(name);
  robot.hb = hb;
  robot.hbAt = performance.now();
  count(robot, "heartbeat", payload, robot.hbAt);
  updateRow(robot, robot.hbAt);
  if (!dash.selected) selectRobot(name);
  else if (dash.selected === name) updateBanner(robot);
}

function onState(robot, name, payload) {
  const now = performance.now();
  count(robot, name, payload, now);
  if (name === "description") {
    const raw = decoder.decode(payload);
    if (raw === robot.descRaw) return;  // the same retained description again (a reconnect)
    robot.descRaw = raw;
    robot.description = raw ? readDescription(payload) : null;
    presenceIfNeeded(robot);
    if (dash.selected === robot.name) buildControls(robot);
    return;
  }
  const paramNode = paramEventsNode(name);
  if (paramNode !== null) { onParamEvent(robot, paramNode, payload); return; }
  // every robot: what the fleet overview, the attention list and the alerts need
  if (name === "robot_status") {
    const status = message("robot_status", payload);
    if (status) addStatus(robot, status, now);
    return;
  }
  if (name === "control") {  // who drives (docs/protocol.md, "control state")
    robot.control = read("control_state", payload);
    if (dash.selected === robot.name) showControl(robot);
    return;
  }
  if (name === "link") {  // the bridge's uplink report (docs/protocol.md, "link report")
    const link = read("link_report", payload);
    if (link) addLink(robot, link, now);
    if (dash.selected === robot.name) showUplink(robot);
    return;
  }
  if (name === "global_motion") {  // every robot's position: the fleet map and each robot's trail
    const m = message("global_motion", payload);
    if (!m) return;
    addPose(robot, m, now);
    if (dash.selected === robot.name) {  // another robot's move does not redraw this one's plot
      updatePose(robot);
      markDirty();
    }
    drawFleetMap();  // at most five times a second, and only while shown
    return;
  }
  if (name === "gps_raw_info") {
    const g = message("gps_raw_info", payload);
    if (g && g.fix_type >= 2) {
      addGps(robot, g);
      if (dash.selected === robot.name) drawGps(robot);
    }
    return;
  }
  if (name === "ack") {
    const a = message("ack", payload);
    if (!a) return;
    if (dash.stopRound) noteStopAck(robot, a);  // STOP ALL waits for every robot's acknowledgement
    if (a.result === FAILSAFE) {
      robot.failsafe = { at: now, text: a.text || "failsafe stop" };
      onFailsafeAlert(robot, a.text || "failsafe stop", now);
    }
    if (dash.selected === robot.name) {
      const result = ACK_RESULTS[a.result] || `result ${a.result}`;
      addLog(ui.acks, `${result}: command ${a.command} seq ${a.command_sequence} ${a.text || ""}`, { result });
    }
    return;
  }
  if (isWatched(robot.name, name)) { onVideoFrame(payload); return; }
  if (dash.selected !== robot.name) return;  // other robots' cameras and scans: counted, not parsed
  const encoding = (entryOf(robot, "state", name) || {}).encoding;
  if (encoding === "raw") { showImageBytes(robot, name, payload); return; }
  if (encoding && encoding !== "json") { notDecoded(robot, name, encoding); return; }
  if (name === "range_finder_data") {
    const s = message("range_finder_data", payload);
    if (s) { robot.scan = s; markDirty(); }
  } else if (name === "image") {
    const im = message("image", payload);
    if (im) showImage(im);
  }
}

function onPersonal(name, p, payload) {
  const kind = p.verb;
  if (kind === "access") {
    const robot = robotFor(name);  // the report can come before the heartbeat: kept for its first heartbeat
    robot.access = payload.length ? read("access_report", payload) : null;
    presenceIfNeeded(robot);
    if (dash.selected === name) buildControls(robot);
    updateRow(robot, performance.now());
  } else if (kind === "notice") {  // carried out, but changed (a twist clamped to the robot's limits)
    const n = read("notice", payload);
    if (!n || (n.client_id && n.client_id !== dash.clientId)) return;
    notice(`${name}: ${n.notice}`);
  } else if (kind === "error") {
    onError(name, read("error_report", payload));
  } else if (kind === "reply") {
    onCallReply(name, read("call_reply", payload));
  } else if (kind === "goal_status" || kind === "feedback" || kind === "result") {
    onGoalMessage(name, kind, p.name, read({ goal_status: "goal_status", feedback: "goal_feedback",
                                              result: "goal_result" }[kind], payload));
  } else if (kind === "param_reply") {
    onParamReply(name, read("parameter_reply", payload));
  } else if (kind === "snapshot_data") {
    onSnapshotChunk(name, p.name, payload);
  }
}

function onError(name, e) {
  if (!e) { addLog(ui.errors, `${name}: unreadable error report`); return; }
  // reports naming another program of ours are theirs; reports naming none may be ours: shown
  if (e.client_id && e.client_id !== dash.clientId) return;
  const about = dash.tree.parse(e.topic);
  const where = about && about.kind === KINDS.from ? leafOf(about) : e.topic;
  const text = `${name} refused ${where}: ${e.error}`;
  addLog(ui.errors, text, { robot: name });
  notice(text);
  const robot = dash.robots.get(name);
  if (robot) robot.lastError = { at: performance.now(), text };
  onErrorAlert(name, text, performance.now());
  // a refused goal, cancel or parameter request: said in its panel too (by the request's id)
  const goal = e.id !== null && dash.goals.get(e.id);
  if (goal && goal.robot === name) {
    if (about && about.verb === "cancel") {
      goal.cancelSent = false;
      goal.text = `cancel refused: ${e.error}`;
      renderGoal(goal);
    } else endGoal(goal, "refused", e.error);
  }
  const snap = e.id !== null && dash.snapshots.get(e.id);
  if (snap && snap.robot === name && !snap.done) endSnapshot(snap, "refused", `refused: ${e.error}`);
  if (e.id !== null) refuseParamRequest(name, e.id, `refused: ${e.error}`);
}
