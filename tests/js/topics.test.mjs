// The page's topic tree (roslink_mqtt/dashboard/static/topics.mjs) builds and parses every case as
// roslink_mqtt/topics.py does. The cases come from tests/unit/test_dashboard_js.py (ROSLINK_TOPIC_CASES).
import test from "node:test";
import assert from "node:assert";
import fs from "node:fs";

import { TopicTree, leafOf, paramEventsNode } from "../../roslink_mqtt/dashboard/static/topics.mjs";
const casesFile = process.env.ROSLINK_TOPIC_CASES;

test("each topic is built and read as Python does", { skip: !casesFile && "run through tests/unit/test_dashboard_js.py" },
     () => {
  const { built, parsed, paramEvents } = JSON.parse(fs.readFileSync(casesFile, "utf8"));
  assert.ok(built.length > 20 && parsed.length > 40);
  for (const c of built) {
    assert.strictEqual(new TopicTree(c.prefix)[c.fn](...c.args), c.expected, `${c.fn}(${c.args})`);
  }
  for (const c of parsed) {
    const got = new TopicTree(c.prefix).parse(c.topic);
    assert.deepStrictEqual(got, c.expected, c.topic);
    if (got) assert.strictEqual(leafOf(got), c.leaf, c.topic);
  }
  for (const c of paramEvents) assert.strictEqual(paramEventsNode(c.name), c.expected, c.name);
});
