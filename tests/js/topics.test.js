// The page's topic tree (roslink_mqtt/dashboard/static/topics.js) builds and parses every case as
// roslink_mqtt/topics.py does. The cases come from tests/unit/test_dashboard_js.py (ROSLINK_TOPIC_CASES).
"use strict";
const test = require("node:test");
const assert = require("node:assert");
const fs = require("node:fs");
const path = require("node:path");

const { TopicTree, leafOf, paramEventsNode } = require(path.join(__dirname, "..", "..", "roslink_mqtt", "dashboard", "static",
                                                "topics.js"));
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
