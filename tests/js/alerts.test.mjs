// The alert rules (roslink_mqtt/dashboard/static/alerts.mjs): raised once per episode, resolved, acknowledged.
import test from "node:test";
import assert from "node:assert";

import { STALE_AFTER_MS, STATUS } from "../../roslink_mqtt/dashboard/static/decode.mjs";
import { ALERTS_MAX, AlertBook, DEFAULT_RULES, conditionsOf, readRules } from "../../roslink_mqtt/dashboard/static/alerts.mjs";
import { addStatus, newRobot } from "../../roslink_mqtt/dashboard/static/model.mjs";

const robot = (name, word, at) => {
  const r = newRobot(name);
  r.hb = { system_status: STATUS.indexOf(word), owner_id: "", mode: 0 };
  r.hbAt = at;
  return r;
};

test("rules from storage: defaults for what is missing or of the wrong type, nothing unknown kept", () => {
  assert.deepStrictEqual(readRules(null), DEFAULT_RULES);
  const r = readRules({ battery_below: 35, stale: false, notify: "yes", evil: 1 });
  assert.strictEqual(r.battery_below, 35);
  assert.strictEqual(r.stale, false);
  assert.strictEqual(r.notify, DEFAULT_RULES.notify);
  assert.ok(!("evil" in r));
  assert.strictEqual(readRules({ battery_below: 1e9 }).battery_below, DEFAULT_RULES.battery_below);
  assert.strictEqual(readRules({ battery_below: Number.NaN }).battery_below, DEFAULT_RULES.battery_below);
});

test("conditions follow the rules: a rule turned off raises nothing", () => {
  const r = robot("r1", "active", 0);
  addStatus(r, { battery_remaining: 8 }, 0);
  const now = STALE_AFTER_MS + 1000;
  assert.deepStrictEqual(conditionsOf(r, DEFAULT_RULES, now).map((c) => [c.kind, c.severity]),
                         [["stale", "critical"], ["battery", "critical"]]);
  assert.deepStrictEqual(conditionsOf(r, { ...DEFAULT_RULES, stale: false, battery_below: 0 }, now), []);
  assert.deepStrictEqual(conditionsOf(robot("r2", "offline", 0), DEFAULT_RULES, 0).map((c) => c.kind), ["offline"]);
});

test("a condition is raised once per episode, resolved when it ends, raised again when it comes back", () => {
  const book = new AlertBook();
  const r = robot("r1", "active", 0);
  assert.deepStrictEqual(book.evaluate([r], DEFAULT_RULES, 1000), []);
  const late = STALE_AFTER_MS + 1000;
  assert.deepStrictEqual(book.evaluate([r], DEFAULT_RULES, late).map((a) => a.key), ["r1:stale#1"]);
  assert.deepStrictEqual(book.evaluate([r], DEFAULT_RULES, late + 500), []);  // the same episode: not again
  r.hbAt = late + 900;
  book.evaluate([r], DEFAULT_RULES, late + 1000);
  assert.strictEqual(book.alerts.get("r1:stale#1").active, false);
  assert.strictEqual(book.pending(), 1);  // resolved, still waiting for an acknowledgement
  assert.deepStrictEqual(book.evaluate([r], DEFAULT_RULES, late + 1000 + 2 * STALE_AFTER_MS).map((a) => a.key),
                         ["r1:stale#2"]);
});

test("acknowledged alerts stay acknowledged (a new book of the same session starts with the keys)", () => {
  const book = new AlertBook();
  const r = robot("r1", "active", 0);
  const late = STALE_AFTER_MS + 1000;
  book.evaluate([r], DEFAULT_RULES, late);
  book.acknowledge("r1:stale#1");
  assert.strictEqual(book.pending(), 0);
  const reloaded = new AlertBook([...book.acked]);
  assert.deepStrictEqual(reloaded.evaluate([r], DEFAULT_RULES, late), []);  // still going on: not raised again
  assert.strictEqual(reloaded.list()[0].key, "r1:stale#1");
  book.acknowledge("nonsense");
  assert.ok(!book.acked.has("nonsense"));
});

test("events (failsafe, errors) are raised once each, critical first in the list, bounded in number", () => {
  const book = new AlertBook();
  assert.ok(book.event("r1", "error", "r1 refused cmd/twist: too fast", 10, 10));
  assert.strictEqual(book.event("r1", "error", "again", 10, 10), null);
  const f = book.event("r1", "failsafe", "r1: failsafe stop", 20, 20);
  assert.strictEqual(f.severity, "critical");
  assert.deepStrictEqual(book.list().map((a) => a.kind), ["failsafe", "error"]);
  book.acknowledgeAll();
  assert.strictEqual(book.pending(), 0);
  for (let i = 0; i < ALERTS_MAX * 2; i += 1) book.event("r2", "error", `e${i}`, 100 + i, 100 + i);
  assert.strictEqual(book.alerts.size, ALERTS_MAX);
  assert.ok(book.alerts.has(`r2:error:${100 + ALERTS_MAX * 2 - 1}`));  // the newest kept
});
