// Alerts: conditions the operator asked to be told about (the page's settings), raised once per episode, shown
// until acknowledged; an acknowledged alert stays acknowledged for the session (the page keeps the keys in
// sessionStorage). Pure: the page feeds it robots and events; tests/js/alerts.test.mjs checks it under node.
import { batteryOf, presenceOf } from "./model.mjs";

export const DEFAULT_RULES = Object.freeze({
  battery_below: 20,  // percent; 0 turns the rule off
  stale: true,        // no heartbeat for the SDK's stale time
  offline: true,      // the bridge said goodbye
  failsafe: true,     // a failsafe stop (state/ack result 3)
  errors: true,       // a refusal or error report addressed to this page
  notify: false,      // also as browser notifications (asks the browser's permission)
});
export const ALERTS_MAX = 100;
const FORGET_MS = 10 * 60 * 1000;  // a resolved, acknowledged alert leaves the list after this
const EVENTS = new Set(["failsafe", "error"]);  // one-off alerts: never resolved, only acknowledged

/** Rules from settings as stored (JSON): unknown keys dropped, wrong types replaced by the defaults. */
export function readRules(stored) {
  const out = { ...DEFAULT_RULES };
  if (stored && typeof stored === "object") {
    for (const [k, v] of Object.entries(DEFAULT_RULES)) {
      if (typeof stored[k] === typeof v && (typeof v !== "number" || (Number.isFinite(stored[k]) && stored[k] >= 0 && stored[k] <= 100))) {
        out[k] = stored[k];
      }
    }
  }
  return out;
}

/** The conditions holding now for one robot under `rules`: [{kind, severity, text}]. */
export function conditionsOf(robot, rules, now) {
  const out = [];
  const presence = presenceOf(robot, now);
  if (rules.stale && presence === "stale") {
    out.push({ kind: "stale", severity: "critical", text: `${robot.name}: no heartbeat — its link or bridge is down` });
  }
  if (rules.offline && presence === "offline") {
    out.push({ kind: "offline", severity: "warning", text: `${robot.name} is offline (its bridge signed off)` });
  }
  const b = batteryOf(robot);
  if (rules.battery_below > 0 && b !== null && b < rules.battery_below) {
    out.push({ kind: "battery", severity: b < rules.battery_below / 2 ? "critical" : "warning",
               text: `${robot.name}: battery ${Math.round(b)} % (below ${rules.battery_below} %)` });
  }
  return out;
}

/** The page's alerts: raised, updated, resolved, acknowledged. */
export class AlertBook {
  constructor(acked = []) {
    this.alerts = new Map();      // key → {key, robot, kind, severity, text, since, active, resolvedAt}
    this.acked = new Set(acked);  // keys acknowledged this session
    this.episodes = new Map();    // robot:kind → how many times that condition began
  }

  #raise(key, robot, kind, severity, text, now, raised) {
    const a = { key, robot, kind, severity, text, since: now, active: true, resolvedAt: null };
    this.alerts.set(key, a);
    if (!this.acked.has(key)) raised.push(a);
    return a;
  }

  /** Every robot's conditions now: new ones raised (returned, for notifications), gone ones resolved. */
  evaluate(robots, rules, now) {
    const raised = [], seen = new Set();
    for (const robot of robots) {
      for (const c of conditionsOf(robot, rules, now)) {
        const base = `${robot.name}:${c.kind}`;
        seen.add(base);
        const key = `${base}#${this.episodes.get(base) || 0}`;
        const open = this.alerts.get(key);
        if (open && open.active) { open.text = c.text; open.severity = c.severity; continue; }
        const episode = (this.episodes.get(base) || 0) + 1;
        this.episodes.set(base, episode);
        this.#raise(`${base}#${episode}`, robot.name, c.kind, c.severity, c.text, now, raised);
      }
    }
    for (const a of this.alerts.values()) {
      if (a.active && !EVENTS.has(a.kind) && !seen.has(`${a.robot}:${a.kind}`)) {
        a.active = false;
        a.resolvedAt = now;
      }
    }
    this.#prune(now);
    return raised;
  }

  /** A one-off event (a failsafe stop, an error report): raised once under its own id; the list holds it until
   * acknowledged. Returns the alert when it is new and not acknowledged, else null. */
  event(robot, kind, text, now, id) {
    const key = `${robot}:${kind}:${id}`;
    if (this.alerts.has(key)) return null;
    const raised = [];
    this.#raise(key, robot, kind, EVENTS.has(kind) && kind !== "error" ? "critical" : "warning", text, now, raised);
    this.#prune(now);
    return raised[0] || null;
  }

  acknowledge(key) { if (this.alerts.has(key)) this.acked.add(key); }
  acknowledgeAll() { for (const a of this.alerts.values()) this.acked.add(a.key); }
  isAcked(a) { return this.acked.has(a.key); }

  /** Unacknowledged first (critical before warning, newest first), then acknowledged or resolved. */
  list() {
    const rank = (a) => (this.acked.has(a.key) ? 2 : 0) + (a.severity === "critical" ? 0 : 1);
    return [...this.alerts.values()].sort((a, b) => rank(a) - rank(b) || b.since - a.since);
  }

  /** How many alerts wait for an acknowledgement. */
  pending() { let n = 0; for (const a of this.alerts.values()) if (!this.acked.has(a.key)) n += 1; return n; }

  #prune(now) {
    for (const [key, a] of this.alerts) {
      const over = (a.active === false || EVENTS.has(a.kind)) && this.acked.has(key);
      if (over && now - (a.resolvedAt || a.since) > FORGET_MS) this.alerts.delete(key);
    }
    if (this.alerts.size > ALERTS_MAX) {
      const drop = this.list().reverse().slice(0, this.alerts.size - ALERTS_MAX);
      for (const a of drop) this.alerts.delete(a.key);
    }
  }
}
