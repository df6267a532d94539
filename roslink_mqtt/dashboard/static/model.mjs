// What the page knows about each robot, and what it derives from it: presence, who drives, the trail, the time
// series, the link's quality and how urgently a robot needs attention. Pure (no page, no MQTT, no clock of its
// own: every function takes `now`), so tests/js/model.test.mjs checks it under node.
import { STALE_AFTER_MS, STATUS } from "./decode.mjs";

export const TRAIL_MAX = 3000;       // trail points kept per robot while the page is open (~5 min at 10 Hz)
export const TRAIL_STEP_M = 0.01;    // a pose closer than this to the last trail point adds none
export const GPS_MAX = 300;
export const RECENT_MAX = 30;        // poses kept to place each scan where it was taken (3 s at 10 Hz)
export const SERIES_MAX = 1200;      // samples kept per time series (10 min at 2 Hz)
export const SERIES_PERIOD_MS = 500; // one sample per series at most this often
const EMERGENCY = STATUS.indexOf("emergency");
const OFFLINE = STATUS.indexOf("offline");
const CRITICAL = STATUS.indexOf("critical");

/** A fixed-size time series: (ms, value) pairs, the oldest dropped; arrays for the chart library on demand. */
export class Series {
  constructor(max = SERIES_MAX) {
    this.max = max;
    this.t = [];
    this.v = [];
  }

  push(t, v) {
    const last = this.t.length - 1;
    if (last >= 0 && t - this.t[last] < SERIES_PERIOD_MS) {  // a burst: the latest value stands for the period
      this.v[last] = v;
      return;
    }
    this.t.push(t);
    this.v.push(v);
    if (this.t.length > this.max) {
      this.t.splice(0, this.t.length - this.max);
      this.v.splice(0, this.v.length - this.max);
    }
  }

  get length() { return this.t.length; }
  last() { return this.v.length ? this.v[this.v.length - 1] : null; }
}

export const SERIES = ["battery", "speed", "link"];  // what each robot keeps over time (the robot view's charts)

export function newRobot(name) {
  return {
    name, hb: null, hbAt: 0, status: null, access: undefined, control: undefined, link: null,
    rates: new Map(), pose: null, recent: [], trail: [], scan: null, gps: [], gpsFix: null, poses: 0,
    description: null, descRaw: "", lastGoals: new Map(), blocked: false, failsafe: null, lastError: null,
    series: Object.fromEntries(SERIES.map((k) => [k, new Series()])),
  };
}

/** online, stale (no heartbeat for STALE_AFTER_MS), offline (the bridge said goodbye) or unseen. */
export function presenceOf(robot, now, staleAfter = STALE_AFTER_MS) {
  if (!robot.hb) return "unseen";
  if (robot.hb.system_status === OFFLINE) return "offline";
  return now - robot.hbAt > staleAfter ? "stale" : "online";
}

export const isBlocked = (robot) => Boolean(robot && robot.hb && robot.hb.system_status === EMERGENCY);

export function fmt(v, digits) { return typeof v === "number" && Number.isFinite(v) ? v.toFixed(digits) : "–"; }

/** A bridge's session is the time it started (s since the epoch): shown as a time of day, not a number. */
/** "07:31:12": every time of day the page shows, one way (24 h, the browser's locale otherwise). */
export function clock(ms) { return new Date(ms).toLocaleTimeString([], { hour12: false }); }

export function sessionText(session) {
  return session > 1e9 ? `since ${clock(session * 1000)}` : String(session);
}

export function isOperator(robot) { return Boolean(robot && robot.access && robot.access.role === "operator"); }
export function mayStop(robot) { return isOperator(robot) || Boolean(robot && robot.access && robot.access.estop); }
export function mayUse(robot, who) { return who === "viewers" ? Boolean(robot.access) : isOperator(robot); }

/** "alice since 12:03:05" from the robot's state/control (the heartbeat's owner_id says only who). */
export function driverText(robot) {
  const c = robot.control;
  if (c && typeof c.holder === "string") {
    const since = typeof c.since === "number" ? clock(c.since * 1000) : "?";
    return `${c.holder}${c.supervisor ? " (supervisor)" : ""} since ${since}`;
  }
  if (c && c.holder === null) return "";
  return robot.hb && robot.hb.owner_id ? robot.hb.owner_id : "";
}

export function heldByOther(robot, user) {
  return Boolean(robot && robot.control && typeof robot.control.holder === "string" && robot.control.holder !== user);
}

/** battery_remaining in percent, or null when the robot does not report it (-1) or sent no status. */
export function batteryOf(robot) {
  const st = robot.status;
  return st && typeof st.battery_remaining === "number" && st.battery_remaining >= 0 ? st.battery_remaining : null;
}

/** The share of what the robot offers that its uplink carries (1 = every stream at its rate), or null. */
export function linkQuality(link) {
  if (!link || !link.streams) return null;
  let offered = 0, sent = 0;
  for (const s of Object.values(link.streams)) {
    if (!s || !(s.offered_hz > 0)) continue;
    offered += s.offered_hz;
    sent += Math.min(s.sent_hz > 0 ? s.sent_hz : 0, s.offered_hz);
  }
  return offered > 0 ? sent / offered : 1;
}

/** "uplink 244 kbit/s — range_finder_data 3.9 of 5 Hz (2 superseded)": the streams its link cannot carry at
 * their rate, so a slow scan on a thin link reads as what it is rather than as a fault. */
