// roslink-mqtt dashboard: plain JavaScript, no build step. MQTT.js (window.mqtt) does all MQTT.
//
// The browser connects to the broker's WebSocket listener with the user's own login, so the broker's ACL
// is the only access path: this page shows what the broker lets the user read, and its controls come from
// the robot's access report (retained on to/<user>/access), so a viewer gets none. Contracts: docs/protocol.md.
"use strict";

(() => {
  // From the protocol's declarations (protocol.js, generated) and read as the SDK reads them (body.js)
  const { STALE_AFTER_MS, STATUS, MODES, LOGIN_WAIT_MS } = window.ROSLINK.constants;
  const BODIES = window.ROSLINK.bodies;
  // one body, named as in docs/protocol.md ("control state" → control_state): its declared fields, or null
  const read = (name, payload) => window.roslinkBody.readBody(BODIES[name], parse(payload));
  // one ROSLink message (heartbeat, global_motion, ack …), read as the SDK decodes it (message.js): its payload, or null
  const { envelope: ENVELOPE, specs: MESSAGES } = window.ROSLINK.messages;
  const message = (name, payload) => window.roslinkMessage.readMessage(MESSAGES[name], parse(payload), ENVELOPE);
  const { TopicTree, leafOf, paramEventsNode } = window.roslinkTopics;  // topics.py's grammar (topics.js)
  const KINDS = window.ROSLINK.topics.kinds;  // what a parsed topic is: heartbeat, state, from, to, operator
  let tree = new TopicTree("roslink");  // the broker's prefix, once config.json has said it
  const PRESENCE_PERIOD_MS = 500;    // operator heartbeat; robots drop an operator after 1.5 s without one
  const TWIST_PERIOD_MS = 100;       // 10 Hz while a drive button or key is held
  const TRAIL_MAX = 600;             // points kept per robot (60 s at 10 Hz)
  const GPS_MAX = 300;
  const RECENT_MAX = 30;             // poses kept to place each scan where it was taken (3 s at 10 Hz)
  const LOG_MAX = 30;                // list items kept in the error and ack lists
  const CALL_TIMEOUT_MS = 10000;
  // a refused CONNACK's return code → why, worded as the CLI and the SDK word it (roslink_mqtt/mqtt.py)
  const CONNACK = Object.fromEntries(Object.entries(window.ROSLINK.constants.CONNACK)
    .map(([code, why]) => [code, `login refused: ${why}`]));
  const DRIVE = {  // direction → twist, as a fraction of the chosen speed (angular 3× linear, capped by the robot)
    fwd: { lx: 1, az: 0 }, back: { lx: -1, az: 0 }, left: { lx: 0, az: 3 }, right: { lx: 0, az: -3 },
  };
  const KEYS = { ArrowUp: "fwd", w: "fwd", W: "fwd", ArrowDown: "back", s: "back", S: "back",
                 ArrowLeft: "left", a: "left", A: "left", ArrowRight: "right", d: "right", D: "right" };

  const $ = (id) => document.getElementById(id);
  const ui = {};
  for (const id of ["conn", "whoami", "logout", "estop", "stop-all", "driver", "take-over", "claim", "release", "notice", "login", "login-form", "ws-url", "username",
                    "password", "connect", "login-error", "main", "fleet", "fleet-empty", "robot-view", "robot-title",
                    "robot-banner", "plot", "pose", "waypoint-label", "waypoint-mode", "controls", "speed",
                    "speed-out", "arm", "driving", "viewer-note", "services-box", "services", "service-result",
                    "actions-box", "actions", "params-box", "params", "snapshot-box", "snapshot", "snapshot-status",
                    "plot-zoom-in", "plot-zoom-out", "plot-follow", "plot-reset", "inspector", "inspector-head",
                    "inspector-body",
                    "rates", "uplink", "gps-box", "gps", "gps-text", "camera-box", "camera", "errors", "acks"]) {
    ui[id.replace(/-(\w)/g, (_, c) => c.toUpperCase())] = $(id);
  }

  // Everything the page knows. Exposed as window.dashboard for the browser tests and for curious users
  // (publishing through it changes nothing: the broker checks every PUBLISH against the login's grants).
  const dash = {
    client: null, user: "", clientId: "", prefix: "roslink", config: null, connected: false, everConnected: false,
    robots: new Map(), selected: null, operatorAnywhere: false, commanding: false,
    presenceSeq: 0, lastSeq: 0, presenceTimer: null, driveTimer: null, driveDir: null, driveRobot: null,
    heldKeys: new Set(), pendingCalls: new Map(), callCounter: 0, waypoint: null,
    goals: new Map(), pendingParams: new Map(), builtFor: null,
    snapshots: new Map(),  // id → a snapshot being received (chunks by index); the finished one stays as .done
    cameraUrl: null, undecoded: new Set(),  // the shown raw image's blob URL; states said to be undecodable
  };
  window.dashboard = dash;
  let dirty = false;                         // the plot needs redrawing (at most once per animation frame)
  // plot: half the shown width in metres, its centre; `manual` once the user zoomed or panned (the plot then stops
  // growing by itself), `follow`: centred on the robot at every frame
  const view = { half: 6, cx: 0, cy: 0, manual: false, follow: false };
  dash.view = view;

  function newRobot(name) {
    return { name, hb: null, hbAt: 0, status: null, access: undefined, rates: new Map(), pose: null, recent: [],
             trail: [], scan: null, gps: [], gpsFix: null, poses: 0, row: null, cells: null,
             description: null, descRaw: "", actionPanels: new Map(), paramPanels: new Map(), lastGoals: new Map(),
             blocked: false };
  }

  // ---------------------------------------------------------------------------------------------- helpers
  function show(el, on) { el.hidden = !on; }
  function notice(text) {
    ui.notice.textContent = text;
    show(ui.notice, Boolean(text));
  }
  function stamp() { return new Date().toLocaleTimeString(); }
  // A bridge's session is the time it started (s since the epoch, 32 bits): shown as a time of day, not a number
  function sessionText(session) {
    return session > 1e9 ? `since ${new Date(session * 1000).toLocaleTimeString()}` : String(session);
  }
  function addLog(list, text, attrs) {
    const li = document.createElement("li");
    li.textContent = `${stamp()}  ${text}`;
    if (attrs) for (const [k, v] of Object.entries(attrs)) li.dataset[k] = v;
    list.prepend(li);
    while (list.childElementCount > LOG_MAX) list.lastElementChild.remove();
  }
  function randomHex(bytes) {
    const a = new Uint8Array(bytes);
    crypto.getRandomValues(a);
    return Array.from(a, (b) => b.toString(16).padStart(2, "0")).join("");
  }
  function parse(payload) {
    try { return JSON.parse(new TextDecoder().decode(payload)); } catch (e) { return undefined; }
  }
  // A command's sequence number: the wall clock in ms, or the previous + 1 when the clock has not moved on, so
  // this page and the user's other programs share one timeline per command topic (docs/protocol.md).
  function nextSeq() {
    const now = Date.now() % 4294967296;
    const ahead = (now - dash.lastSeq + 4294967296) % 4294967296;
    dash.lastSeq = ahead > 0 && ahead < 2147483648 ? now : (dash.lastSeq + 1) % 4294967296;
    return dash.lastSeq;
  }
  function fmt(v, digits) { return typeof v === "number" && Number.isFinite(v) ? v.toFixed(digits) : "–"; }
  function presenceTopic() { return tree.operator(dash.user, dash.clientId); }

  // ------------------------------------------------------------------------------------------- login
  async function loadConfig() {
    try {
      const r = await fetch("config.json", { cache: "no-store" });
      dash.config = await r.json();
    } catch (e) {
      dash.config = { ws_port: 8083, ws_url: "", prefix: "roslink" };
    }
    dash.prefix = dash.config.prefix || "roslink";
    tree = new TopicTree(dash.prefix);
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

  function connect(ev) {
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
        will: { topic: tree.operator(user, dash.clientId), payload: "", qos: 1, retain: true },
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
    client.on("message", (t, payload, packet) => { if (current()) onMessage(t, payload, packet); });
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
    const filters = [tree.heartbeatFilter(), tree.stateFilter(), tree.toUserFilter("+", dash.user)];
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

  function logout() {
    closeClient();
    dash.robots.clear();
    dash.selected = null;
    dash.builtFor = null;
    for (const g of dash.goals.values()) clearTimeout(g.timer);
    dash.goals.clear();
    for (const r of dash.pendingParams.values()) clearTimeout(r.timer);
    dash.pendingParams.clear();
    ui.services.replaceChildren();
    ui.actions.replaceChildren();
    ui.params.replaceChildren();
    dash.operatorAnywhere = false;
    dash.commanding = false;
    ui.fleet.tBodies[0].replaceChildren();
    ui.errors.replaceChildren();
    ui.acks.replaceChildren();
    show(ui.robotView, false);
    show(ui.main, false);
    show(ui.login, true);
    show(ui.logout, false);
    show(ui.estop, false);
    ui.whoami.textContent = "";
    notice("");
    setConn("disconnected", "not connected");
  }

  // ------------------------------------------------------------------------------------ operator presence
  function heartbeatBody(status) {
    dash.presenceSeq = (dash.presenceSeq + 1) % 4294967296;
    return JSON.stringify({ message_id: 0, sequence_number: dash.presenceSeq,
      payload: { type: 0, name: dash.clientId, system_status: status, owner_id: dash.user, mode: 0 } });
  }
  function beat() {
    if (dash.client && dash.connected) {
      // 4 = this client commands (its leaving stops the robot it drove), 3 = it only watches so far
      dash.client.publish(presenceTopic(), heartbeatBody(dash.commanding ? 4 : 3), { qos: 0, retain: true });
    }
  }
  function startPresence() {
    if (dash.presenceTimer) return;
    beat();
    dash.presenceTimer = setInterval(beat, PRESENCE_PERIOD_MS);
  }
  function stopPresence(signOff) {
    if (dash.presenceTimer) clearInterval(dash.presenceTimer);
    dash.presenceTimer = null;
    if (signOff && dash.client && dash.connected && dash.operatorAnywhere) {
      // a clean sign-off (status 7), then the clear the last-will would publish: the robot stops all the same
      dash.client.publish(presenceTopic(), heartbeatBody(7), { qos: 1 });
      dash.client.publish(presenceTopic(), "", { qos: 1, retain: true });
    }
  }

  // ------------------------------------------------------------------------------------------- messages
  function onMessage(t, payload, packet) {
    const p = tree.parse(t);
    if (!p || p.kind === KINDS.operator) return;
    const name = p.robot;
    if (p.kind === KINDS.heartbeat) { onHeartbeat(name, payload); return; }
    let robot = dash.robots.get(name);
    if (p.kind === KINDS.state) {
      if (!robot && p.name === "description" && payload.length) {
        robot = newRobot(name);  // the retained description may come before the heartbeat: keep it
        dash.robots.set(name, robot);
        addFleetRow(robot);
      }
      if (!robot) return;  // state before the first heartbeat: counted from the heartbeat on
      onState(robot, p.name, payload);
    } else if (p.kind === KINDS.to && p.user === dash.user) {
      onPersonal(name, robot, p, payload, packet);
    }
  }

  function onHeartbeat(name, payload) {
    if (!payload.length) {  // a cleared retained heartbeat: the robot left the fleet
      const gone = dash.robots.get(name);
      if (gone && gone.row) gone.row.remove();
      dash.robots.delete(name);
      if (dash.selected === name) selectRobot(null);
      return;
    }
    const hb = message("heartbeat", payload);
    if (!hb) return;
    let robot = dash.robots.get(name);
    if (!robot) {
      robot = newRobot(name);
      dash.robots.set(name, robot);
      addFleetRow(robot);
    }
    robot.hb = hb;
    robot.hbAt = performance.now();
    count(robot, "heartbeat", payload);
    updateRow(robot, robot.hbAt);
    if (!dash.selected) selectRobot(name);
    else if (dash.selected === name) updateBanner(robot);
  }

  // The robot's description with every entry read from its declaration (an unreadable entry is left out).
  function readDescription(payload) {
    const d = read("robot_description", payload);
    if (d) for (const [key, body] of Object.entries(window.ROSLINK.constants.DESCRIPTION_ENTRIES)) {
      d[key] = d[key].map((e) => window.roslinkBody.readBody(BODIES[body], e)).filter(Boolean);
    }
    return d;
  }

  function count(robot, key, payload) {
    let r = robot.rates.get(key);
    if (!r) { r = { n: 0, prevN: 0, hz: 0, last: 0, row: null, payload: null }; robot.rates.set(key, r); }
    r.n += 1;
    r.last = performance.now();
    r.payload = payload || null;  // the latest, for the state inspector (one per topic)
  }

  // The state inspector: the latest message of the row clicked in "Message rates", raw and decoded, with its age.
  const INSPECT_MAX = 4000;  // characters shown
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
      const text = new TextDecoder().decode(payload);
      const value = parse(payload);
      body = value === undefined ? text : JSON.stringify(value, null, 2);
    } else body = `${encoding}: ${payload.length} bytes, not shown as text`;
    const head = `${name === "heartbeat" ? name : `state/${name}`} · ${encoding} · ` +
      `${payload ? payload.length : 0} bytes · ${rate.hz.toFixed(1)} Hz · ${age}`;
    setText(ui.inspectorHead, head);
    setText(ui.inspectorBody, body.length > INSPECT_MAX ? `${body.slice(0, INSPECT_MAX)}…` : body);
    ui.inspector.dataset.topic = name;
  }

  function onState(robot, name, payload) {
    count(robot, name, payload);
    if (name === "description") {
      const raw = new TextDecoder().decode(payload);
      if (raw === robot.descRaw) return;  // the same retained description again (a reconnect)
      robot.descRaw = raw;
      robot.description = raw ? readDescription(payload) : null;
      presenceIfNeeded(robot);
      if (dash.selected === robot.name) buildControls(robot);
      return;
    }
    const paramNode = paramEventsNode(name);
    if (paramNode !== null) { onParamEvent(robot, paramNode, payload); return; }
    if (name === "robot_status") {
      const status = message("robot_status", payload);
      if (status) robot.status = status;
      return;
    }
    if (name === "control") {  // who drives (docs/protocol.md, "control state")
      robot.control = read("control_state", payload);
      if (dash.selected === robot.name) showControl(robot);
      return;
    }
    if (name === "link") {  // the bridge's uplink report (docs/protocol.md, "link report")
      robot.link = read("link_report", payload);
      if (dash.selected === robot.name) showUplink(robot);
      return;
    }
    if (name === "ack" && dash.stopRound) {  // STOP ALL waits for every robot's acknowledgement
      const a = message("ack", payload);
      if (a) noteStopAck(robot, a);
    }
    if (dash.selected !== robot.name) return;  // other robots: counted, not parsed
    const encoding = (entryOf(robot, "state", name) || {}).encoding;
    if (encoding === "raw") { showImageBytes(robot, name, payload); return; }
    if (encoding && encoding !== "json") { notDecoded(robot, name, encoding); return; }
    if (name === "global_motion") {
      const p = message("global_motion", payload);
      if (!p) return;
      robot.pose = { x: p.x, y: p.y, yaw: p.yaw, vx: p.vx, wz: p.wz, t: p.time_boot_ms };
      robot.poses += 1;
      robot.recent.push(robot.pose);
      if (robot.recent.length > RECENT_MAX) robot.recent.shift();
      const last = robot.trail[robot.trail.length - 1];
      if (!last || Math.hypot(last[0] - p.x, last[1] - p.y) > 0.01) {
        robot.trail.push([p.x, p.y]);
        if (robot.trail.length > TRAIL_MAX) robot.trail.splice(0, robot.trail.length - TRAIL_MAX);
      }
      updatePose(robot);
      dirty = true;
    } else if (name === "range_finder_data") {
      const s = message("range_finder_data", payload);
      if (s) {
        robot.scan = s;
        dirty = true;
      }
    } else if (name === "gps_raw_info") {
      const g = message("gps_raw_info", payload);
      if (g && g.fix_type >= 2) {
        robot.gpsFix = g;
        robot.gps.push([g.lat, g.lon]);
        if (robot.gps.length > GPS_MAX) robot.gps.splice(0, robot.gps.length - GPS_MAX);
        drawGps(robot);
      }
    } else if (name === "image") {
      const im = message("image", payload);
      if (im && /^[a-z0-9.+-]+$/i.test(im.format)) {
        ui.camera.src = `data:image/${im.format.toLowerCase()};base64,${im.data}`;
        show(ui.cameraBox, true);
      }
    } else if (name === "ack") {
      const a = message("ack", payload);
      if (a) {
        const result = ["accepted", "rejected", "failed", "failsafe"][a.result] || `result ${a.result}`;
        addLog(ui.acks, `${result}: command ${a.command} seq ${a.command_sequence} ${a.text || ""}`,
               { result });
      }
    }
  }

  // The pose when a scan was taken (both carry their ROS header stamp), interpolated between the poses before and
  // after it, so a turning robot's scan is drawn where it was measured rather than rotated by the time between
  // the two messages. Null (use the latest pose) when the stamps are missing or far apart.
  function poseAt(robot, ms) {
    if (!(ms > 0)) return null;
    let before = null, after = null;
    for (const p of robot.recent) {
      if (!(p.t > 0)) continue;
      if (p.t <= ms && (!before || p.t > before.t)) before = p;
      if (p.t >= ms && (!after || p.t < after.t)) after = p;
    }
    if (before && after) {
      if (after.t === before.t) return before;
      const k = (ms - before.t) / (after.t - before.t);
      const dyaw = Math.atan2(Math.sin(after.yaw - before.yaw), Math.cos(after.yaw - before.yaw));
      return { x: before.x + k * (after.x - before.x), y: before.y + k * (after.y - before.y), yaw: before.yaw + k * dyaw };
    }
    const near = before || after;
    return near && Math.abs(near.t - ms) <= 150 ? near : null;
  }

  function onPersonal(name, robot, p, payload, packet) {
    const kind = p.verb;
    if (kind === "access") {
      if (!robot) {  // the report can come before the heartbeat: keep it for the robot's first heartbeat
        robot = newRobot(name);
        dash.robots.set(name, robot);
        addFleetRow(robot);
      }
      robot.access = payload.length ? read("access_report", payload) : null;
      presenceIfNeeded(robot);
      if (dash.selected === name) buildControls(robot);
      updateRow(robot, performance.now());
    } else if (kind === "notice") {  // carried out, but changed (a twist clamped to the robot's limits)
      const n = read("notice", payload);
      if (!n || (n.client_id && n.client_id !== dash.clientId)) return;
      notice(`${name}: ${n.notice}`);
    } else if (kind === "error") {
      const e = read("error_report", payload);
      if (!e) { addLog(ui.errors, `${name}: unreadable error report`); return; }
      // reports naming another program of ours are theirs; reports naming none may be ours: shown
      if (e.client_id && e.client_id !== dash.clientId) return;
      const about = tree.parse(e.topic);
      const where = about && about.kind === KINDS.from ? leafOf(about) : e.topic;
      addLog(ui.errors, `${name} refused ${where}: ${e.error}`, { robot: name });
      notice(`${name} refused ${where}: ${e.error}`);
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
      const preq = e.id !== null && dash.pendingParams.get(e.id);
      if (preq && preq.robot === name) {
        clearTimeout(preq.timer);
        dash.pendingParams.delete(e.id);
        preq.onReply(null, `refused: ${e.error}`);
      }
    } else if (kind === "reply") {
      const r = read("call_reply", payload);
      if (!r || !dash.pendingCalls.has(r.id)) return;
      const call = dash.pendingCalls.get(r.id);
      clearTimeout(call.timer);
      dash.pendingCalls.delete(r.id);
      const text = r.result ? `${call.service}: ${JSON.stringify(r.values)}` : `${call.service} failed: ${r.error}`;
      ui.serviceResult.textContent = text;
      ui.serviceResult.dataset.result = r.result ? "ok" : "failed";
      if (!r.result) addLog(ui.errors, `${name} call ${call.service}: ${r.error}`, { robot: name });
    } else if (kind === "goal_status" || kind === "feedback" || kind === "result") {
      onGoalMessage(name, kind, p.name, read({ goal_status: "goal_status", feedback: "goal_feedback",
                                                result: "goal_result" }[kind], payload));
    } else if (kind === "param_reply") {
      onParamReply(name, read("parameter_reply", payload));
    } else if (kind === "snapshot_data") {
      onSnapshotChunk(name, p.name, payload);
    }
    void packet;
  }

  // ------------------------------------------------------------------------------------------ fleet view
  function addFleetRow(robot) {
    const tr = document.createElement("tr");
    tr.dataset.robot = robot.name;
    const cells = {};
    for (const key of ["name", "presence", "status", "session", "age", "battery", "mode", "owner", "role"]) {
      const td = document.createElement("td");
      td.className = key;
      tr.append(td);
      cells[key] = td;
    }
    cells.name.textContent = robot.name;
    tr.addEventListener("click", () => selectRobot(robot.name));
    robot.row = tr;
    robot.cells = cells;
    const rows = Array.from(ui.fleet.tBodies[0].rows);
    const before = rows.find((r) => r.dataset.robot > robot.name);
    ui.fleet.tBodies[0].insertBefore(tr, before || null);
    show(ui.fleetEmpty, false);
  }

  function presenceOf(robot, now) {
    if (!robot.hb) return "unseen";
    if (robot.hb.system_status === 8) return "offline";
    return now - robot.hbAt > STALE_AFTER_MS ? "stale" : "online";
  }

  function setText(el, text) { if (el.textContent !== text) el.textContent = text; }

  function updateRow(robot, now) {
    const c = robot.cells;
    if (!c) return;
    const hb = robot.hb;
    const presence = presenceOf(robot, now);
    c.presence.dataset.presence = presence;
    robot.row.dataset.presence = presence;
    setText(c.presence, presence);
    setText(c.status, hb ? (STATUS[hb.system_status] || String(hb.system_status)) : "–");
    setText(c.session, hb && hb.session !== undefined ? sessionText(hb.session) : "–");
    setText(c.age, hb ? `${((now - robot.hbAt) / 1000).toFixed(1)} s` : "–");
    const st = robot.status;
    setText(c.battery, st ? (st.battery_remaining >= 0 ? `${Math.round(st.battery_remaining)} %` : "?") +
      ` ${fmt(st.voltage_battery, 1)} V` : "–");
    setText(c.mode, hb ? (MODES[hb.mode] || String(hb.mode)) : "–");
    setText(c.owner, driverText(robot) || "–");
    setText(c.role, robot.access ? robot.access.role : (robot.access === null ? "none" : "–"));
    robot.row.classList.toggle("selected", dash.selected === robot.name);
  }

  // ------------------------------------------------------------------------------------------ robot view
  function selectRobot(name) {
    if (dash.driveRobot && dash.driveRobot !== name) stopDriving(true);
    dash.selected = name;
    const robot = name ? dash.robots.get(name) : null;
    show(ui.robotView, Boolean(robot));
    if (!robot) { show(ui.estop, false); return; }
    ui.robotTitle.textContent = `Robot ${name}`;
    ui.rates.tBodies[0].replaceChildren();
    for (const r of robot.rates.values()) r.row = null;
    ui.acks.replaceChildren();
    showUplink(robot);
    show(ui.gpsBox, false);
    show(ui.cameraBox, false);
    ui.serviceResult.textContent = "";
    dash.waypoint = null;
    dash.builtFor = null;
    buildControls(robot);
    updatePose(robot);
    updateBanner(robot);
    for (const r of dash.robots.values()) updateRow(r, performance.now());
    dirty = true;
  }

  // Operator presence (heartbeat + last-will) is kept by operators, and by a viewer who may send goals (an action
  // open to viewers in the access report) or set parameters (an entry with set_by viewers): the robot accepts
  // goals and parameter sets only from users with a live presence, as commands.
  function presenceIfNeeded(robot) {
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

  function isOperator(robot) { return Boolean(robot && robot.access && robot.access.role === "operator"); }

  // "alice since 12:03:05" from the robot's state/control (the heartbeat's owner_id says only who)
  function driverText(robot) {
    const c = robot.control;
    if (c && typeof c.holder === "string") {
      const since = typeof c.since === "number" ? new Date(c.since * 1000).toLocaleTimeString([], { hour12: false }) : "?";
      return `${c.holder}${c.supervisor ? " (supervisor)" : ""} since ${since}`;
    }
    if (c && c.holder === null) return "";
    return robot.hb && robot.hb.owner_id ? robot.hb.owner_id : "";
  }

  function heldByOther(robot) {
    return Boolean(robot && robot.control && typeof robot.control.holder === "string" && robot.control.holder !== dash.user);
  }

  function showControl(robot) {
    const who = driverText(robot);
    setText(ui.driver, who ? `driven by ${who}` : "nobody drives it: the first command claims control");
    ui.driver.dataset.holder = robot.control && robot.control.holder ? robot.control.holder : "";
    const sup = robot.control && Array.isArray(robot.control.supervisors) && robot.control.supervisors.includes(dash.user);
    show(ui.takeOver, isOperator(robot) && heldByOther(robot) && (!robot.control.supervisor || sup));
    ui.takeOver.textContent = heldByOther(robot) ? `Take over from ${robot.control.holder}` : "Take over";
    show(ui.claim, isOperator(robot) && Boolean(robot.control) && robot.control.holder === null);
    show(ui.release, Boolean(robot.control) && robot.control.holder === dash.user);
  }

  function mayStop(robot) { return isOperator(robot) || Boolean(robot && robot.access && robot.access.estop); }

  function buildControls(robot) {
    const op = isOperator(robot);
    show(ui.controls, op);
    showControl(robot);
    showSnapshot(robot);
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
    for (const r of dash.robots.values()) {  // panels of the robot shown before are gone from the page
      if (r !== robot) { r.actionPanels = new Map(); r.paramPanels = new Map(); }
    }
    const services = robot.access && Array.isArray(robot.access.services) ? robot.access.services : [];
    ui.services.replaceChildren();
    for (const svc of services) if (typeof svc === "string") ui.services.append(serviceControl(robot, svc));
    show(ui.servicesBox, services.length > 0);
    buildActions(robot);
    buildParams(robot);
  }

  // -- snapshots (docs/protocol.md, "Snapshots"): the robot's last seconds as MCAP, downloaded as a file ------------
  const SNAPSHOT_SECONDS = 30;
  const SNAPSHOT_STALL_MS = 10000;  // no chunk for this long: ask again from the first missing one
  const SNAPSHOT_RESUMES = 20;

  function showSnapshot(robot) {
    show(ui.snapshotBox, Boolean(robot && robot.access && robot.access.snapshot));
  }

  function snapshotStatus(state, text) {
    ui.snapshotStatus.dataset.state = state;
    ui.snapshotStatus.textContent = text;
  }

  function askSnapshot(snap, resumeFrom) {
    const body = { last: SNAPSHOT_SECONDS, client_id: dash.clientId };
    if (resumeFrom) body.resume_from = resumeFrom;
    dash.client.publish(tree.userTopic(snap.robot, dash.user, "snapshot", snap.id), JSON.stringify(body), { qos: 1 });
    snap.lastChunk = performance.now();
  }

  function takeSnapshot() {
    const robot = dash.selected;
    if (!robot || !dash.client) return;
    const id = `d${randomHex(6)}`;
    const snap = { id, robot, chunks: new Map(), header: null, done: false, resumes: 0, lastChunk: 0, timer: null };
    dash.snapshots.set(id, snap);
    ui.snapshot.disabled = true;
    snapshotStatus("asking", `asking ${robot} for its last ${SNAPSHOT_SECONDS} s…`);
    askSnapshot(snap, 0);
    snap.timer = setInterval(() => {
      if (snap.done || performance.now() - snap.lastChunk < SNAPSHOT_STALL_MS) return;
      if (++snap.resumes > SNAPSHOT_RESUMES) { endSnapshot(snap, "failed", "the robot stopped sending; given up"); return; }
      let first = 0;
      while (snap.chunks.has(first)) first += 1;
      askSnapshot(snap, first);
    }, 1000);
  }

  function endSnapshot(snap, state, text) {
    snap.done = true;
    clearInterval(snap.timer);
    if (dash.selected === snap.robot) snapshotStatus(state, text);
    ui.snapshot.disabled = false;
    addLog(state === "saved" ? ui.acks : ui.errors, `${snap.robot} snapshot: ${text}`, { robot: snap.robot });
  }

  function onSnapshotChunk(robotName, id, payload) {
    const snap = dash.snapshots.get(id);
    if (!snap || snap.done || snap.robot !== robotName) return;
    const bytes = payload instanceof Uint8Array ? payload : new Uint8Array(payload);
    const cut = bytes.indexOf(10);  // the header line ends at the first newline
    const header = cut > 0 ? read("snapshot_chunk", bytes.subarray(0, cut)) : null;
    if (!header) { endSnapshot(snap, "failed", "a malformed chunk"); return; }
    if (snap.header && (header.count !== snap.header.count || header.sha256 !== snap.header.sha256)) {
      endSnapshot(snap, "failed", "chunks of two different files under one id");
      return;
    }
    snap.header = snap.header || header;
    snap.chunks.set(header.index, bytes.slice(cut + 1));
    snap.lastChunk = performance.now();
    if (dash.selected === snap.robot) snapshotStatus("receiving", `${snap.chunks.size} / ${header.count} chunks`);
    if (snap.chunks.size === header.count) finishSnapshot(snap);
  }

  async function finishSnapshot(snap) {
    const { count, size, sha256, messages } = snap.header;
    const data = new Uint8Array(size);
    let at = 0;
    for (let i = 0; i < count; i += 1) {
      const part = snap.chunks.get(i);
      if (at + part.length > size) { endSnapshot(snap, "failed", "more bytes than the robot announced"); return; }
      data.set(part, at);
      at += part.length;
    }
    const digest = new Uint8Array(await crypto.subtle.digest("SHA-256", data));
    const hex = [...digest].map((b) => b.toString(16).padStart(2, "0")).join("");
    if (at !== size || hex !== sha256) { endSnapshot(snap, "failed", "the file arrived damaged (SHA-256 differs)"); return; }
    snap.file = data;  // kept for the browser tests; the download is the user's copy
    const name = `${snap.robot}-${new Date().toISOString().replace(/[:.]/g, "-")}.mcap`;
    const link = document.createElement("a");
    link.href = URL.createObjectURL(new Blob([data], { type: "application/octet-stream" }));
    link.download = name;
    link.click();
    setTimeout(() => URL.revokeObjectURL(link.href), 60000);
    endSnapshot(snap, "saved", `${name}: ${messages} messages, ${(size / 1000).toFixed(0)} kB, SHA-256 checked`);
  }

  function updateBanner(robot) {
    const hb = robot.hb;
    const blocked = Boolean(hb && hb.system_status === 6);
    if (dash.selected === robot.name) blockPad(blocked);
    // the stop was lifted (Resume): the refusals it caused are resolved, their red line goes
    if (robot.blocked && !blocked && ui.notice.textContent.startsWith(`${robot.name} refused`)) notice("");
    robot.blocked = blocked;
    let text = "";
    if (hb && hb.system_status === 6) text = `Motion blocked on ${robot.name} (emergency stop or disarm)` +
      (isOperator(robot) ? ": press Resume (arm) to drive again." : ".");
    else if (hb && hb.system_status === 8) text = `${robot.name} is offline (its bridge is gone).`;
    setText(ui.robotBanner, text);
    show(ui.robotBanner, Boolean(text));
  }

  function updatePose(robot) {
    const p = robot.pose;
    if (!p) { ui.pose.textContent = "no position yet"; ui.pose.dataset.n = "0"; return; }
    ui.pose.textContent = `x ${fmt(p.x, 2)} m  y ${fmt(p.y, 2)} m  yaw ${fmt(p.yaw * 180 / Math.PI, 0)}°  ` +
      `v ${fmt(p.vx, 2)} m/s  ω ${fmt(p.wz, 2)} rad/s`;
    ui.pose.dataset.x = p.x.toFixed(3);
    ui.pose.dataset.y = p.y.toFixed(3);
    ui.pose.dataset.yaw = p.yaw.toFixed(3);
    ui.pose.dataset.n = String(robot.poses);
  }

  // The plot: world metres, x right, y up, centred on the room's origin and growing to keep the robot in view.
  function toPx(x, y) {
    const c = ui.plot, s = c.width / (2 * view.half);
    return [c.width / 2 + (x - view.cx) * s, c.height / 2 - (y - view.cy) * s];
  }
  function fromPx(px, py) {
    const c = ui.plot, s = c.width / (2 * view.half);
    return [view.cx + (px - c.width / 2) / s, view.cy - (py - c.height / 2) / s];
  }
  function draw() {
    dirty = false;
    const robot = dash.selected && dash.robots.get(dash.selected);
    const c = ui.plot, g = c.getContext("2d");
    g.clearRect(0, 0, c.width, c.height);
    if (!robot) return;
    const p = robot.pose;
    if (p && view.follow) { view.cx = p.x; view.cy = p.y; }
    else if (p && !view.manual) {
      const need = Math.max(Math.abs(p.x - view.cx), Math.abs(p.y - view.cy)) + 1.5;
      if (need > view.half) view.half = Math.min(1000, Math.ceil(need));
    }
    // grid, 1 m (or coarser when zoomed out)
    const step = view.half > 30 ? 10 : view.half > 12 ? 5 : 1;
    g.strokeStyle = "#eef0f3";
    g.lineWidth = 1;
    g.beginPath();
    for (let v = Math.ceil((view.cx - view.half) / step) * step; v <= view.cx + view.half; v += step) {
      const [x] = toPx(v, 0);
      g.moveTo(x, 0); g.lineTo(x, c.height);
    }
    for (let v = Math.ceil((view.cy - view.half) / step) * step; v <= view.cy + view.half; v += step) {
      const [, y] = toPx(0, v);
      g.moveTo(0, y); g.lineTo(c.width, y);
    }
    g.stroke();
    g.strokeStyle = "#c9ced4";
    g.beginPath();
    const [ox, oy] = toPx(0, 0);
    g.moveTo(ox, 0); g.lineTo(ox, c.height); g.moveTo(0, oy); g.lineTo(c.width, oy);
    g.stroke();
    g.fillStyle = "#7b8590";
    g.font = "11px sans-serif";
    g.fillText(`grid ${step} m`, 6, c.height - 6);
    // axis labels: metres along the bottom (x) and the left edge (y), on the grid lines
    const labels = [];
    for (let v = Math.ceil((view.cx - view.half) / step) * step; v <= view.cx + view.half; v += step) {
      const [x] = toPx(v, 0);
      if (x > 40 && x < c.width - 20) { g.fillText(`${+v.toFixed(2)}`, x + 2, c.height - 20); labels.push(`x${+v.toFixed(2)}`); }
    }
    for (let v = Math.ceil((view.cy - view.half) / step) * step; v <= view.cy + view.half; v += step) {
      const [, y] = toPx(0, v);
      if (y > 12 && y < c.height - 30) { g.fillText(`${+v.toFixed(2)}`, 4, y - 2); labels.push(`y${+v.toFixed(2)}`); }
    }
    g.fillText("x (m) →", c.width - 52, c.height - 6);
    g.fillText("↑ y (m)", 4, 12);
    c.dataset.labels = labels.join(" ");
    // trail
    if (robot.trail.length > 1) {
      g.strokeStyle = "#4a90d9";
      g.lineWidth = 2;
      g.beginPath();
      robot.trail.forEach(([x, y], i) => { const [px, py] = toPx(x, y); if (i) g.lineTo(px, py); else g.moveTo(px, py); });
      g.stroke();
    }
    // laser scan, around the robot in its heading (the scanner is taken to sit on base_link)
    if (p && robot.scan) {
      const s = robot.scan, at = poseAt(robot, typeof s.time_usec === "number" ? s.time_usec / 1000 : 0) || p;
      g.fillStyle = "#d9534f";
      for (let i = 0; i < s.ranges.length; i++) {
        const r = s.ranges[i];
        if (typeof r !== "number") continue;
        const a = at.yaw + s.angle_min + i * s.angle_increment;
        const [px, py] = toPx(at.x + r * Math.cos(a), at.y + r * Math.sin(a));
        g.fillRect(px - 1.5, py - 1.5, 3, 3);
      }
    }
    // waypoint marker
    if (dash.waypoint) {
      const [wx, wy] = toPx(dash.waypoint[0], dash.waypoint[1]);
      g.strokeStyle = "#2b9a4a";
      g.lineWidth = 2;
      g.beginPath();
      g.arc(wx, wy, 7, 0, 2 * Math.PI);
      g.moveTo(wx - 10, wy); g.lineTo(wx + 10, wy); g.moveTo(wx, wy - 10); g.lineTo(wx, wy + 10);
      g.stroke();
    }
    // the robot: a triangle pointing along its yaw
    if (p) {
      const [px, py] = toPx(p.x, p.y);
      g.save();
      g.translate(px, py);
      g.rotate(-p.yaw);
      g.fillStyle = robot.hb && robot.hb.system_status === 6 ? "#c4161c" : "#22313f";
      g.beginPath();
      g.moveTo(14, 0); g.lineTo(-9, 8); g.lineTo(-9, -8); g.closePath();
      g.fill();
      g.restore();
    }
  }
  function frame() {
    if (dirty) draw();
    requestAnimationFrame(frame);
  }

  function drawGps(robot) {
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
    g.strokeStyle = "#8a6d3b";
    g.lineWidth = 2;
    g.beginPath();
    pts.forEach((p, i) => { const [x, y] = px(p); if (i) g.lineTo(x, y); else g.moveTo(x, y); });
    g.stroke();
    const [lx, ly] = px(pts[pts.length - 1]);
    g.fillStyle = "#8a6d3b";
    g.beginPath();
    g.arc(lx, ly, 4, 0, 2 * Math.PI);
    g.fill();
    g.fillStyle = "#7b8590";
    g.font = "11px sans-serif";
    g.fillText(`N ↑   ±${half.toFixed(0)} m`, 6, 14);
  }

  // "uplink 244 kbit/s — range_finder_data 3.9 of 5 Hz (2 superseded)": the streams its link cannot carry at
  // their rate, so a slow scan on a thin link reads as what it is rather than as a fault.
  function uplinkText(link) {
    if (!link) return "";
    const behind = Object.entries(link.streams)
      .filter(([, s]) => s && s.offered_hz > 0 && s.sent_hz + 0.05 < s.offered_hz)
      .map(([n, s]) => `${n} ${Number(s.sent_hz).toFixed(1)} of ${Number(s.offered_hz).toFixed(1)} Hz` +
           (s.superseded ? ` (${s.superseded} superseded)` : ""));
    return `uplink ${link.measured ? "" : "≥ "}${Math.round(link.rate_kbit_s)} kbit/s — ` +
           (behind.length ? behind.join(", ") : "every stream at its rate");
  }

  function showUplink(robot) {
    setText(ui.uplink, uplinkText(robot.link));
  }

  function updateRates(now) {
    const robot = dash.selected && dash.robots.get(dash.selected);
    for (const r of dash.robots.values()) {
      for (const rate of r.rates.values()) {
        rate.hz = (rate.n - rate.prevN) / ((now - (rate.prevAt || now - 1000)) / 1000 || 1);
        rate.prevN = rate.n;
        rate.prevAt = now;
      }
    }
    if (!robot) return;
    const body = ui.rates.tBodies[0];
    for (const [name, rate] of [...robot.rates.entries()].sort()) {
      if (!rate.row) {
        rate.row = document.createElement("tr");
        rate.row.dataset.topic = name;
        rate.row.append(document.createElement("td"), document.createElement("td"), document.createElement("td"));
        rate.row.cells[0].textContent = name;
        rate.row.title = "show its latest message";
        rate.row.addEventListener("click", () => { dash.inspect = name; inspect(robot); });
        body.append(rate.row);
      }
      setText(rate.row.cells[1], rate.hz.toFixed(1));
      setText(rate.row.cells[2], `${((now - rate.last) / 1000).toFixed(1)} s ago`);
      rate.row.dataset.hz = rate.hz.toFixed(1);
    }
    inspect(robot);
  }

  // ---------------------------------------------------------------------------------------------- commands
  // Every command goes through here: refused at once (and said so) when the page knows the broker would drop it.
  function command(robotName, name, payload, messageId) {
    const robot = dash.robots.get(robotName);
    if (!dash.client || !dash.connected) { notice(`not sent (${name}): not connected to the broker`); return false; }
    if (!isOperator(robot) && !(name === "emergency_stop" && mayStop(robot))) {
      const why = `not sent (${name}): ${dash.user} is ${robot && robot.access ? "a " + robot.access.role : "not an operator"} ` +
        `of ${robotName}; the broker would drop it`;
      addLog(ui.errors, why, { robot: robotName });
      notice(why);
      return false;
    }
    if (name !== "emergency_stop" && heldByOther(robot)) {  // the robot would refuse it: say who drives at once
      const why = `not sent (${name}): ${robotName} is driven by ${driverText(robot)}; take over to drive it`;
      addLog(ui.errors, why, { robot: robotName });
      notice(why);
      return false;
    }
    if (name !== "emergency_stop" && robot && robot.control && robot.control.holder === null) claimControl(robotName, "claim");
    if (!dash.commanding && isOperator(robot)) {  // from now on this client's leaving stops the robot: say so first
      dash.commanding = true;
      beat();
    }
    const body = { message_id: messageId, sequence_number: nextSeq(), client_id: dash.clientId, payload };
    dash.client.publish(tree.userTopic(robotName, dash.user, "cmd", name), JSON.stringify(body), { qos: name === "twist" ? 0 : 1 });
    return true;
  }
  dash.command = command;
  dash.sendTwist = (robotName, lx, az) => command(robotName, "twist", { lx, ly: 0, lz: 0, ax: 0, ay: 0, az }, 100);

  function twistFor(dir) {
    const v = parseFloat(ui.speed.value) || 0.3;
    const d = DRIVE[dir];
    return { lx: d.lx * v, az: d.az * v };
  }

  function startDriving(dir) {
    const name = dash.selected;
    if (!name || !DRIVE[dir]) return;
    if (dash.driveDir === dir && dash.driveRobot === name) return;
    stopDriving(false);
    dash.driveDir = dir;
    dash.driveRobot = name;
    const send = () => {
      const t = twistFor(dash.driveDir);
      if (!dash.sendTwist(dash.driveRobot, t.lx, t.az)) stopDriving(false);
    };
    send();
    if (dash.driveDir) dash.driveTimer = setInterval(send, TWIST_PERIOD_MS);
    ui.driving.textContent = `driving ${dir}`;
    ui.driving.dataset.driving = dir;
    const b = document.querySelector(`.pad button[data-dir="${dir}"]`);
    if (b) b.classList.add("held");
  }

  // Release: end the stream and send one zero twist (the dead-man would stop it too, after command_timeout).
  function stopDriving(sendZero = true) {
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
      dash.sendTwist(robot, 0, 0);
    }
  }

  // control/claim (the drive pad claims a free robot before its first twist) and control/take_over (confirmed)
  function claimControl(robotName, op) {
    if (!dash.client || !dash.connected) return;
    if (!dash.commanding) { dash.commanding = true; beat(); }
    dash.client.publish(tree.userTopic(robotName, dash.user, "control", op), JSON.stringify({ client_id: dash.clientId }),
                        { qos: 1 });
  }
  dash.claimControl = claimControl;

  // explicit claim and release: hold control before driving (nobody else's commands move the robot meanwhile), and
  // give it back when done (the lease also ends with this page's presence)
  function claimSelected() {
    if (dash.selected) claimControl(dash.selected, "claim");
  }

  function releaseSelected() {
    if (!dash.client || !dash.connected || !dash.selected) return;
    dash.client.publish(tree.userTopic(dash.selected, dash.user, "control", "release"),
                        JSON.stringify({ client_id: dash.clientId }), { qos: 1 });
  }

  function takeOver() {
    const robot = dash.selected && dash.robots.get(dash.selected);
    if (!robot || !heldByOther(robot)) return;
    if (!window.confirm(`Take control of ${robot.name} from ${robot.control.holder}? The robot stops, and ` +
                        `${robot.control.holder} is told.`)) return;
    claimControl(robot.name, "take_over");
    addLog(ui.acks, `asked to take over ${robot.name} from ${robot.control.holder}`);
  }

  // STOP ALL: an emergency stop to every robot this login may stop, then per robot whether its bridge acknowledged
  // it (state/ack, command 108, our sequence number) within STOP_ACK_MS.
  const STOP_ACK_MS = 1000;
  function stopAll() {
    stopDriving(false);
    const round = { sent: new Map(), acked: new Map() };
    dash.stopRound = round;
    for (const robot of dash.robots.values()) {
      if (!mayStop(robot) || presenceOf(robot, performance.now()) !== "online") continue;
      const seq = nextSeq();
      const body = { message_id: 108, sequence_number: seq, client_id: dash.clientId,
                     payload: { reason: `STOP ALL (dashboard, ${dash.user})` } };
      dash.client.publish(tree.userTopic(robot.name, dash.user, "cmd", "emergency_stop"), JSON.stringify(body), { qos: 1 });
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
  function noteStopAck(robot, a) {
    const round = dash.stopRound;
    const sent = round && round.sent.get(robot.name);
    if (sent && a.command === 108 && a.command_sequence === sent.seq && a.result === 0 && !round.acked.has(robot.name)) {
      round.acked.set(robot.name, Math.round(performance.now() - sent.at));
    }
  }

  function emergencyStop() {
    const name = dash.selected;
    if (!name) return;
    stopDriving(false);
    if (command(name, "emergency_stop", { reason: `emergency stop button (dashboard, ${dash.user})` }, 108)) {
      addLog(ui.acks, `sent emergency stop to ${name}`);
    }
  }

  function arm() {
    const name = dash.selected;
    if (name && command(name, "arm", {}, 104)) addLog(ui.acks, `sent arm (resume) to ${name}`);
  }

  function callService(robotName, service, args) {
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
    dash.client.publish(tree.userTopic(robotName, dash.user, "call", service),
                        JSON.stringify({ id, args, client_id: dash.clientId }), { qos: 1 });
  }
  dash.callService = callService;

  // ------------------------------------------------------------------- forms from the robot description
  // The robot's description (retained on state/description) carries the field layout of every ROS type it
  // maps: name → "float64" / "string" / "int32[]" …, or {type, fields} for a nested message. Forms are built
  // from it with createElement/textContent only (the description comes from the robot: never innerHTML).
  const INT_RANGE = {
    int8: [-128, 127], uint8: [0, 255], byte: [0, 255], char: [0, 255], int16: [-32768, 32767], uint16: [0, 65535],
    int32: [-2147483648, 2147483647], uint32: [0, 4294967295],
    int64: [-Number.MAX_SAFE_INTEGER, Number.MAX_SAFE_INTEGER], uint64: [0, Number.MAX_SAFE_INTEGER],
  };
  const FLOATS = new Set(["float32", "float64", "float", "double"]);
  const NUMBER_RE = /^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$/;
  const MAX_FORM_DEPTH = 4;          // nested messages deeper than this are edited as JSON
  const MAX_FIELDS = 200;            // inputs per form (a huge type gets a JSON box for the rest)
  const SHOW_MAX = 2000;             // characters of a reply, feedback or result shown
  const GOALS_MAX = 64;              // goals of this page tracked at once (the oldest is forgotten)
  const PARAMS_MAX = 200;            // parameters listed per node
  const PARAM_TIMEOUT_MS = 10000;

  class FieldError extends Error {}

  function short(value) {
    let text;
    try { text = JSON.stringify(value); } catch (e) { text = String(value); }
    if (text === undefined) text = String(value);
    return text.length > SHOW_MAX ? `${text.slice(0, SHOW_MAX)} … (${text.length} characters)` : text;
  }
  function el(tag, attrs, text) {
    const e = document.createElement(tag);
    if (attrs) for (const [k, v] of Object.entries(attrs)) {
      if (k.startsWith("data-")) e.dataset[k.slice(5).replace(/-(\w)/g, (_, c) => c.toUpperCase())] = v;
      else if (k === "class") e.className = v;
      else e[k] = v;
    }
    if (text !== undefined) e.textContent = text;
    return e;
  }
  // A rule with `encoding: raw` sends a CompressedImage's JPEG or PNG itself (docs/protocol.md, "State encodings"):
  // shown from a blob URL, the previous one released. What the page cannot decode (CBOR) is said once, not hidden.
  function showImageBytes(robot, name, payload) {
    const b = payload;
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
  function notDecoded(robot, name, what) {
    const key = `${robot.name}/${name}`;
    if (dash.undecoded.has(key)) return;
    dash.undecoded.add(key);
    addLog(ui.errors, `${robot.name} state/${name} is ${what}: this page does not show it (the SDK decodes it)`,
           { robot: robot.name });
  }
  function isLayout(v) { return Boolean(v) && typeof v === "object" && !Array.isArray(v); }
  function typeLayout(robot, rosType) {
    const d = robot.description;
    const t = d && isLayout(d.types) && typeof rosType === "string" ? d.types[rosType] : undefined;
    return isLayout(t) ? t : undefined;
  }
  function entryOf(robot, kind, name) {
    const d = robot.description;
    const list = d && Array.isArray(d[kind]) ? d[kind] : [];
    return list.find((e) => isLayout(e) && e.name === name);
  }

  // One input per primitive field, a fieldset per nested message, a JSON box for arrays (and what is too deep).
  // Returns a collector: () → the JSON object to send, or throws FieldError naming the field.
  function buildFields(container, fields, path, depth, budget) {
    const collectors = [];
    for (const [name, spec] of Object.entries(fields)) {
      const full = path ? `${path}.${name}` : name;
      if (budget.n-- <= 0 || (isLayout(spec) && depth >= MAX_FORM_DEPTH) ||
          (isLayout(spec) && !isLayout(spec.fields)) || (typeof spec !== "string" && !isLayout(spec))) {
        collectors.push([name, jsonField(container, full, isLayout(spec) ? String(spec.type || "message") : "JSON", false)]);
      } else if (isLayout(spec)) {
        const fs = el("fieldset", { "data-field": full });
        fs.append(el("legend", null, `${name} (${spec.type || "message"})`));
        container.append(fs);
        const inner = buildFields(fs, spec.fields, full, depth + 1, budget);
        collectors.push([name, () => { const v = inner(); return Object.keys(v).length ? v : undefined; }]);
      } else {
        collectors.push([name, primitiveField(container, full, name, spec)]);
      }
    }
    return () => {
      const out = {};
      for (const [name, get] of collectors) {
        const v = get();
        if (v !== undefined) out[name] = v;
      }
      return out;
    };
  }

  function markInvalid(input, why) {
    input.classList.add("invalid");
    input.setAttribute("aria-invalid", "true");
    throw new FieldError(why);
  }

  function primitiveField(container, full, name, type) {
    const label = el("label", { class: "field" });
    label.append(el("span", { class: "field-name" }, name), el("span", { class: "field-type" }, type));
    container.append(label);
    if (/\[.*\]$/.test(type)) return jsonField(label, full, type, true);
    if (type === "bool" || type === "boolean") {
      const box = el("input", { type: "checkbox", "data-field": full, "data-type": type });
      label.prepend(box);
      return () => box.checked;
    }
    const input = el("input", { type: "text", spellcheck: false, "data-field": full, "data-type": type });
    input.addEventListener("input", () => { input.classList.remove("invalid"); input.removeAttribute("aria-invalid"); });
    label.append(input);
    const range = INT_RANGE[type];
    if (range || FLOATS.has(type)) {
      input.inputMode = range ? "numeric" : "decimal";
      input.placeholder = "0";
      return () => {
        const raw = input.value.trim();
        if (!raw) return undefined;  // the ROS default
        if (!NUMBER_RE.test(raw)) markInvalid(input, `${full}: "${raw}" is not a number (${type})`);
        const n = Number(raw);
        if (!Number.isFinite(n)) markInvalid(input, `${full}: ${raw} is not a finite number (${type})`);
        if (range) {
          if (!Number.isInteger(n)) markInvalid(input, `${full}: ${raw} is not an integer (${type})`);
          if (n < range[0] || n > range[1]) markInvalid(input, `${full}: ${raw} is out of range for ${type} ` +
                                                        `(${range[0]}..${range[1]})`);
        }
        return n;
      };
    }
    const bound = /^w?string<=(\d+)$/.exec(type);
    if (bound) input.maxLength = Number(bound[1]);
    return () => (input.value === "" ? undefined : input.value);
  }

  function jsonField(container, full, type, isArray) {
    const area = el("textarea", { rows: 2, spellcheck: false, "data-field": full, "data-type": type,
                                  placeholder: isArray ? "JSON array, e.g. [1, 2]" : "JSON object" });
    area.addEventListener("input", () => { area.classList.remove("invalid"); area.removeAttribute("aria-invalid"); });
    if (container.tagName === "LABEL") container.append(area);
    else {
      const label = el("label", { class: "field" });
      label.append(el("span", { class: "field-name" }, full.split(".").pop()), el("span", { class: "field-type" }, type), area);
      container.append(label);
    }
    return () => {
      const raw = area.value.trim();
      if (!raw) return undefined;
      let v;
      try { v = JSON.parse(raw); } catch (e) { markInvalid(area, `${full}: not JSON (${e.message})`); }
      const bytes = /^(uint8|byte|char)\[/.test(type);  // byte arrays travel as base64 strings
      if (isArray && !bytes && !Array.isArray(v)) markInvalid(area, `${full}: expected a JSON array (${type})`);
      if (!isArray && !isLayout(v)) markInvalid(area, `${full}: expected a JSON object (${type})`);
      return v;
    };
  }

  // A form: fields, a submit button, a line for what is wrong. onSubmit(values) is called only when every
  // field is valid; an invalid field is said so in the form and nothing is sent.
  function rosForm(attrs, layout, buttonText, onSubmit) {
    const form = el("form", { class: "ros-form", noValidate: true, ...attrs });
    const collect = isLayout(layout) ? buildFields(form, layout, "", 0, { n: MAX_FIELDS })
      : buildFields(form, { "(goal)": { type: "unknown type: JSON", fields: null } }, "", 0, { n: MAX_FIELDS });
    const row = el("div", { class: "form-buttons" });
    const submit = el("button", { type: "submit", class: "submit" }, buttonText);
    row.append(submit);
    const error = el("p", { class: "form-error", role: "alert", hidden: true });
    form.append(row, error);
    form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      let values;
      try {
        values = collect();
        if (!isLayout(layout)) values = values["(goal)"] || {};
      } catch (e) {
        if (!(e instanceof FieldError)) throw e;
        error.textContent = `not sent: ${e.message}`;
        form.dataset.state = "invalid";
        show(error, true);
        return;
      }
      error.textContent = "";
      show(error, false);
      form.dataset.state = "sent";
      onSubmit(values);
    });
    return { form, row, error };
  }

  // ----------------------------------------------------------------------------------------------- services
  function serviceControl(robot, svc) {
    const entry = entryOf(robot, "services", svc);
    const t = entry && typeLayout(robot, entry.ros_type);
    const request = t && isLayout(t.request) ? t.request : undefined;
    if (!request || Object.keys(request).length === 0) {
      const b = el("button", { type: "button", "data-service": svc, class: "service-button" }, svc);
      b.title = request ? `call ${svc} (${entry.ros_type}: no arguments)` : `call ${svc} with empty arguments ({})`;
      b.addEventListener("click", () => callService(robot.name, svc, {}));
      return b;
    }
    const box = el("div", { class: "service-form" });
    box.append(el("h4", null, `${svc} `));
    box.firstChild.append(el("small", null, entry.ros_type));
    const { form } = rosForm({ "data-service": svc }, request, `Call ${svc}`,
                             (args) => callService(robot.name, svc, args));
    box.append(form);
    return box;
  }

  // ------------------------------------------------------------------------------------------------ actions
  function buildActions(robot) {
    const actions = robot.access && Array.isArray(robot.access.actions) ? robot.access.actions : [];
    robot.actionPanels = new Map();
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
      const p = { panel, form, cancel, status, progress, feedback, result, layout: t };
      robot.actionPanels.set(name, p);
      const last = robot.lastGoals && robot.lastGoals.get(name);
      if (last) renderGoal(last);
    }
    show(ui.actionsBox, robot.actionPanels.size > 0);
  }

  const GOAL_ENDED = new Set(["succeeded", "aborted", "canceled", "timeout", "failed", "rejected", "refused",
                              "no-answer"]);

  function sendGoal(robotName, action, goal) {
    const robot = dash.robots.get(robotName);
    if (!robot) return;
    if (!dash.client || !dash.connected) { notice(`not sent (goal ${action}): not connected to the broker`); return; }
    const id = `${dash.clientId}-g${++dash.callCounter}`;
    const g = { id, robot: robotName, action, goal, status: "sending", text: "sent, waiting for the robot …",
                feedback: null, result: null, sentAt: performance.now(), timer: null };
    g.timer = setTimeout(() => {
      if (g.status !== "sending") return;
      endGoal(g, "no-answer", `no answer within ${CALL_TIMEOUT_MS / 1000} s (robot offline, or the broker dropped ` +
              "the goal: are you allowed to send it?)");
      addLog(ui.errors, `${robotName} goal ${action}: ${g.text}`, { robot: robotName });
    }, CALL_TIMEOUT_MS);
    dash.goals.set(id, g);
    while (dash.goals.size > GOALS_MAX) {  // forget the oldest (a goal whose result never came)
      const [oldId, old] = dash.goals.entries().next().value;
      clearTimeout(old.timer);
      dash.goals.delete(oldId);
    }
    if (!robot.lastGoals) robot.lastGoals = new Map();
    robot.lastGoals.set(action, g);
    if (isOperator(robot) && !dash.commanding) { dash.commanding = true; beat(); }
    dash.client.publish(tree.userTopic(robotName, dash.user, "goal", action),
                        JSON.stringify({ id, goal, client_id: dash.clientId }), { qos: 1 });
    renderGoal(g);
  }

  function cancelGoal(robotName, action) {
    const robot = dash.robots.get(robotName);
    const g = robot && robot.lastGoals && robot.lastGoals.get(action);
    if (!g || GOAL_ENDED.has(g.status)) return;
    if (!dash.client || !dash.connected) { notice(`not sent (cancel ${action}): not connected to the broker`); return; }
    dash.client.publish(tree.userTopic(robotName, dash.user, "cancel", action),
                        JSON.stringify({ id: g.id, client_id: dash.clientId }), { qos: 1 });
    g.text = `${g.text}; cancel sent …`;
    g.cancelSent = true;
    renderGoal(g);
  }

  function endGoal(g, status, text) {
    clearTimeout(g.timer);
    g.status = status;
    g.text = text;
    dash.goals.delete(g.id);
    renderGoal(g);
  }

  // A progress fraction, when the feedback says one: a numeric field named like progress/percent, or an
  // array that grows towards the goal's only integer field (fibonacci: the sequence towards `order`).
  function progressOf(g) {
    const f = g.feedback;
    if (!isLayout(f)) return null;
    for (const [k, v] of Object.entries(f)) {
      if (typeof v === "number" && /progress|percent|fraction/i.test(k) && v >= 0) return v > 1 ? Math.min(1, v / 100) : v;
    }
    const ints = isLayout(g.goal) ? Object.values(g.goal).filter((v) => Number.isInteger(v) && v > 0) : [];
    const arrays = Object.values(f).filter(Array.isArray);
    if (ints.length === 1 && arrays.length === 1) return Math.max(0, Math.min(1, (arrays[0].length - 1) / ints[0]));
    return null;
  }

  function renderGoal(g) {
    const robot = dash.robots.get(g.robot);
    const p = robot && dash.selected === g.robot && robot.actionPanels && robot.actionPanels.get(g.action);
    if (!p) return;
    p.status.dataset.status = g.status;
    p.status.dataset.goalId = g.id;
    setText(p.status, `goal ${short(g.goal)}: ${g.status}${g.text ? " — " + g.text : ""}`);
    p.cancel.disabled = GOAL_ENDED.has(g.status) || g.status === "canceling" || Boolean(g.cancelSent);
    const frac = g.status === "succeeded" ? 1 : progressOf(g);
    show(p.progress, frac !== null);
    if (frac !== null) { p.progress.value = frac; p.progress.dataset.fraction = frac.toFixed(3); }
    setText(p.feedback, g.feedback ? `feedback: ${short(g.feedback)}` : "");
    p.feedback.dataset.count = String(g.feedbackCount || 0);
    setText(p.result, g.result !== null ? `result: ${short(g.result)}` : "");
  }

  function onGoalMessage(name, kind, action, body) {
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

  // --------------------------------------------------------------------------------------------- parameters
  function paramRequest(robotName, node, body, onReply) {
    if (!dash.client || !dash.connected) { onReply(null, "not connected to the broker"); return; }
    const id = `${dash.clientId}-p${++dash.callCounter}`;
    const timer = setTimeout(() => {
      dash.pendingParams.delete(id);
      onReply(null, `no reply within ${PARAM_TIMEOUT_MS / 1000} s (robot offline, or the broker dropped the request)`);
    }, PARAM_TIMEOUT_MS);
    dash.pendingParams.set(id, { robot: robotName, node, onReply, timer });
    dash.client.publish(tree.userTopic(robotName, dash.user, "param", node),
                        JSON.stringify({ id, ...body, client_id: dash.clientId }), { qos: 1 });
  }

  function mayUse(robot, who) { return who === "viewers" ? Boolean(robot.access) : isOperator(robot); }

  function buildParams(robot) {
    const d = robot.description;
    const entries = robot.access && d && Array.isArray(d.parameters) ? d.parameters.filter(
      (e) => isLayout(e) && typeof e.name === "string" && mayUse(robot, e.who || "viewers")) : [];
    robot.paramPanels = new Map();
    ui.params.replaceChildren();
    for (const entry of entries) {
      const canSet = mayUse(robot, entry.set_by || "operators");
      const panel = el("div", { class: "params", "data-params": entry.name, "data-can-set": canSet ? "yes" : "no" });
      const h = el("h4", null, `${entry.name} `);
      h.append(el("small", null, `node ${entry.node || entry.name}; set by ${entry.set_by || "operators"}`));
      const refresh = el("button", { type: "button", class: "refresh", title: "read the values again" }, "↻");
      h.append(refresh);
      const table = el("table", { class: "param-table" });
      table.append(el("tbody"));
      const result = el("p", { class: "param-result" });
      panel.append(h, table);
      if (!canSet) panel.append(el("p", { class: "hint" }, `read-only for you: ${entry.set_by || "operators"} may set these`));
      panel.append(result);
      ui.params.append(panel);
      const p = { entry, panel, table, result, canSet, rows: new Map(), types: new Map() };
      robot.paramPanels.set(entry.name, p);
      refresh.addEventListener("click", () => loadParams(robot, p));
      loadParams(robot, p);
    }
    show(ui.paramsBox, entries.length > 0);
  }

  function paramNote(p, result, text) {
    p.result.dataset.result = result;
    setText(p.result, text);
  }

  function loadParams(robot, p) {
    const node = p.entry.name;
    paramNote(p, "pending", "reading …");
    paramRequest(robot.name, node, { op: "list" }, (r, err) => {
      if (!r) { paramNote(p, "failed", `list failed: ${err}`); return; }
      const names = isLayout(r.values) && Array.isArray(r.values.names)
        ? r.values.names.filter((n) => typeof n === "string").sort().slice(0, PARAMS_MAX) : [];
      for (const [n, row] of p.rows) if (!names.includes(n)) { row.tr.remove(); p.rows.delete(n); }
      for (const n of names) paramRow(robot, p, n);
      if (!names.length) { paramNote(p, "ok", "no parameters"); return; }
      paramRequest(robot.name, node, { op: "describe", names }, (rd) => {
        if (!rd || !isLayout(rd.values)) return;
        for (const [n, info] of Object.entries(rd.values)) {
          const row = p.rows.get(n);
          if (!row || !isLayout(info)) continue;
          p.types.set(n, String(info.type || ""));
          row.name.title = `${info.type || "?"}${info.description ? ": " + info.description : ""}`;
          row.tr.dataset.type = String(info.type || "");
          if (info.read_only && row.set) { row.set.disabled = true; row.input.disabled = true; row.set.title = "read-only parameter"; }
        }
      });
      paramRequest(robot.name, node, { op: "get", names }, (rg, err2) => {
        if (!rg) { paramNote(p, "failed", `get failed: ${err2}`); return; }
        if (isLayout(rg.values)) for (const [n, v] of Object.entries(rg.values)) setParamValue(p, n, v);
        paramNote(p, "ok", `${names.length} parameters read at ${stamp()}`);
      });
    });
  }

  function paramRow(robot, p, name) {
    if (p.rows.has(name)) return p.rows.get(name);
    const tr = el("tr", { "data-param": name });
    const nameTd = el("td", { class: "name" }, name);
    const valueTd = el("td", { class: "value" }, "…");
    tr.append(nameTd, valueTd);
    const row = { tr, name: nameTd, value: valueTd, input: null, set: null };
    if (p.canSet) {
      const td = el("td", { class: "edit" });
      row.input = el("input", { type: "text", size: 8, spellcheck: false, "data-param": name, placeholder: "new value" });
      row.set = el("button", { type: "button", class: "set", "data-param": name }, "Set");
      const send = () => setParam(robot, p, name, row);
      row.set.addEventListener("click", send);
      row.input.addEventListener("keydown", (ev) => { if (ev.key === "Enter") { ev.preventDefault(); send(); } });
      td.append(row.input, row.set);
      tr.append(td);
    }
    p.table.tBodies[0].append(tr);
    p.rows.set(name, row);
    return row;
  }

  function setParamValue(p, name, value) {
    const row = p.rows.get(name);
    if (!row) return;
    const text = value === null || value === undefined ? "(not set)" : typeof value === "string" ? value : short(value);
    setText(row.value, text);
    row.value.dataset.value = short(value === undefined ? null : value);
  }

  // The typed value of an edit box, from the parameter's described type (a double also takes "1"; a string
  // takes the text as is); throws FieldError with the reason.
  function parseParam(type, raw, name) {
    const text = raw.trim();
    const num = (int) => {
      if (!NUMBER_RE.test(text) || !Number.isFinite(Number(text))) throw new FieldError(`${name}: "${raw}" is not a number (${type})`);
      const n = Number(text);
      if (int && !Number.isSafeInteger(n)) throw new FieldError(`${name}: "${raw}" is not an integer (${type})`);
      return n;
    };
    if (type === "double") return num(false);
    if (type === "integer") return num(true);
    if (type === "bool") {
      if (/^(true|false)$/i.test(text)) return text.toLowerCase() === "true";
      throw new FieldError(`${name}: "${raw}" is not true or false (bool)`);
    }
    if (type === "string") return raw;
    let v;
    try { v = JSON.parse(text); } catch (e) {
      if (!type || type === "not_set") return raw;  // an untyped parameter: the text as a string
      throw new FieldError(`${name}: not a JSON array (${type})`);
    }
    if (type.endsWith("_array") && !Array.isArray(v)) throw new FieldError(`${name}: expected a JSON array (${type})`);
    return v;
  }

  function setParam(robot, p, name, row) {
    let value;
    try {
      if (row.input.value.trim() === "" && p.types.get(name) !== "string") throw new FieldError(`${name}: enter a value`);
      value = parseParam(p.types.get(name) || "", row.input.value, name);
    } catch (e) {
      if (!(e instanceof FieldError)) throw e;
      row.input.classList.add("invalid");
      paramNote(p, "invalid", `not sent: ${e.message}`);
      return;
    }
    row.input.classList.remove("invalid");
    paramNote(p, "pending", `setting ${name} to ${short(value)} …`);
    paramRequest(robot.name, p.entry.name, { op: "set", values: { [name]: value } }, (r, err) => {
      if (!r) { paramNote(p, "failed", `set ${name} failed: ${err}`); return; }
      const res = isLayout(r.values) ? r.values[name] : undefined;
      if (res && res.successful) {
        paramNote(p, "ok", `${name} set to ${short(value)}`);
        row.input.value = "";
      } else {
        const why = res && res.reason ? res.reason : "the node refused it";
        paramNote(p, "refused", `${name} not set: ${why}`);
        addLog(ui.errors, `${robot.name} refused parameter ${name} = ${short(value)}: ${why}`, { robot: robot.name });
      }
      paramRequest(robot.name, p.entry.name, { op: "get", names: [name] }, (rg) => {
        if (rg && isLayout(rg.values) && name in rg.values) setParamValue(p, name, rg.values[name]);
      });
    });
  }

  function onParamReply(name, body) {
    if (!body || (body.client_id && body.client_id !== dash.clientId)) return;
    const req = dash.pendingParams.get(body.id);
    if (!req || req.robot !== name) return;
    clearTimeout(req.timer);
    dash.pendingParams.delete(body.id);
    if (body.result) req.onReply(body, null);
    else req.onReply(null, body.error || "failed");
  }

  // state/parameter_events/<name>: values changed by anyone (MQTT, ros2 param set, the node itself)
  function onParamEvent(robot, name, payload) {
    const p = robot.paramPanels && robot.paramPanels.get(name);
    if (!p) return;
    const ev = read("parameter_event", payload);
    if (!ev) return;
    for (const key of ["new", "changed"]) {
      for (const [n, v] of Object.entries(ev[key])) {
        if (key === "new" && p.rows.size < PARAMS_MAX) paramRow(robot, p, n);
        setParamValue(p, n, v);
      }
    }
    for (const n of ev.deleted) {
      const row = p.rows.get(n);
      if (row) { row.tr.remove(); p.rows.delete(n); }
    }
  }

  // zoom (wheel, +/−), pan (drag), follow, reset: the plot is the user's to move
  function zoom(factor, px, py) {
    const [ax, ay] = px === undefined ? [view.cx, view.cy] : fromPx(px, py);  // the point under the cursor stays
    const half = Math.min(1000, Math.max(0.5, view.half * factor));
    view.cx = ax - (ax - view.cx) * half / view.half;
    view.cy = ay - (ay - view.cy) * half / view.half;
    view.half = half;
    view.manual = true;
    dirty = true;
  }
  function canvasPoint(ev) {
    const rect = ui.plot.getBoundingClientRect();
    return [(ev.clientX - rect.left) * ui.plot.width / rect.width, (ev.clientY - rect.top) * ui.plot.height / rect.height];
  }
  let drag = null;  // {x, y, cx, cy, moved}: a pan in progress
  ui.plot.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const [px, py] = canvasPoint(ev);
    zoom(ev.deltaY > 0 ? 1.25 : 0.8, px, py);
  }, { passive: false });
  ui.plot.addEventListener("pointerdown", (ev) => {
    const [px, py] = canvasPoint(ev);
    drag = { x: px, y: py, cx: view.cx, cy: view.cy, moved: false };
  });
  ui.plot.addEventListener("pointermove", (ev) => {
    if (!drag || !(ev.buttons & 1)) return;
    const [px, py] = canvasPoint(ev);
    const s = ui.plot.width / (2 * view.half);
    if (!drag.moved && Math.hypot(px - drag.x, py - drag.y) < 4) return;  // a click, not a drag
    drag.moved = true;
    view.follow = false;
    ui.plotFollow.checked = false;
    view.cx = drag.cx - (px - drag.x) / s;
    view.cy = drag.cy + (py - drag.y) / s;
    view.manual = true;
    dirty = true;
  });
  ui.plot.addEventListener("pointerup", () => { setTimeout(() => { drag = null; }, 0); });
  ui.plotZoomIn.addEventListener("click", () => zoom(0.5));
  ui.plotZoomOut.addEventListener("click", () => zoom(2));
  ui.plotFollow.addEventListener("change", () => { view.follow = ui.plotFollow.checked; view.manual = true; dirty = true; });
  ui.plotReset.addEventListener("click", () => {
    Object.assign(view, { half: 6, cx: 0, cy: 0, manual: false, follow: false });
    ui.plotFollow.checked = false;
    dirty = true;
  });

  function onPlotClick(ev) {
    if (drag && drag.moved) return;  // the end of a pan, not a waypoint
    if (!ui.waypointMode.checked || !dash.selected) return;
    const rect = ui.plot.getBoundingClientRect();
    const px = (ev.clientX - rect.left) * ui.plot.width / rect.width;
    const py = (ev.clientY - rect.top) * ui.plot.height / rect.height;
    const [x, y] = fromPx(px, py);
    if (command(dash.selected, "go_to_waypoint", { frame_type: 0, x: +x.toFixed(3), y: +y.toFixed(3), z: 0 }, 101)) {
      dash.waypoint = [x, y];
      addLog(ui.acks, `sent go-to-waypoint (${x.toFixed(2)}, ${y.toFixed(2)}) to ${dash.selected}`);
      dirty = true;
    }
  }

  // ----------------------------------------------------------------------------------------------- input
  function padDown(ev) {
    const dir = ev.currentTarget.dataset.dir;
    ev.preventDefault();
    if (dir === "stop") { stopDriving(true); return; }
    startDriving(dir);
  }
  // While the robot's motion is blocked (emergency stop, disarm) the pad's motion buttons and keys do nothing:
  // the robot would refuse every twist; only Resume (arm) unblocks it.
  function blockPad(blocked) {
    ui.controls.dataset.blocked = blocked ? "yes" : "no";
    for (const b of document.querySelectorAll(".pad button")) if (b.dataset.dir !== "stop") b.disabled = blocked;
    if (blocked && dash.driveDir) stopDriving(false);
  }
  function padUp() { if (dash.driveDir && dash.heldKeys.size === 0) stopDriving(true); }
  for (const b of document.querySelectorAll(".pad button")) {
    b.addEventListener("pointerdown", padDown);
    b.addEventListener("pointerup", padUp);
    b.addEventListener("pointerleave", padUp);
    b.addEventListener("pointercancel", padUp);
    b.addEventListener("contextmenu", (e) => e.preventDefault());
  }
  document.addEventListener("keydown", (ev) => {
    const target = ev.target;
    // typing in a form drives nothing (text boxes and JSON areas of the service, goal and parameter forms)
    if (target && ((target.tagName === "INPUT" && target.type !== "range" && target.type !== "checkbox") ||
                   target.tagName === "TEXTAREA" || target.tagName === "SELECT" || target.isContentEditable)) return;
    if (ui.controls.hidden) return;
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
  // Losing focus loses the key-up and pointer-up events: stop rather than drive blind.
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
  ui.estop.addEventListener("click", emergencyStop);
  ui.snapshot.addEventListener("click", takeSnapshot);
  ui.stopAll.addEventListener("click", stopAll);
  ui.takeOver.addEventListener("click", takeOver);
  ui.claim.addEventListener("click", claimSelected);
  ui.release.addEventListener("click", releaseSelected);
  ui.arm.addEventListener("click", arm);
  ui.plot.addEventListener("click", onPlotClick);
  ui.loginForm.addEventListener("submit", connect);
  ui.logout.addEventListener("click", logout);

  setInterval(() => {
    const now = performance.now();
    for (const r of dash.robots.values()) updateRow(r, now);
    const robot = dash.selected && dash.robots.get(dash.selected);
    if (robot) { updateBanner(robot); showControl(robot); }
    show(ui.stopAll, dash.connected && [...dash.robots.values()].some(mayStop));
    show(ui.fleetEmpty, dash.robots.size === 0);
  }, 500);
  setInterval(() => updateRates(performance.now()), 1000);
  requestAnimationFrame(frame);
  loadConfig();
})();
