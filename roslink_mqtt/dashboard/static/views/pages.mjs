// Two views, one at a time: the fleet overview and one robot's view, switched by the tabs in the header (the
// Fleet tab says how many alerts wait). The first robot seen opens its view; a click on a robot anywhere opens it.
import { dash, selectedRobot } from "../store.mjs";
import { setText, show, ui } from "./dom.mjs";
import { markDirty } from "./plot.mjs";
import { drawFleetMap } from "./fleet.mjs";

/** "fleet" or "robot" (the robot view needs a selected robot; without one the fleet view shows). */
export function showPage(page) {
  dash.page = page;
  renderTabs();
  markDirty();
  drawFleetMap();
}

export function renderTabs() {
  const robot = selectedRobot();
  const onRobot = dash.page === "robot" && Boolean(robot);
  show(ui.fleetView, !onRobot);
  show(ui.robotView, onRobot);
  show(ui.tabs, dash.connected || dash.everConnected);
  ui.tabFleet.setAttribute("aria-pressed", String(!onRobot));
  ui.tabRobot.setAttribute("aria-pressed", String(onRobot));
  show(ui.tabRobot, Boolean(robot));
  setText(ui.tabRobot, robot ? robot.name : "");
  const pending = dash.alerts.pending();
  setText(ui.fleetBadge, pending ? String(pending) : "");
  ui.fleetBadge.dataset.pending = pending ? "yes" : "no";
  ui.tabFleet.setAttribute("aria-label", pending ? `Fleet, ${pending} alerts waiting` : "Fleet");
}
