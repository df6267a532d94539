// Reading what the user typed (roslink_mqtt/dashboard/static/forms.mjs): the value to send or why not.
import test from "node:test";
import assert from "node:assert";

import { FieldError, parseJsonField, parseNumber, parseParam, progressOf, short } from "../../roslink_mqtt/dashboard/static/forms.mjs";

test("numbers by ROS type: ranges, integers, finite; empty is the ROS default", () => {
  assert.strictEqual(parseNumber("a.b", "float64", " 1.5e3 "), 1500);
  assert.strictEqual(parseNumber("a", "int8", ""), undefined);
  assert.throws(() => parseNumber("a", "uint8", "256"), (e) => e instanceof FieldError && /out of range for uint8 \(0\.\.255\)/.test(e.message));
  assert.throws(() => parseNumber("a", "int32", "1.5"), /not an integer/);
  assert.throws(() => parseNumber("a", "float32", "1e999"), /not a finite number/);
  assert.throws(() => parseNumber("a", "float32", "NaN"), /is not a number/);
  assert.throws(() => parseNumber("a", "float32", "0x10"), /is not a number/);
});

test("JSON fields: arrays for T[], objects for messages, byte arrays as base64 text", () => {
  assert.deepStrictEqual(parseJsonField("p", "int32[]", true, "[1, 2]"), [1, 2]);
  assert.strictEqual(parseJsonField("p", "uint8[]", true, '"AAE="'), "AAE=");
  assert.throws(() => parseJsonField("p", "int32[]", true, "{}"), /expected a JSON array/);
  assert.throws(() => parseJsonField("p", "pose", false, "[1]"), /expected a JSON object/);
  assert.throws(() => parseJsonField("p", "pose", false, "{"), /not JSON/);
});

test("parameters by described type", () => {
  assert.strictEqual(parseParam("double", "1", "speed"), 1);
  assert.strictEqual(parseParam("integer", "7", "n"), 7);
  assert.throws(() => parseParam("integer", "7.5", "n"), /not an integer/);
  assert.strictEqual(parseParam("bool", "TRUE", "b"), true);
  assert.throws(() => parseParam("bool", "yes", "b"), /not true or false/);
  assert.strictEqual(parseParam("string", " x ", "s"), " x ");
  assert.strictEqual(parseParam("string", "", "s"), "");
  assert.throws(() => parseParam("double", " ", "speed"), /enter a value/);
  assert.deepStrictEqual(parseParam("double_array", "[1, 2]", "a"), [1, 2]);
  assert.throws(() => parseParam("double_array", "3", "a"), /expected a JSON array/);
  assert.strictEqual(parseParam("", "hello", "u"), "hello");
});

test("goal progress from feedback, and long values cut", () => {
  assert.strictEqual(progressOf({}, { progress: 40 }), 0.4);
  assert.strictEqual(progressOf({ order: 5 }, { sequence: [0, 1, 1] }), 0.4);
  assert.strictEqual(progressOf({}, { note: "x" }), null);
  assert.match(short("x".repeat(3000)), /… \(3002 characters\)$/);
});
