// The dashboard's body reader (roslink_mqtt/dashboard/static/body.mjs) reads every case as Python's lenient reader
// does. The cases come from tests/unit/test_dashboard_js.py (ROSLINK_BODY_CASES names the file it wrote).
import test from "node:test";
import assert from "node:assert";
import fs from "node:fs";

import { ROSLINK } from "../../roslink_mqtt/dashboard/static/protocol.mjs";
import { readBody } from "../../roslink_mqtt/dashboard/static/body.mjs";

const casesFile = process.env.ROSLINK_BODY_CASES;

test("every body is declared", () => {
  assert.ok(Object.keys(ROSLINK.bodies).includes("control_state"));
  assert.strictEqual(ROSLINK.constants.STATUS[8], "offline");
});

test("each case reads as Python reads it", { skip: !casesFile && "run through tests/unit/test_dashboard_js.py" }, () => {
  const cases = JSON.parse(fs.readFileSync(casesFile, "utf8"));
  assert.ok(cases.length > 100);
  for (const c of cases) {
    assert.deepStrictEqual(readBody(ROSLINK.bodies[c.body], c.input), c.expected,
                           `${c.body}: ${JSON.stringify(c.input)}`);
  }
});
