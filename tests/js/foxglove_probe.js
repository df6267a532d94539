// A Foxglove client for the gateway tests: @foxglove/ws-protocol's FoxgloveClient (what Foxglove's own WebSocket
// data source is built on) over the `ws` package. It does what the plan says, then prints one JSON line of what it saw.
//
//   node foxglove_probe.js ws://127.0.0.1:PORT PLAN_JSON
//
// PLAN_JSON: {"subscribe": [topic…], "seconds": S, "keep": {topic: N}, "call": {"service": name, "request": {…}},
//             "parameters": true, "twist": {"topic": name, "linear": x, "angular": z, "hz": H, "seconds": S},
//             "summary": true (lines for people instead of the JSON)}
"use strict";

const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, planText] = process.argv.slice(2);
const plan = JSON.parse(planText || "{}");
const seen = { serverInfo: null, channels: {}, services: {}, messages: {}, firstMessage: {}, status: [],
  callResponse: null, callFailure: null, parameters: null, errors: [], kept: {} };
const SUBPROTOCOL = process.env.FOXGLOVE_SUBPROTOCOL || "foxglove.sdk.v1";
const decoder = new TextDecoder();
const encoder = new TextEncoder();
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

async function waitFor(check, ms) {
  const end = Date.now() + ms;
  while (!check() && Date.now() < end) await sleep(20);
  return check();
}

// "summary": true — for people (docs/foxglove.md): one line per channel, with its message count and the last message
// cut to a line, instead of one JSON line with every schema in it (~15 kB).
function printSummary() {
  const server = seen.serverInfo ? seen.serverInfo.name : "no server info";
  console.log(`${server}: ${Object.keys(seen.channels).length} channels, ${Object.keys(seen.services).length} services`);
  for (const [topic, channel] of Object.entries(seen.channels).sort()) {
    const count = seen.messages[topic] || 0;
    const first = seen.firstMessage[topic];
    const sample = first === undefined ? "" : `  ${JSON.stringify(first).slice(0, 80)}`;
    console.log(`  ${topic}  ${channel.encoding}/${channel.schemaEncoding}  ${count} msg${sample}`);
  }
  for (const error of seen.errors) console.log(`  error: ${error}`);
}

async function main() {
  // The protocol's current name is foxglove.sdk.v1; older clients offer foxglove.websocket.v1 (ws-protocol's
  // FoxgloveClient.SUPPORTED_SUBPROTOCOL): the same messages. FOXGLOVE_SUBPROTOCOL says which this client offers.
  const client = new FoxgloveClient({ ws: new WebSocket(url, [SUBPROTOCOL]) });
  const byId = {};
  client.on("error", (err) => seen.errors.push(String(err && err.message ? err.message : err)));
  client.on("serverInfo", (info) => { seen.serverInfo = info; });
  client.on("status", (status) => seen.status.push(status.message));
  client.on("advertise", (channels) => {
    for (const channel of channels) {
      byId[channel.id] = channel.topic;
      seen.channels[channel.topic] = { encoding: channel.encoding, schemaName: channel.schemaName,
        schemaEncoding: channel.schemaEncoding, schema: channel.schema };
    }
  });
  client.on("advertiseServices", (services) => {
    for (const service of services) seen.services[service.name] = service;
  });
  const subscriptions = {};
  client.on("message", (event) => {
    const topic = subscriptions[event.subscriptionId];
    const text = decoder.decode(event.data);
    seen.messages[topic] = (seen.messages[topic] || 0) + 1;
    if (!(topic in seen.firstMessage)) seen.firstMessage[topic] = JSON.parse(text);
    const keep = (plan.keep || {})[topic] || 0;  // every message of this topic, up to this many
    if (keep) {
      const kept = (seen.kept[topic] = seen.kept[topic] || []);
      if (kept.length < keep) kept.push(JSON.parse(text));
    }
  });
  client.on("serviceCallResponse", (response) => {
    seen.callResponse = JSON.parse(decoder.decode(response.data));
  });
  client.on("serviceCallFailure", (failure) => { seen.callFailure = failure.message; });
  client.on("parameterValues", (event) => { seen.parameters = event.parameters; });

  const wanted = plan.subscribe || [];
  await waitFor(() => seen.serverInfo && wanted.every((t) => t in seen.channels), 15000);
  if (!seen.serverInfo) {  // refused (no or a wrong token, say) or nothing there: a failure, not an empty result
    console.error(`no serverInfo from ${url.replace(/token=[^&]*/, "token=…")}: ${seen.errors.join("; ")}`);
    process.exit(2);
  }
  for (const [id, topic] of Object.entries(byId)) {
    if (wanted.includes(topic)) subscriptions[client.subscribe(Number(id))] = topic;
  }
  if (plan.call) {
    await waitFor(() => plan.call.service in seen.services, 10000);
    const service = seen.services[plan.call.service];
    if (service) {
      client.sendServiceCallRequest({ serviceId: service.id, callId: 1, encoding: "json",
        data: encoder.encode(JSON.stringify(plan.call.request || {})) });
      await waitFor(() => seen.callResponse || seen.callFailure, 15000);
    }
  }
  if (plan.parameters) {
    client.getParameters([], "all");
    await waitFor(() => seen.parameters, 15000);
  }
  if (plan.twist) {
    const twist = plan.twist;
    const channel = client.advertise({ topic: twist.topic, encoding: "json", schemaName: "geometry_msgs/msg/Twist" });
    const message = encoder.encode(JSON.stringify({ linear: { x: twist.linear, y: 0, z: 0 },
      angular: { x: 0, y: 0, z: twist.angular } }));
    const end = Date.now() + twist.seconds * 1000;
    while (Date.now() < end) {
      client.sendMessage(channel, message);
      await sleep(1000 / twist.hz);
    }
    if (twist.hold) {
      // keep publishing until killed: the test kills the gateway under it
      console.log(JSON.stringify({ driving: true }));
      for (;;) { client.sendMessage(channel, message); await sleep(1000 / twist.hz); }
    }
  }
  await sleep((plan.seconds || 0) * 1000);
  if (plan.summary) printSummary(); else console.log(JSON.stringify(seen));
  client.close();
  setTimeout(() => process.exit(0), 200);
}

main().catch((err) => { console.error(err); process.exit(1); });
