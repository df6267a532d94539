// The page's model (roslink_mqtt/dashboard/static/model.mjs): presence, trail, series, link quality, attention.
import test from "node:test";
import assert from "node:assert";

import { STALE_AFTER_MS, STATUS } from "../../roslink_mqtt/dashboard/static/decode.mjs";
import { SERIES_MAX, SERIES_PERIOD_MS, SequenceClock, Series, TRAIL_MAX, addLink, addPose, addStatus, attention,
         attentionOf, driverText, heldByOther, linkQuality, newRobot, poseAt, presenceOf, sessionText,
         uplinkText } from "../../roslink_mqtt/dashboard/static/model.mjs";

const status = (word) => STATUS.indexOf(word);
const beat = (robot, word, at) => { robot.hb = { system_status: status(word), owner_id: "", mode: 0 }; robot.hbAt = at; };
const pose = (x, y, t = 0) => ({ x, y, yaw: 0, vx: 0.2, wz: 0, time_boot_ms: t });

test("presence: unseen, online, stale after the SDK's time, offline when the bridge signs off", () => {
  const r = newRobot("r1");
  assert.strictEqual(presenceOf(r, 0), "unseen");
  beat(r, "active", 1000);
  assert.strictEqual(presenceOf(r, 1000 + STALE_AFTER_MS), "online");
  assert.strictEqual(presenceOf(r, 1001 + STALE_AFTER_MS), "stale");
  beat(r, "offline", 1000);
  assert.strictEqual(presenceOf(r, 1e9), "offline");
});

test("the trail keeps moves over 1 cm, at most TRAIL_MAX points, and the speed series follows", () => {
  const r = newRobot("r1");
  addPose(r, pose(0, 0), 0);
  addPose(r, pose(0.005, 0), 10);  // under 1 cm: no new point
  assert.strictEqual(r.trail.length, 1);
  for (let i = 1; i <= TRAIL_MAX + 50; i += 1) addPose(r, pose(i * 0.1, 0), i * SERIES_PERIOD_MS);
  assert.strictEqual(r.trail.length, TRAIL_MAX);
  assert.deepStrictEqual(r.trail[TRAIL_MAX - 1], [(TRAIL_MAX + 50) * 0.1, 0]);
  assert.strictEqual(r.series.speed.last(), 0.2);
  assert.ok(r.series.speed.length <= SERIES_MAX);
});

test("a series keeps one sample per period (the latest) and drops the oldest past its size", () => {
  const s = new Series(3);
  s.push(0, 1);
  s.push(SERIES_PERIOD_MS - 1, 2);  // the same period: replaces
  assert.deepStrictEqual([s.t, s.v], [[0], [2]]);
  for (let i = 1; i <= 4; i += 1) s.push(i * SERIES_PERIOD_MS, 10 + i);
  assert.deepStrictEqual(s.v, [12, 13, 14]);
});

test("battery and link go into their series; unknown battery (-1) does not", () => {
  const r = newRobot("r1");
  addStatus(r, { battery_remaining: -1, voltage_battery: 12 }, 0);
  assert.strictEqual(r.series.battery.length, 0);
  addStatus(r, { battery_remaining: 55, voltage_battery: 12 }, 1000);
  assert.strictEqual(r.series.battery.last(), 55);
  addLink(r, { rate_kbit_s: 256, measured: true, streams: { a: { offered_hz: 10, sent_hz: 5 }, b: { offered_hz: 10, sent_hz: 10 } } }, 0);
  assert.strictEqual(r.series.link.last(), 75);
});

