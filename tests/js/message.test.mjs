// The dashboard's message reader (roslink_mqtt/dashboard/static/message.mjs) reads every case as Python's
// decode_object does. The cases come from tests/unit/test_dashboard_js.py (ROSLINK_MESSAGE_CASES names the file).
import test from "node:test";
import assert from "node:assert";
import fs from "node:fs";

import { ROSLINK } from "../../roslink_mqtt/dashboard/static/protocol.mjs";
import { readMessage } from "../../roslink_mqtt/dashboard/static/message.mjs";

const casesFile = process.env.ROSLINK_MESSAGE_CASES;

test("each message reads as Python decodes it", { skip: !casesFile && "run through tests/unit/test_dashboard_js.py" },
  () => {
    const cases = JSON.parse(fs.readFileSync(casesFile, "utf8"));
    assert.ok(cases.length > 500);
    const { envelope, specs } = ROSLINK.messages;
    for (const c of cases) {
      assert.deepStrictEqual(readMessage(specs[c.message], c.input, envelope), c.expected,
                             `${c.message}: ${JSON.stringify(c.input)}`);
    }
  });