export function uplinkText(link) {
  if (!link) return "";
  const behind = Object.entries(link.streams)
    .filter(([, s]) => s && s.offered_hz > 0 && s.sent_hz + 0.05 < s.offered_hz)
    .map(([n, s]) => `${n} ${Number(s.sent_hz).toFixed(1)} of ${Number(s.offered_hz).toFixed(1)} Hz` +
         (s.superseded ? ` (${s.superseded} superseded)` : ""));
  // unmeasured: the link never filled, so the rate is only what was sent (on loopback, not a capacity)
  const rate = Math.round(link.rate_kbit_s);
  const path = link.path && link.path.steering ? link.path : null;  // a queue hidden beyond the robot, found
  let head = link.measured || path ? `uplink ${rate} kbit/s` : `uplink never full (${rate} kbit/s sent; capacity not measured)`;
  if (path) {
    head += ` (its queue hidden beyond the robot: ${Math.round(path.queue_ms)} ms; round trip ` +
      `${Math.round(path.rtt_ms)} ms, base ${Math.round(path.base_ms)} ms)`;
  }
  return `${head} — ` + (behind.length ? behind.join(", ") : "every stream at its rate");
}

/** A new position (global_motion): the latest pose, the recent ones (for scans), the trail, the speed series. */
export function addPose(robot, p, now) {
  robot.pose = { x: p.x, y: p.y, yaw: p.yaw, vx: p.vx, wz: p.wz, t: p.time_boot_ms };
  robot.poses += 1;
  robot.recent.push(robot.pose);
  if (robot.recent.length > RECENT_MAX) robot.recent.shift();
  const last = robot.trail[robot.trail.length - 1];
  if (!last || Math.hypot(last[0] - p.x, last[1] - p.y) > TRAIL_STEP_M) {
    robot.trail.push([p.x, p.y]);
    if (robot.trail.length > TRAIL_MAX) robot.trail.splice(0, robot.trail.length - TRAIL_MAX);
  }
  robot.series.speed.push(now, Math.abs(p.vx));
}

export function addStatus(robot, status, now) {
  robot.status = status;
  const b = batteryOf(robot);
  if (b !== null) robot.series.battery.push(now, b);
}

export function addLink(robot, link, now) {
  robot.link = link;
  const q = linkQuality(link);
  if (q !== null) robot.series.link.push(now, Math.round(q * 100));
}

export function addGps(robot, g) {
  robot.gpsFix = g;
  robot.gps.push([g.lat, g.lon]);
  if (robot.gps.length > GPS_MAX) robot.gps.splice(0, robot.gps.length - GPS_MAX);
}

/** The pose when a scan was taken (both carry their ROS header stamp), interpolated between the poses before and
 * after it, so a turning robot's scan is drawn where it was measured. Null (use the latest pose) when the stamps
 * are missing or far apart. */
export function poseAt(robot, ms) {
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

/** Count one message of a topic (for the rates table) and keep the latest (for the state inspector). */
export function count(robot, key, payload, now) {
  let r = robot.rates.get(key);
  if (!r) { r = { n: 0, prevN: 0, prevAt: 0, hz: 0, last: 0, payload: null }; robot.rates.set(key, r); }
  r.n += 1;
  r.last = now;
  r.payload = payload || null;
}

/** Each topic's rate over the time since the last call (called once a second). */
export function updateRates(robots, now) {
  for (const robot of robots) {
    for (const rate of robot.rates.values()) {
      rate.hz = (rate.n - rate.prevN) / ((now - (rate.prevAt || now - 1000)) / 1000 || 1);
      rate.prevN = rate.n;
      rate.prevAt = now;
    }
  }
}

/** A command's sequence number: the wall clock in ms, or the previous + 1 when the clock has not moved on, so the
 * page and the user's other programs share one timeline per command topic (docs/protocol.md). */
export class SequenceClock {
  constructor() { this.last = 0; }
  next(nowMs) {
    const now = nowMs % 4294967296;
    const ahead = (now - this.last + 4294967296) % 4294967296;
    this.last = ahead > 0 && ahead < 2147483648 ? now : (this.last + 1) % 4294967296;
    return this.last;
  }
}

export const LEVELS = ["ok", "note", "warning", "critical"];
export const LOW_BATTERY = 20;  // percent: the attention list's default line (the alert rules have their own)

/** How urgently a robot needs someone: {level 0..3, reasons[]}, from what the page knows of it at `now`. */
export function attentionOf(robot, now, lowBattery = LOW_BATTERY) {
  const reasons = [];
  let level = 0;
  const raise = (l, why) => { level = Math.max(level, l); reasons.push(why); };
  const presence = presenceOf(robot, now);
  if (presence === "stale") raise(3, `no heartbeat for ${((now - robot.hbAt) / 1000).toFixed(0)} s`);
  if (presence === "offline") raise(2, "offline");
  if (presence === "unseen") raise(1, "no heartbeat yet");
  if (isBlocked(robot)) raise(3, "motion blocked (emergency stop)");
  if (robot.hb && robot.hb.system_status === CRITICAL) raise(3, "status critical");
  if (robot.failsafe && now - robot.failsafe.at < 60000) raise(3, `failsafe stop: ${robot.failsafe.text}`);
  const b = batteryOf(robot);
  if (b !== null && b < lowBattery) raise(b < lowBattery / 2 ? 3 : 2, `battery ${Math.round(b)} %`);
  const q = linkQuality(robot.link);
  if (q !== null && q < 0.5) raise(1, `uplink carries ${Math.round(q * 100)} % of its streams`);
  return { level, reasons };
}

/** Robots by urgency (most urgent first, then by name): what the fleet overview's attention list shows. */
export function attention(robots, now, lowBattery = LOW_BATTERY) {
  return [...robots].map((robot) => ({ robot, ...attentionOf(robot, now, lowBattery) }))
    .sort((a, b) => b.level - a.level || (a.robot.name < b.robot.name ? -1 : a.robot.name > b.robot.name ? 1 : 0));
}
