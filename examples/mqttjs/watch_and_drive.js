#!/usr/bin/env node
// Watch a robot and drive it with plain MQTT.js: no SDK, only the wire protocol of docs/protocol.md.
//
//   npm install mqtt          (in this repository `make install` puts it in node_modules/)
//   ROSLINK_URL=mqtt://127.0.0.1:1883 ROSLINK_USERNAME=alice ROSLINK_PASSWORD=alice-demo \
//       node examples/mqttjs/watch_and_drive.js --robot turtle1 --seconds 2 --speed 0.2
//
// What it does, in protocol order:
//   1. connects with a last-will that clears its operator heartbeat (empty, retained, QoS 1) and publishes a
//      retained heartbeat on roslink/operators/<user>/<client_id> once a second (status 3 = watching);
//   2. prints the robot's heartbeat and position (state/global_motion), error reports meant for it and acks;
//   3. once the robot is online: switches its heartbeat to 4 (commanding), sends a twist 10 times a second for
//      --seconds (the robot's dead-man stops it when twists stop for 1 s), then a zero twist;
//   4. signs off: a heartbeat saying 7 (leaving on purpose), then the empty retained message, and exits.
// Exit status: 0 when the robot was driven and nothing was refused, 1 otherwise.
'use strict';

const crypto = require('crypto');
const mqtt = require('mqtt');

function parseArgs(argv) {
  const opts = {
    url: process.env.ROSLINK_URL || 'mqtt://127.0.0.1:1883',
    username: process.env.ROSLINK_USERNAME || 'alice',
    password: process.env.ROSLINK_PASSWORD,
    robot: 'turtle1', seconds: 2, speed: 0.2, turn: 0, wait: 10,
  };
  const names = { '--url': 'url', '-u': 'username', '--username': 'username', '--robot': 'robot',
    '--seconds': 'seconds', '--speed': 'speed', '--turn': 'turn', '--wait': 'wait' };
  for (let i = 0; i < argv.length; i += 2) {
    const key = names[argv[i]];
    if (!key || i + 1 >= argv.length) {
      console.error(`usage: watch_and_drive.js [--url URL] [-u USER] [--robot NAME] [--seconds S] [--speed M/S] ` +
        `[--turn RAD/S] [--wait S]   (password in ROSLINK_PASSWORD)`);
      process.exit(2);
    }
    opts[key] = ['seconds', 'speed', 'turn', 'wait'].includes(key) ? Number(argv[i + 1]) : argv[i + 1];
  }
  if (!opts.password) {
    console.error('set ROSLINK_PASSWORD (the password is never taken on the command line)');
    process.exit(2);
  }
  for (const key of ['seconds', 'speed', 'turn', 'wait']) {
    if (!Number.isFinite(opts[key])) {
      console.error(`--${key}: not a number`);
      process.exit(2);
    }
  }
  return opts;
}

const opts = parseArgs(process.argv.slice(2));
const user = opts.username;
const clientId = `${user}-mqttjs-${crypto.randomBytes(8).toString('hex')}`;
const base = `roslink/${opts.robot}`;
const presenceTopic = `roslink/operators/${user}/${clientId}`;
const STATUS = { 0: 'uninit', 1: 'boot', 2: 'calibrating', 3: 'standby', 4: 'active', 5: 'critical',
  6: 'emergency', 7: 'power-off', 8: 'offline' };

// A ROSLink envelope (docs/protocol.md, "The envelope"); system_id is free for clients.
function envelope(messageId, sequenceNumber, payload, extra = {}) {
  return JSON.stringify({ roslink_version: 2, ros_version: 24, system_id: 0, message_id: messageId,
    sequence_number: sequenceNumber, payload, ...extra });
}

// Operator presence: ROSLink heartbeat (message 0) naming this client; 3 = watching, 4 = commanding, 7 = leaving.
let heartbeatSeq = 0;
let presenceStatus = 3;
function operatorHeartbeat(status) {
  heartbeatSeq = (heartbeatSeq + 1) % 2 ** 32;
  return envelope(0, heartbeatSeq, { type: 0, name: clientId, system_status: status, owner_id: user, mode: 0 });
}

// Command sequence numbers: the wall clock in ms, or the previous number + 1 (docs/protocol.md, "Sequence numbers").
let lastSeq = null;
function nextSequence() {
  let now = Date.now() % 2 ** 32;
  if (lastSeq !== null) {
    const ahead = (now - lastSeq + 2 ** 32) % 2 ** 32;
    if (ahead === 0 || ahead >= 2 ** 31) now = (lastSeq + 1) % 2 ** 32;
  }
  lastSeq = now;
  return now;
}
function twist(lx, az) {
  return envelope(100, nextSequence(), { lx, ly: 0, lz: 0, ax: 0, ay: 0, az }, { client_id: clientId });
}

const client = mqtt.connect(opts.url, {
  clientId, username: user, password: opts.password, protocolVersion: 4, clean: true, keepalive: 5,
  reconnectPeriod: 0, connectTimeout: 10000,
  will: { topic: presenceTopic, payload: Buffer.alloc(0), qos: 1, retain: true },
});

let robotOnline = false;
let role = null;
let refusals = 0;
let lastPositionPrint = 0;
let beating = null;
let driving = false; // twists went out and no zero twist yet
let exiting = false; // finish() has begun: stop driving, sign off, exit

function beat() {
  client.publish(presenceTopic, operatorHeartbeat(presenceStatus), { qos: 1, retain: true });
}

