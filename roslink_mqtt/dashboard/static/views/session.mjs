// Logging in and out, and this page's operator presence. MQTT.js (window.mqtt) does all MQTT: the browser
// connects to the broker's WebSocket listener with the user's own login, so the broker's ACL is the only access
// path. Contracts: docs/protocol.md.
import { CONNACK, LOGIN_WAIT_MS } from "../decode.mjs";
import { TopicTree } from "../topics.mjs";
import { dash } from "../store.mjs";
import { notice, randomHex, show, ui } from "./dom.mjs";
import { onMessage } from "./incoming.mjs";
import { stopDriving } from "./drive.mjs";
import { clearRobots } from "./robot.mjs";

const PRESENCE_PERIOD_MS = 500;  // operator heartbeat; robots drop an operator after 1.5 s without one
const DEFAULT_CONFIG = { ws_port: 8083, ws_url: "", prefix: "roslink", tiles: "", tiles_attribution: "" };

export async function loadConfig() {
  try {
    const r = await fetch("config.json", { cache: "no-store" });
    dash.config = { ...DEFAULT_CONFIG, ...(await r.json()) };
  } catch (e) {
    dash.config = { ...DEFAULT_CONFIG };
  }
  dash.prefix = dash.config.prefix || "roslink";
  dash.tree = new TopicTree(dash.prefix);
  const host = location.hostname.includes(":") ? `[${location.hostname}]` : (location.hostname || "127.0.0.1");
  ui.wsUrl.value = dash.config.ws_url || `ws://${host}:${dash.config.ws_port}`;
}

function loginError(text) {
  ui.loginError.textContent = text;
  show(ui.loginError, Boolean(text));
}

function setConn(state, text) {
  ui.conn.dataset.state = state;
  ui.conn.textContent = text;
}

export function connect(ev) {
  if (ev) ev.preventDefault();
  if (typeof window.mqtt === "undefined") {
    loginError("MQTT.js did not load (vendor/mqtt.min.js): run `make install` where the dashboard is served");
    return;
  }
  const url = ui.wsUrl.value.trim(), user = ui.username.value.trim(), password = ui.password.value;
  if (!url || !user) { loginError("enter the broker URL and your username"); return; }
  loginError("");
  closeClient();
  dash.user = user;
  dash.clientId = `${user}-web-${randomHex(8)}`;
  ui.connect.disabled = true;
  setConn("connecting", `connecting to ${url} …`);
  let client;
  try {
    client = window.mqtt.connect(url, {
      username: user, password, clientId: dash.clientId, protocolVersion: 4, clean: true, keepalive: 5,
      // no retry until a first login succeeded: a refused password must not become a loop of attempts
      // connectTimeout: longer than the broker's login throttle may hold its answer after failed logins from
      // this address (a refusal heard late beats "connack timeout")
      reconnectPeriod: 0, connectTimeout: LOGIN_WAIT_MS, resubscribe: true,
      // operator presence: when this page vanishes without a word, the broker clears its heartbeat
      will: { topic: dash.tree.operator(user, dash.clientId), payload: "", qos: 1, retain: true },
    });
  } catch (e) {
    ui.connect.disabled = false;
    loginError(`cannot connect: ${e.message}`);
    setConn("disconnected", "not connected");
    return;
  }
  dash.client = client;
  const current = () => dash.client === client;  // events of a client replaced by a new login are ignored
  // a slow answer is most often the broker's login throttle (failed logins from this address): say so
  setTimeout(() => {
    if (current() && !dash.everConnected && ui.conn.dataset.state === "connecting") {
      setConn("connecting", `connecting to ${url} … (waiting for the broker to check the login: it slows ` +
              "logins down after failed ones from this address)");
    }
  }, 3000);
  client.on("connect", () => { if (current()) onConnect(); });
  client.on("message", (t, payload) => { if (current()) onMessage(t, payload); });
  client.on("error", (err) => {
    if (!current()) return;
    const text = CONNACK[err && err.code] || (err && /connack timeout/i.test(err.message)
      ? `no answer from the broker within ${LOGIN_WAIT_MS / 1000} s`
      : `connection error: ${err && err.message ? err.message : err}`);
    if (err && CONNACK[err.code]) {  // a refused CONNACK: say why and stop trying
      client.options.reconnectPeriod = 0;
      client.end(true);
      if (dash.everConnected) {
        notice(text);
        setConn("refused", "login refused");
      } else {
        loginError(text);
        setConn("refused", "not connected");
        ui.connect.disabled = false;
      }
      return;
    }
    if (dash.connected) notice(text);
    else loginError(text);
  });
  client.on("close", () => {
    if (!current()) return;
    const was = dash.connected;
    dash.connected = false;
    stopDriving(false);
    if (!dash.everConnected) {
      if (ui.loginError.hidden) loginError(`cannot reach the broker at ${url} (the WebSocket closed)`);
      setConn("disconnected", "not connected");
      ui.connect.disabled = false;
    } else if (was) {
      setConn("lost", "connection lost — reconnecting");
      notice("connection to the broker lost: reconnecting (the robot stops on its own within its failsafe bound)");
    }
  });
  client.on("reconnect", () => { if (current()) setConn("connecting", "reconnecting …"); });
}

