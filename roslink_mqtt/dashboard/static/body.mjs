// Reading the robot's JSON bodies as a client does: the lenient reader of roslink_mqtt/protocol/body.py (read with
// strict=False), over the declarations generated into protocol.mjs. Unknown fields are ignored, a malformed field
// with a default takes it, a malformed field without one makes the body unreadable (null). tests/js/body.test.mjs
// checks it against what Python reads, case by case.

const isInt = (v) => typeof v === "number" && Number.isInteger(v);
const isObject = (v) => v !== null && typeof v === "object" && !Array.isArray(v);
const BAD = Symbol("bad");

// One value against one spec ({kind, …} as BodyField.as_data() writes it): the value, or BAD.
function check(spec, v) {
  switch (spec.kind) {
    case "string":
      return typeof v === "string" && v.length >= spec.min && (spec.max === null || v.length <= spec.max) ? v : BAD;
    case "integer":
      return isInt(v) && (spec.low === null || v >= spec.low) && (spec.high === null || v <= spec.high) ? v : BAD;
    case "number":
      if (typeof v !== "number" || !Number.isFinite(v)) return BAD;
      if (spec.low !== null && (spec.low_open ? v <= spec.low : v < spec.low)) return BAD;
      return spec.high === null || v <= spec.high ? v : BAD;
    case "boolean":
      return typeof v === "boolean" ? v : BAD;
    case "object":
      return isObject(v) && (spec.max === null || Object.keys(v).length <= spec.max) ? v : BAD;
    case "text_map":
      return isObject(v) && Object.values(v).every((s) => typeof s === "string") ? v : BAD;
    case "objects":
      return Array.isArray(v) && v.every(isObject) ? v : BAD;
    case "strings":
      return Array.isArray(v) && (spec.max === null || v.length <= spec.max) &&
        v.every((s) => typeof s === "string" && (s.length > 0 || !spec.non_empty)) ? v : BAD;
    case "choice":
    case "levels":
      return spec.values.includes(v) && (spec.kind === "choice" ? typeof v === "string" : isInt(v)) ? v : BAD;
    case "id":
      if (typeof v === "string") return v.length >= spec.min && v.length <= spec.max ? v : BAD;
      return isInt(v) && !spec.strings_only ? v : BAD;
    case "nullable":
      return v === null ? null : check(spec.inner, v);
    case "any":
      return v;
    default:
      return BAD;
  }
}

const fresh = (d) => (Array.isArray(d) ? d.slice() : isObject(d) ? { ...d } : d);

// The declared fields of one body (by its key in ROSLINK.bodies), or null when it cannot be read.
function readBody(fields, body) {
  if (!isObject(body)) return null;
  const out = {};
  for (const f of fields) {
    const has = Object.prototype.hasOwnProperty.call(body, f.name);
    const got = has ? check(f.spec, body[f.name]) : BAD;
    if (got !== BAD) out[f.name] = got;
    else if ("default" in f) out[f.name] = fresh(f.default);
    else if (f.required) return null;  // missing or malformed, and nothing to stand in for it
  }
  return out;
}

export { check, readBody, BAD };
