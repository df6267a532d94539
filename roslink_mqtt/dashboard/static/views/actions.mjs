// Action panels: a goal form per action the access report opens to this user, its status, progress, feedback and
// result, and Cancel. Goals are tracked by their id; a refused or unanswered goal says so in its panel.
import { GOAL_ENDED, isLayout, progressOf, short } from "../forms.mjs";
import { isOperator } from "../model.mjs";
import { dash } from "../store.mjs";
import { addLog, el, notice, setText, show, ui } from "./dom.mjs";
import { rosForm } from "./forms.mjs";
import { becomeCommanding, publishUser } from "./session.mjs";
import { entryOf, typeLayout } from "./robot.mjs";

const GOAL_TIMEOUT_MS = 10000;
const GOALS_MAX = 64;  // goals of this page tracked at once (the oldest is forgotten)
let panels = new Map();  // action → its panel, for the robot shown

export function buildActions(robot) {
  const actions = robot.access && Array.isArray(robot.access.actions) ? robot.access.actions : [];
  panels = new Map();
  ui.actions.replaceChildren();
  for (const name of actions) {
    if (typeof name !== "string") continue;
    const entry = entryOf(robot, "actions", name);
    const t = entry && typeLayout(robot, entry.ros_type);
    const panel = el("div", { class: "action", "data-action": name });
    const h = el("h4", null, `${name} `);
    h.append(el("small", null, entry ? entry.ros_type : "(not in the robot description: goal as JSON)"));
    panel.append(h);
    const { form, row } = rosForm({ "data-action": name }, t && isLayout(t.goal) ? t.goal : undefined, "Send goal",
                                  (goal) => sendGoal(robot.name, name, goal));
    const cancel = el("button", { type: "button", class: "cancel", disabled: true }, "Cancel");
    cancel.addEventListener("click", () => cancelGoal(robot.name, name));
    row.append(cancel);
    const status = el("p", { class: "goal-status", "data-status": "idle" }, "no goal sent from this page");
    const progress = el("progress", { class: "goal-progress", max: 1, value: 0, hidden: true });
    const feedback = el("pre", { class: "goal-feedback" });
    const result = el("pre", { class: "goal-result" });
    panel.append(form, status, progress, feedback, result);
    ui.actions.append(panel);
    panels.set(name, { robot: robot.name, panel, form, cancel, status, progress, feedback, result });
    const last = robot.lastGoals.get(name);
    if (last) renderGoal(last);
  }
  show(ui.actionsBox, panels.size > 0);
}

function sendGoal(robotName, action, goal) {
  const robot = dash.robots.get(robotName);
  if (!robot) return;
  if (!dash.client || !dash.connected) { notice(`not sent (goal ${action}): not connected to the broker`); return; }
  const id = `${dash.clientId}-g${++dash.callCounter}`;
  const g = { id, robot: robotName, action, goal, status: "sending", text: "sent, waiting for the robot …",
              feedback: null, result: null, sentAt: performance.now(), timer: null };
  g.timer = setTimeout(() => {
    if (g.status !== "sending") return;
    endGoal(g, "no-answer", `no answer within ${GOAL_TIMEOUT_MS / 1000} s (robot offline, or the broker dropped ` +
            "the goal: are you allowed to send it?)");
    addLog(ui.errors, `${robotName} goal ${action}: ${g.text}`, { robot: robotName });
  }, GOAL_TIMEOUT_MS);
  dash.goals.set(id, g);
  while (dash.goals.size > GOALS_MAX) {  // forget the oldest (a goal whose result never came)
    const [oldId, old] = dash.goals.entries().next().value;
    clearTimeout(old.timer);
    dash.goals.delete(oldId);
  }
  robot.lastGoals.set(action, g);
  if (isOperator(robot)) becomeCommanding();
  publishUser(robotName, "goal", action, { id, goal, client_id: dash.clientId });
  renderGoal(g);
}

function cancelGoal(robotName, action) {
  const robot = dash.robots.get(robotName);
  const g = robot && robot.lastGoals.get(action);
  if (!g || GOAL_ENDED.has(g.status)) return;
  if (!dash.client || !dash.connected) { notice(`not sent (cancel ${action}): not connected to the broker`); return; }
  publishUser(robotName, "cancel", action, { id: g.id, client_id: dash.clientId });
  g.text = `${g.text}; cancel sent …`;
  g.cancelSent = true;
  renderGoal(g);
}

export function endGoal(g, status, text) {
  clearTimeout(g.timer);
  g.status = status;
  g.text = text;
  dash.goals.delete(g.id);
  renderGoal(g);
}

export function renderGoal(g) {
  const p = dash.selected === g.robot ? panels.get(g.action) : null;
  if (!p || p.robot !== g.robot) return;
  p.status.dataset.status = g.status;
  p.status.dataset.goalId = g.id;
  setText(p.status, `goal ${short(g.goal)}: ${g.status}${g.text ? " — " + g.text : ""}`);
  p.cancel.disabled = GOAL_ENDED.has(g.status) || g.status === "canceling" || Boolean(g.cancelSent);
  const frac = g.status === "succeeded" ? 1 : progressOf(g.goal, g.feedback);
  show(p.progress, frac !== null);
  if (frac !== null) { p.progress.value = frac; p.progress.dataset.fraction = frac.toFixed(3); }
  setText(p.feedback, g.feedback ? `feedback: ${short(g.feedback)}` : "");
  p.feedback.dataset.count = String(g.feedbackCount || 0);
  setText(p.result, g.result !== null ? `result: ${short(g.result)}` : "");
}

export function onGoalMessage(name, kind, action, body) {
  if (!body || (body.client_id && body.client_id !== dash.clientId)) return;  // unreadable, or another program's
  const g = dash.goals.get(body.id);
  if (!g || g.robot !== name || g.action !== action) return;
  if (kind === "goal_status") {
    clearTimeout(g.timer);
    if (body.status === "rejected") {
      const why = body.error || "the action server refused it";
      endGoal(g, "rejected", why);
      addLog(ui.errors, `${name} rejected goal ${action} ${short(g.goal)}: ${why}`, { robot: name });
      notice(`${name} rejected goal ${action}: ${why}`);
      return;
    }
    g.status = body.status;
    g.text = body.status === "canceling" ? "cancel accepted, waiting for the result …" : "";
  } else if (kind === "feedback") {
    g.feedback = body.feedback;
    g.feedbackCount = (g.feedbackCount || 0) + 1;
    if (g.status === "sending") g.status = "accepted";
  } else if (kind === "result") {
    g.result = body.result;
    const status = body.status;
    endGoal(g, status, body.error || "");
    if (status !== "succeeded") {
      addLog(ui.errors, `${name} goal ${action} ended ${status}${body.error ? ": " + body.error : ""}`, { robot: name });
    }
    return;
  }
  renderGoal(g);
}
