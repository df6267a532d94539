// Reading ROSLink messages (heartbeat, global_motion, ack, …) as the SDK does: roslink_mqtt/protocol/codec.py's
// decode_object with the topic's message id, over the declarations generated into protocol.mjs (ROSLINK.messages).
// An envelope ({"message_id", "payload", header…}) or a bare payload; unknown fields, a header out of bounds or
// a payload field of the wrong type make the message unreadable (null), as they make Python raise ProtocolError;
// optional fields left out read as their defaults. tests/js/message.test.mjs checks it against what Python reads.

const isInt = (v) => typeof v === "number" && Number.isInteger(v);
const isNumber = (v) => typeof v === "number" && Number.isFinite(v);
const isObject = (v) => v !== null && typeof v === "object" && !Array.isArray(v);
const has = (o, k) => Object.prototype.hasOwnProperty.call(o, k);
const BASE64 = /^(?:[A-Za-z0-9+/]{4})*(?:[A-Za-z0-9+/]{2}==|[A-Za-z0-9+/]{3}=)?$/;
const MAX_LIST_ITEMS = 1000000;
const inBounds = (v, b) => isInt(v) && (!b || (v >= b[0] && v <= b[1]));
const list = (v) => Array.isArray(v) && v.length <= MAX_LIST_ITEMS;

// One payload field's value (Field.as_data(): {name, kind, required, default?, bounds?}) is as declared.
function fits(field, v) {
  switch (field.kind) {
    case "float": return isNumber(v);
    case "int": return inBounds(v, field.bounds);
    case "str": return typeof v === "string";
    case "bool": return typeof v === "boolean";
    case "float_list": return list(v) && v.every(isNumber);
    case "range_list": return list(v) && v.every((x) => x === null || isNumber(x));
    case "int_list": return list(v) && v.every((x) => inBounds(x, field.bounds));
    case "base64": return typeof v === "string" && BASE64.test(v);
    default: return false;
  }
}

// validate_payload: every declared field as declared, defaults for optional ones left out, nothing unknown.
function readPayload(spec, payload) {
  if (!isObject(payload)) return null;
  const out = {};
  for (const f of spec.fields) {
    if (has(payload, f.name)) {
      if (!fits(f, payload[f.name])) return null;
      out[f.name] = payload[f.name];
    } else if (f.required) {
      return null;
    } else {
      out[f.name] = Array.isArray(f.default) ? f.default.slice() : f.default;
    }
  }
  return Object.keys(payload).every((k) => has(out, k)) ? out : null;
}

// The header around a payload: known keys only, integers in their bounds, a client id of 1..max characters.
function headerFits(envelope, obj) {
  for (const [key, v] of Object.entries(obj)) {
    if (key === "payload") continue;
    if (key === envelope.client_id) {
      if (typeof v !== "string" || v.length < 1 || v.length > envelope.client_id_max) return false;
      continue;
    }
    const bounds = envelope.header[key];
    if (!bounds || !inBounds(v, bounds)) return false;
  }
  return true;
}

// The payload of one message the topic says is `spec` (ROSLINK.messages.specs[name]), or null.
function readMessage(spec, obj, envelope) {
  if (!isObject(obj)) return null;
  if (!has(obj, "message_id") && !has(obj, "payload")) return readPayload(spec, obj);  // a bare payload
  if (!headerFits(envelope, obj)) return null;
  if (has(obj, "message_id") && obj.message_id !== spec.id) return null;
  return has(obj, "payload") ? readPayload(spec, obj.payload) : null;
}

export { readMessage, readPayload };
