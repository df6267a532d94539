// roslink-mqtt dashboard: native ES modules, no build step. The pure modules (decode, model, geometry, alerts,
// forms, topics, body, message) hold what the page knows and are tested under node (tests/js); views/ draws it
// and takes the user's input; store.mjs holds the state. Contracts: docs/protocol.md.
import { mayStop, updateRates } from "./model.mjs";
import { dash, selectedRobot } from "./store.mjs";
import { show, ui } from "./views/dom.mjs";
import { connect, loadConfig, logout } from "./views/session.mjs";
import { arm, claimSelected, emergencyStop, releaseSelected, stopAll, takeOver } from "./views/commands.mjs";
import { installDrive } from "./views/drive.mjs";
import { renderRates, showControl, updateBanner } from "./views/robot.mjs";
import { installPlot, markDirty } from "./views/plot.mjs";
import { drawFleetMap, installFleet, updateAttention, updateRow } from "./views/fleet.mjs";
import { installCharts, updateCharts } from "./views/charts.mjs";
import { evaluateAlerts, installAlerts } from "./views/alerts.mjs";
import { takeSnapshot } from "./views/snapshot.mjs";
import { renderTabs, showPage } from "./views/pages.mjs";
import { toggleWatch } from "./views/video.mjs";

installDrive();
installPlot();
installFleet();
installCharts();
installAlerts();
ui.estop.addEventListener("click", emergencyStop);
ui.snapshot.addEventListener("click", takeSnapshot);
ui.videoWatch.addEventListener("click", toggleWatch);
ui.stopAll.addEventListener("click", stopAll);
ui.takeOver.addEventListener("click", takeOver);
ui.claim.addEventListener("click", claimSelected);
ui.release.addEventListener("click", releaseSelected);
ui.arm.addEventListener("click", arm);
ui.loginForm.addEventListener("submit", connect);
ui.logout.addEventListener("click", logout);
ui.tabFleet.addEventListener("click", () => showPage("fleet"));
ui.tabRobot.addEventListener("click", () => showPage("robot"));

// presence, banners, attention and alerts: twice a second; rates, charts: once a second
setInterval(() => {
  const now = performance.now();
  for (const r of dash.robots.values()) updateRow(r, now);
  const robot = selectedRobot();
  if (robot) { updateBanner(robot); showControl(robot); }
  show(ui.stopAll, dash.connected && [...dash.robots.values()].some(mayStop));
  show(ui.fleetEmpty, dash.robots.size === 0);
  updateAttention(now);
  evaluateAlerts(now);
  renderTabs(now);
  drawFleetMap();
}, 500);
setInterval(() => {
  const now = performance.now();
  updateRates(dash.robots.values(), now);
  renderRates(now);
  updateCharts();
}, 1000);
markDirty();
loadConfig();