client.on('connect', () => {
  console.log(`connected to ${opts.url} as ${user} (client id ${clientId})`);
  beat();
  beating = setInterval(beat, 1000);
  client.subscribe([`${base}/to/${user}/#`, `${base}/heartbeat`, `${base}/state/global_motion`, `${base}/state/ack`],
    { qos: 1 }, (err, granted) => {
      if (err || granted.some((g) => g.qos === 0x80)) {
        console.error(`subscription refused: ${err ? err.message : 'not granted'}`);
        finish(1);
      }
    });
});

client.on('error', (err) => {
  if (exiting) return;
  // CONNACK 4 and 5: what roslink-mqtt's CLI, SDK and dashboard say too
  const why = err.code === 4 || err.code === 5 ? 'wrong username or password' : err.message;
  console.error(client.connected ? `MQTT error: ${why}` : `cannot connect to ${opts.url} as ${user}: ${why}`);
  finish(1);
});
client.on('close', () => {
  if (!exiting) {
    console.error('connection closed');
    finish(1);
  }
});

client.on('message', (topic, buf) => {
  if (buf.length === 0) return; // a cleared retained message
  let msg;
  try {
    msg = JSON.parse(buf.toString('utf8'));
  } catch (e) {
    console.log(`${topic}: not JSON (${buf.length} bytes)`);
    return;
  }
  if (topic === `${base}/heartbeat`) {
    const p = msg.payload;
    robotOnline = p.system_status !== 8;
    console.log(`heartbeat ${p.name}: ${STATUS[p.system_status] || p.system_status} (status ${p.system_status}), ` +
      `owner '${p.owner_id}', session ${p.session}`);
  } else if (topic === `${base}/state/global_motion`) {
    const now = Date.now();
    if (now - lastPositionPrint >= 500) { // it arrives at ~20 Hz: print twice a second
      lastPositionPrint = now;
      const p = msg.payload;
      console.log(`position ${opts.robot}: x=${p.x.toFixed(2)} y=${p.y.toFixed(2)} ` +
        `yaw=${(p.yaw * 180 / Math.PI).toFixed(0)}° vx=${p.vx.toFixed(2)}`);
    }
  } else if (topic === `${base}/state/ack`) {
    console.log(`ack: command ${msg.payload.command}, result ${msg.payload.result} ${msg.payload.text}`);
  } else if (topic === `${base}/to/${user}/access`) {
    role = msg.role;
    console.log(`access: ${msg.role}, services ${msg.services.join(', ')}`);
  } else if (topic === `${base}/to/${user}/error`) {
    // Reports naming another program of ours are not ours; reports without an id may be (docs/protocol.md, Errors).
    if (msg.client_id !== undefined && msg.client_id !== clientId) return;
    refusals += 1;
    console.log(`refused: ${msg.error} (on ${msg.topic})`);
  }
});

function sleep(ms) {
  return new Promise((resolve) => setTimeout(resolve, ms));
}

function publish(topic, payload, options) {
  return new Promise((resolve, reject) => client.publish(topic, payload, options,
    (err) => (err ? reject(err) : resolve())));
}

async function drive() {
  const deadline = Date.now() + opts.wait * 1000;
  while (!robotOnline && Date.now() < deadline && !exiting) await sleep(50);
  if (exiting) return;
  if (!robotOnline) {
    console.error(`${opts.robot} is not online (no heartbeat within ${opts.wait} s)`);
    return finish(1);
  }
  if (role === 'viewer') {
    console.error(`${user} only views ${opts.robot}: the broker would drop its commands`);
    return finish(1);
  }
  presenceStatus = 4; // say "commanding" before the first command, on the same connection
  beat();
  const topic = `${base}/from/${user}/cmd/twist`;
  const count = Math.round(opts.seconds * 10);
  console.log(`driving ${opts.robot}: lx=${opts.speed} az=${opts.turn} for ${opts.seconds} s (${count} twists at 10 Hz)`);
  driving = true;
  const start = Date.now();
  for (let i = 0; i < count && !exiting; i++) {
    client.publish(topic, twist(opts.speed, opts.turn), { qos: 0 }); // a stream that repeats itself: QoS 0
    const next = start + (i + 1) * 100;
    await sleep(Math.max(0, next - Date.now()));
  }
  if (exiting) return;
  await publish(topic, twist(0, 0), { qos: 1 });
  driving = false;
  console.log(`sent ${count} twists, then stop`);
  await sleep(700); // see the robot stand still and any refusal of our commands
  finish(refusals ? 1 : 0);
}

async function finish(code) {
  if (exiting) return;
  exiting = true;
  if (beating) clearInterval(beating);
  if (client.connected) {
    try {
      if (driving) await publish(`${base}/from/${user}/cmd/twist`, twist(0, 0), { qos: 1 });
      await publish(presenceTopic, operatorHeartbeat(7), { qos: 1 }); // leaving on purpose ...
      await publish(presenceTopic, Buffer.alloc(0), { qos: 1, retain: true }); // ... then clear, as the will would
    } catch (e) {
      console.error(`sign-off failed: ${e.message}`);
    }
  }
  client.end(false, () => process.exit(code));
  setTimeout(() => process.exit(code), 2000).unref();
}

process.on('SIGINT', () => {
  console.log('interrupted: stopping the robot');
  finish(130);
});

client.once('connect', () => {
  drive().catch((e) => {
    console.error(e);
    finish(1);
  });
});