test("link quality: the share of offered messages the uplink carries; streams offering nothing do not count", () => {
  assert.strictEqual(linkQuality(null), null);
  assert.strictEqual(linkQuality({ streams: {} }), 1);
  assert.strictEqual(linkQuality({ streams: { a: { offered_hz: 0, sent_hz: 0 }, b: { offered_hz: 4, sent_hz: 8 } } }), 1);
  assert.strictEqual(linkQuality({ streams: { a: { offered_hz: 10, sent_hz: 2.5 } } }), 0.25);
  const text = uplinkText({ rate_kbit_s: 243.6, measured: false, streams: { scan: { offered_hz: 5, sent_hz: 3.9, superseded: 2 } } });
  assert.strictEqual(text, "uplink never full (244 kbit/s sent; capacity not measured) — scan 3.9 of 5.0 Hz (2 superseded)");
  assert.strictEqual(uplinkText({ rate_kbit_s: 243.6, measured: true, streams: {} }), "uplink 244 kbit/s — every stream at its rate");
  const hidden = { rate_kbit_s: 120.4, measured: false, streams: {},
                   path: { base_ms: 60, rtt_ms: 145.2, queue_ms: 85.2, rate_kbit_s: 120.4, cuts: 3, steering: true } };
  assert.strictEqual(uplinkText(hidden), "uplink 120 kbit/s (its queue hidden beyond the robot: 85 ms; round trip " +
                     "145 ms, base 60 ms) — every stream at its rate");
});

test("who drives: state/control's holder and since; the heartbeat's owner only without it", () => {
  const r = newRobot("r1");
  beat(r, "active", 0);
  r.hb.owner_id = "bob";
  assert.strictEqual(driverText(r), "bob");
  r.control = { holder: null, since: null, supervisor: false };
  assert.strictEqual(driverText(r), "");
  r.control = { holder: "alice", since: null, supervisor: true };
  assert.strictEqual(driverText(r), "alice (supervisor) since ?");
  assert.ok(heldByOther(r, "bob") && !heldByOther(r, "alice"));
});

test("a session is shown as a time of day, not a raw number", () => {
  assert.match(sessionText(1795636720), /^since \d/);
  assert.strictEqual(sessionText(7), "7");
});

test("a scan is placed at the pose interpolated to its stamp", () => {
  const r = newRobot("r1");
  addPose(r, { ...pose(0, 0, 1000), yaw: 0 }, 0);
  addPose(r, { ...pose(1, 0, 1100), yaw: 0.2 }, 100);
  const at = poseAt(r, 1050);
  assert.ok(Math.abs(at.x - 0.5) < 1e-9 && Math.abs(at.yaw - 0.1) < 1e-9);
  assert.strictEqual(poseAt(r, 5000), null);
  assert.strictEqual(poseAt(r, 0), null);
});

test("attention: stale and e-stopped robots first, then low battery and thin links; reasons said", () => {
  const now = 100000;
  const ok = newRobot("a-ok"); beat(ok, "active", now);
  const stale = newRobot("b-stale"); beat(stale, "active", now - STALE_AFTER_MS - 2000);
  const stopped = newRobot("c-stopped"); beat(stopped, "emergency", now);
  const low = newRobot("d-low"); beat(low, "active", now); addStatus(low, { battery_remaining: 15 }, now);
  const thin = newRobot("e-thin"); beat(thin, "active", now);
  addLink(thin, { streams: { a: { offered_hz: 10, sent_hz: 1 } } }, now);
  const order = attention([ok, thin, low, stopped, stale], now).map((a) => [a.robot.name, a.level]);
  assert.deepStrictEqual(order, [["b-stale", 3], ["c-stopped", 3], ["d-low", 2], ["e-thin", 1], ["a-ok", 0]]);
  assert.deepStrictEqual(attentionOf(low, now).reasons, ["battery 15 %"]);
  assert.strictEqual(attentionOf(low, now, 10).level, 0);
  low.failsafe = { at: now - 1000, text: "operator alice went away" };
  assert.strictEqual(attentionOf(low, now).level, 3);
});

test("sequence numbers follow the clock and never repeat when it stands still or steps back", () => {
  const c = new SequenceClock();
  assert.strictEqual(c.next(1000), 1000);
  assert.strictEqual(c.next(1000), 1001);
  assert.strictEqual(c.next(900), 1002);
  assert.strictEqual(c.next(5000), 5000);
  assert.strictEqual(c.next(4294967296 + 10), 5001);  // the wrap: 10 is "behind" 5000 by less than half the range
});