function onConnect() {
  const client = dash.client;
  dash.connected = true;
  dash.everConnected = true;
  client.options.reconnectPeriod = 2000;  // logged in once: from now on a lost link is retried
  ui.connect.disabled = false;
  setConn("connected", `connected to ${ui.wsUrl.value.trim()}`);
  notice("");
  ui.whoami.textContent = `${dash.user} (${dash.clientId})`;
  ui.password.value = "";
  show(ui.login, false);
  show(ui.main, true);
  show(ui.logout, true);
  const t = dash.tree;
  const filters = [t.heartbeatFilter(), t.stateFilter(), t.toUserFilter("+", dash.user)];
  client.subscribe(filters, { qos: 1 }, (err, granted) => {
    if (err) { notice(`subscribe failed: ${err.message}`); return; }
    const refused = (granted || []).filter((g) => g.qos === 128).map((g) => g.topic);
    if (refused.length) notice(`the broker refused to let you read ${refused.join(", ")} (no grant?)`);
  });
  if (dash.operatorAnywhere) startPresence();
}

function closeClient() {
  stopDriving(true);
  stopPresence(true);
  if (dash.client) {
    dash.client.options.reconnectPeriod = 0;
    dash.client.end(false);  // not forced: the zero twist and the sign-off above go out before DISCONNECT
  }
  dash.client = null;
  dash.connected = false;
  dash.everConnected = false;
}

export function logout() {
  closeClient();
  clearRobots();
  dash.operatorAnywhere = false;
  dash.commanding = false;
  show(ui.main, false);
  show(ui.login, true);
  show(ui.logout, false);
  show(ui.estop, false);
  ui.whoami.textContent = "";
  notice("");
  setConn("disconnected", "not connected");
}

// ------------------------------------------------------------------------------------------ operator presence
function presenceTopic() { return dash.tree.operator(dash.user, dash.clientId); }

function heartbeatBody(status) {
  dash.presenceSeq = (dash.presenceSeq + 1) % 4294967296;
  return JSON.stringify({ message_id: 0, sequence_number: dash.presenceSeq,
    payload: { type: 0, name: dash.clientId, system_status: status, owner_id: dash.user, mode: 0 } });
}

/** One presence heartbeat: 4 = this client commands (its leaving stops the robot it drove), 3 = it only watches. */
export function beat() {
  if (dash.client && dash.connected) {
    dash.client.publish(presenceTopic(), heartbeatBody(dash.commanding ? 4 : 3), { qos: 0, retain: true });
  }
}

/** From now on this client's leaving stops the robot it commands: say so before the first command. */
export function becomeCommanding() {
  if (dash.commanding) return;
  dash.commanding = true;
  beat();
}

export function startPresence() {
  if (dash.presenceTimer) return;
  beat();
  dash.presenceTimer = setInterval(beat, PRESENCE_PERIOD_MS);
}

export function stopPresence(signOff) {
  if (dash.presenceTimer) clearInterval(dash.presenceTimer);
  dash.presenceTimer = null;
  if (signOff && dash.client && dash.connected && dash.operatorAnywhere) {
    // a clean sign-off (status 7), then the clear the last-will would publish: the robot stops all the same
    dash.client.publish(presenceTopic(), heartbeatBody(7), { qos: 1 });
    dash.client.publish(presenceTopic(), "", { qos: 1, retain: true });
  }
}

/** Publish a body to one of this user's topics of a robot (from/<user>/<verb>[/<name>]). */
export function publishUser(robotName, verb, name, body, qos = 1) {
  dash.client.publish(dash.tree.userTopic(robotName, dash.user, verb, name), JSON.stringify(body), { qos });
}
