// roslink-mqtt dashboard: plain JavaScript, no build step. MQTT.js (window.mqtt) does all MQTT.
//
// The browser connects to the broker's WebSocket listener with the user's own login, so the broker's ACL
// is the only access path: this page shows what the broker lets the user read, and its controls come from
// the robot's access report (retained on to/<user>/access), so a viewer gets none. Contracts: docs/protocol.md.
"use strict";

(() => {
  const STALE_AFTER_MS = 5000;       // as the SDK: a heartbeat older than this is stale (beats come every 1 s)
  const PRESENCE_PERIOD_MS = 500;    // operator heartbeat; robots drop an operator after 1.5 s without one
  const TWIST_PERIOD_MS = 100;       // 10 Hz while a drive button or key is held
  const TRAIL_MAX = 600;             // points kept per robot (60 s at 10 Hz)
  const GPS_MAX = 300;
  const RECENT_MAX = 30;             // poses kept to place each scan where it was taken (3 s at 10 Hz)
  const LOG_MAX = 30;                // list items kept in the error and ack lists
  const CALL_TIMEOUT_MS = 10000;
  const STATUS = ["uninit", "boot", "calibrating", "standby", "active", "critical", "emergency", "power-off",
                  "offline"];
  const MODES = ["MANUAL", "STABILIZE", "GUIDED", "AUTO", "LOITER", "RETURN_TO_LAUNCH", "LAND", "TAKEOFF"];
  const CONNACK = {
    1: "login refused: the broker does not accept this MQTT protocol version",
    2: "login refused: client id rejected",
    3: "login refused: the broker is unavailable",
    4: "login refused: bad username or password",
    // what the embedded broker (and Mosquitto) answer to a wrong password; also a login that may not connect
    5: "login refused: bad username or password (the broker says: not authorized)",
  };
  const DRIVE = {  // direction → twist, as a fraction of the chosen speed (angular 3× linear, capped by the robot)
    fwd: { lx: 1, az: 0 }, back: { lx: -1, az: 0 }, left: { lx: 0, az: 3 }, right: { lx: 0, az: -3 },
  };
  const KEYS = { ArrowUp: "fwd", w: "fwd", W: "fwd", ArrowDown: "back", s: "back", S: "back",
                 ArrowLeft: "left", a: "left", A: "left", ArrowRight: "right", d: "right", D: "right" };

  const $ = (id) => document.getElementById(id);
  const ui = {};
  for (const id of ["conn", "whoami", "logout", "estop", "notice", "login", "login-form", "ws-url", "username",
                    "password", "connect", "login-error", "main", "fleet", "fleet-empty", "robot-view", "robot-title",
                    "robot-banner", "plot", "pose", "waypoint-label", "waypoint-mode", "controls", "speed",
                    "speed-out", "arm", "driving", "viewer-note", "services-box", "services", "service-result",
                    "rates", "gps-box", "gps", "gps-text", "camera-box", "camera", "errors", "acks"]) {
    ui[id.replace(/-(\w)/g, (_, c) => c.toUpperCase())] = $(id);
  }

  // Everything the page knows. Exposed as window.dashboard for the browser tests and for curious users
  // (publishing through it changes nothing: the broker checks every PUBLISH against the login's grants).
  const dash = {
    client: null, user: "", clientId: "", prefix: "roslink", config: null, connected: false, everConnected: false,
    robots: new Map(), selected: null, operatorAnywhere: false, commanding: false,
    presenceSeq: 0, lastSeq: 0, presenceTimer: null, driveTimer: null, driveDir: null, driveRobot: null,
    heldKeys: new Set(), pendingCalls: new Map(), callCounter: 0, waypoint: null,
  };
  window.dashboard = dash;
  let dirty = false;                         // the plot needs redrawing (at most once per animation frame)
  const view = { half: 6, cx: 0, cy: 0 };    // plot: half the shown width in metres, and its centre

  function newRobot(name) {
    return { name, hb: null, hbAt: 0, status: null, access: undefined, rates: new Map(), pose: null, recent: [],
             trail: [], scan: null, gps: [], gpsFix: null, poses: 0, row: null, cells: null };
  }

  // ---------------------------------------------------------------------------------------------- helpers
  function show(el, on) { el.hidden = !on; }
  function notice(text) {
    ui.notice.textContent = text;
    show(ui.notice, Boolean(text));
  }
  function stamp() { return new Date().toLocaleTimeString(); }
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
  function topic(...parts) { return [dash.prefix, ...parts].join("/"); }
  function presenceTopic() { return topic("operators", dash.user, dash.clientId); }

  // ------------------------------------------------------------------------------------------- login
  async function loadConfig() {
    try {
      const r = await fetch("config.json", { cache: "no-store" });
      dash.config = await r.json();
    } catch (e) {
      dash.config = { ws_port: 8083, ws_url: "", prefix: "roslink" };
    }
    dash.prefix = dash.config.prefix || "roslink";
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
        reconnectPeriod: 0, connectTimeout: 8000, resubscribe: true,
        // operator presence: when this page vanishes without a word, the broker clears its heartbeat
        will: { topic: topic("operators", user, dash.clientId), payload: "", qos: 1, retain: true },
      });
    } catch (e) {
      ui.connect.disabled = false;
      loginError(`cannot connect: ${e.message}`);
      setConn("disconnected", "not connected");
      return;
    }
    dash.client = client;
    const current = () => dash.client === client;  // events of a client replaced by a new login are ignored
    client.on("connect", () => { if (current()) onConnect(); });
    client.on("message", (t, payload, packet) => { if (current()) onMessage(t, payload, packet); });
    client.on("error", (err) => {
      if (!current()) return;
      const text = CONNACK[err && err.code] || `connection error: ${err && err.message ? err.message : err}`;
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
    const filters = [topic("+", "heartbeat"), topic("+", "state", "#"), topic("+", "to", dash.user, "#")];
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
    if (!t.startsWith(dash.prefix + "/")) return;
    const parts = t.slice(dash.prefix.length + 1).split("/");
    const name = parts[0];
    if (name === "operators") return;
    if (parts[1] === "heartbeat") { onHeartbeat(name, payload); return; }
    const robot = dash.robots.get(name);
    if (parts[1] === "state" && parts.length >= 3) {
      if (!robot) return;  // state before the first heartbeat: counted from the heartbeat on
      onState(robot, parts.slice(2).join("/"), payload);
    } else if (parts[1] === "to" && parts[2] === dash.user) {
      onPersonal(name, robot, parts.slice(3), payload, packet);
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
    const env = parse(payload);
    const hb = env && env.payload;
    if (!hb || typeof hb !== "object") return;
    let robot = dash.robots.get(name);
    if (!robot) {
      robot = newRobot(name);
      dash.robots.set(name, robot);
      addFleetRow(robot);
    }
    robot.hb = hb;
    robot.hbAt = performance.now();
    count(robot, "heartbeat");
    updateRow(robot, robot.hbAt);
    if (!dash.selected) selectRobot(name);
    else if (dash.selected === name) updateBanner(robot);
  }

  function count(robot, key) {
    let r = robot.rates.get(key);
    if (!r) { r = { n: 0, prevN: 0, hz: 0, last: 0, row: null }; robot.rates.set(key, r); }
    r.n += 1;
    r.last = performance.now();
  }

  function onState(robot, name, payload) {
    count(robot, name);
    if (name === "robot_status") {
      const env = parse(payload);
      if (env && env.payload) robot.status = env.payload;
      return;
    }
    if (dash.selected !== robot.name) return;  // other robots: counted, not parsed
    if (name === "global_motion") {
      const m = parse(payload);
      const p = m && (m.payload || m);
      if (!p || typeof p.x !== "number" || typeof p.y !== "number") return;
      robot.pose = { x: p.x, y: p.y, yaw: typeof p.yaw === "number" ? p.yaw : 0, vx: p.vx, wz: p.wz,
                     t: typeof p.time_boot_ms === "number" ? p.time_boot_ms : 0 };
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
      const m = parse(payload);
      const s = m && (m.payload || m);
      if (s && Array.isArray(s.ranges)) {
        robot.scan = s;
        dirty = true;
      }
    } else if (name === "gps_raw_info") {
      const m = parse(payload);
      const g = m && (m.payload || m);
      if (g && typeof g.lat === "number" && typeof g.lon === "number" && g.fix_type >= 2) {
        robot.gpsFix = g;
        robot.gps.push([g.lat, g.lon]);
        if (robot.gps.length > GPS_MAX) robot.gps.splice(0, robot.gps.length - GPS_MAX);
        drawGps(robot);
      }
    } else if (name === "image") {
      const m = parse(payload);
      const im = m && (m.payload || m);
      if (im && typeof im.data === "string" && /^[a-z0-9.+-]+$/i.test(im.format || "")) {
        ui.camera.src = `data:image/${im.format.toLowerCase()};base64,${im.data}`;
        show(ui.cameraBox, true);
      }
    } else if (name === "ack") {
      const m = parse(payload);
      const a = m && (m.payload || m);
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

  function onPersonal(name, robot, rest, payload, packet) {
    const kind = rest[0];
    if (kind === "access") {
      if (!robot) {  // the report can come before the heartbeat: keep it for the robot's first heartbeat
        robot = newRobot(name);
        dash.robots.set(name, robot);
        addFleetRow(robot);
      }
      const body = payload.length ? parse(payload) : null;
      robot.access = body && (body.role === "operator" || body.role === "viewer") ? body : null;
      if (robot.access && robot.access.role === "operator" && !dash.operatorAnywhere) {
        dash.operatorAnywhere = true;
        startPresence();
      }
      if (dash.selected === name) buildControls(robot);
      updateRow(robot, performance.now());
    } else if (kind === "error") {
      const e = parse(payload);
      if (!e || typeof e !== "object") { addLog(ui.errors, `${name}: unreadable error report`); return; }
      // reports naming another program of ours are theirs; reports naming none may be ours: shown
      if (e.client_id && e.client_id !== dash.clientId) return;
      const where = String(e.topic || "").split("/from/" + dash.user + "/").pop();
      addLog(ui.errors, `${name} refused ${where}: ${e.error}`, { robot: name });
      notice(`${name} refused ${where}: ${e.error}`);
    } else if (kind === "reply" && rest.length >= 2) {
      const r = parse(payload);
      if (!r || !dash.pendingCalls.has(r.id)) return;
      const call = dash.pendingCalls.get(r.id);
      clearTimeout(call.timer);
      dash.pendingCalls.delete(r.id);
      const text = r.result ? `${call.service}: ${JSON.stringify(r.values || {})}` : `${call.service} failed: ${r.error}`;
      ui.serviceResult.textContent = text;
      ui.serviceResult.dataset.result = r.result ? "ok" : "failed";
      if (!r.result) addLog(ui.errors, `${name} call ${call.service}: ${r.error}`, { robot: name });
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
    setText(c.session, hb && hb.session !== undefined ? String(hb.session) : "–");
    setText(c.age, hb ? `${((now - robot.hbAt) / 1000).toFixed(1)} s` : "–");
    const st = robot.status;
    setText(c.battery, st ? (st.battery_remaining >= 0 ? `${Math.round(st.battery_remaining)} %` : "?") +
      ` ${fmt(st.voltage_battery, 1)} V` : "–");
    setText(c.mode, hb ? (MODES[hb.mode] || String(hb.mode)) : "–");
    setText(c.owner, hb && hb.owner_id ? hb.owner_id : "–");
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
    show(ui.gpsBox, false);
    show(ui.cameraBox, false);
    ui.serviceResult.textContent = "";
    dash.waypoint = null;
    buildControls(robot);
    updatePose(robot);
    updateBanner(robot);
    for (const r of dash.robots.values()) updateRow(r, performance.now());
    dirty = true;
  }

  function isOperator(robot) { return Boolean(robot && robot.access && robot.access.role === "operator"); }

  function buildControls(robot) {
    const op = isOperator(robot);
    show(ui.controls, op);
    show(ui.estop, op);
    ui.estop.textContent = op ? `EMERGENCY STOP ${robot.name}` : "EMERGENCY STOP";
    show(ui.waypointLabel, op);
    if (!op) ui.waypointMode.checked = false;
    ui.viewerNote.textContent = robot.access === undefined
      ? "Waiting for this robot's access report (retained on to/<you>/access): no controls until it says you operate it."
      : robot.access === null ? "You have no access report from this robot: no controls."
      : op ? "" : `You are a ${robot.access.role} of ${robot.name}: you may watch it, not command it.`;
    show(ui.viewerNote, !op);
    const services = robot.access && Array.isArray(robot.access.services) ? robot.access.services : [];
    ui.services.replaceChildren();
    for (const svc of services) {
      const b = document.createElement("button");
      b.type = "button";
      b.textContent = svc;
      b.dataset.service = svc;
      b.title = `call ${svc} with empty arguments ({})`;
      b.addEventListener("click", () => callService(robot.name, svc, {}));
      ui.services.append(b);
    }
    show(ui.servicesBox, services.length > 0);
  }

  function updateBanner(robot) {
    const hb = robot.hb;
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
    if (p) {
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
      `fix ${fix.fix_type}D  sats ${fix.satellites_visible ?? "–"}`;
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
        body.append(rate.row);
      }
      setText(rate.row.cells[1], rate.hz.toFixed(1));
      setText(rate.row.cells[2], `${((now - rate.last) / 1000).toFixed(1)} s ago`);
      rate.row.dataset.hz = rate.hz.toFixed(1);
    }
  }

  // ---------------------------------------------------------------------------------------------- commands
  // Every command goes through here: refused at once (and said so) when the page knows the broker would drop it.
  function command(robotName, name, payload, messageId) {
    const robot = dash.robots.get(robotName);
    if (!dash.client || !dash.connected) { notice(`not sent (${name}): not connected to the broker`); return false; }
    if (!isOperator(robot)) {
      const why = `not sent (${name}): ${dash.user} is ${robot && robot.access ? "a " + robot.access.role : "not an operator"} ` +
        `of ${robotName}; the broker would drop it`;
      addLog(ui.errors, why, { robot: robotName });
      notice(why);
      return false;
    }
    if (!dash.commanding) {  // from now on this client's leaving stops the robot: say so before the command
      dash.commanding = true;
      beat();
    }
    const body = { message_id: messageId, sequence_number: nextSeq(), client_id: dash.clientId, payload };
    dash.client.publish(topic(robotName, "from", dash.user, "cmd", name), JSON.stringify(body), { qos: name === "twist" ? 0 : 1 });
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
    dash.client.publish(topic(robotName, "from", dash.user, "call", service),
                        JSON.stringify({ id, args, client_id: dash.clientId }), { qos: 1 });
  }
  dash.callService = callService;

  function onPlotClick(ev) {
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
    if (target && (target.tagName === "INPUT" && target.type !== "range" && target.type !== "checkbox")) return;
    if (ui.controls.hidden) return;
    if (ev.key === " ") { ev.preventDefault(); dash.heldKeys.clear(); stopDriving(true); return; }
    const dir = KEYS[ev.key];
    if (!dir) return;
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
  ui.arm.addEventListener("click", arm);
  ui.plot.addEventListener("click", onPlotClick);
  ui.loginForm.addEventListener("submit", connect);
  ui.logout.addEventListener("click", logout);

  setInterval(() => {
    const now = performance.now();
    for (const r of dash.robots.values()) updateRow(r, now);
    const robot = dash.selected && dash.robots.get(dash.selected);
    if (robot) updateBanner(robot);
    show(ui.fleetEmpty, dash.robots.size === 0);
  }, 500);
  setInterval(() => updateRates(performance.now()), 1000);
  requestAnimationFrame(frame);
  loadConfig();
})();
