// Reading what arrives, as the SDK reads it: bodies (body.mjs) and ROSLink messages (message.mjs) from the
// protocol's declarations (protocol.mjs, generated). Pure: no page, no MQTT; tests/js/model.test.mjs uses it.
import { ROSLINK } from "./protocol.mjs";
import { readBody } from "./body.mjs";
import { readMessage } from "./message.mjs";

export const { STALE_AFTER_MS, STATUS, MODES, LOGIN_WAIT_MS, DESCRIPTION_ENTRIES } = ROSLINK.constants;
export const KINDS = ROSLINK.topics.kinds;  // what a parsed topic is: heartbeat, state, from, to, operator
const BODIES = ROSLINK.bodies;
const { envelope: ENVELOPE, specs: MESSAGES } = ROSLINK.messages;
const decoder = new TextDecoder();

// a refused CONNACK's return code → why, worded as the CLI and the SDK word it (roslink_mqtt/mqtt.py)
export const CONNACK = Object.fromEntries(Object.entries(ROSLINK.constants.CONNACK)
  .map(([code, why]) => [code, `login refused: ${why}`]));

/** JSON bytes (or text) → a value; undefined when it is not JSON. */
export function parse(payload) {
  try { return JSON.parse(typeof payload === "string" ? payload : decoder.decode(payload)); } catch (e) { return undefined; }
}

/** One body, named as in docs/protocol.md ("control state" → control_state): its declared fields, or null. */
export const read = (name, payload) => readBody(BODIES[name], parse(payload));

/** One ROSLink message (heartbeat, global_motion, ack …), read as the SDK decodes it: its payload, or null. */
export const message = (name, payload) => readMessage(MESSAGES[name], parse(payload), ENVELOPE);

/** The robot's description with every entry read from its declaration (an unreadable entry is left out). */
export function readDescription(payload) {
  const d = read("robot_description", payload);
  if (d) for (const [key, body] of Object.entries(DESCRIPTION_ENTRIES)) {
    d[key] = d[key].map((e) => readBody(BODIES[body], e)).filter(Boolean);
  }
  return d;
}
