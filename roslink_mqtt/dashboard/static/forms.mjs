// Reading what the user typed into forms built from the robot's description (ROS field types) and parameter edit
// boxes: the value to send, or a FieldError naming the field and why. Pure; tests/js/forms.test.mjs.

export const INT_RANGE = {
  int8: [-128, 127], uint8: [0, 255], byte: [0, 255], char: [0, 255], int16: [-32768, 32767], uint16: [0, 65535],
  int32: [-2147483648, 2147483647], uint32: [0, 4294967295],
  int64: [-Number.MAX_SAFE_INTEGER, Number.MAX_SAFE_INTEGER], uint64: [0, Number.MAX_SAFE_INTEGER],
};
export const FLOATS = new Set(["float32", "float64", "float", "double"]);
export const NUMBER_RE = /^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$/;
export const SHOW_MAX = 2000;  // characters of a reply, feedback or result shown

export class FieldError extends Error {}

export const isLayout = (v) => Boolean(v) && typeof v === "object" && !Array.isArray(v);

/** A value as short JSON text for the page (long ones cut, with their length said). */
export function short(value) {
  let text;
  try { text = JSON.stringify(value); } catch (e) { text = String(value); }
  if (text === undefined) text = String(value);
  return text.length > SHOW_MAX ? `${text.slice(0, SHOW_MAX)} … (${text.length} characters)` : text;
}

/** A numeric ROS field's text → its number; undefined when empty (the ROS default). */
export function parseNumber(full, type, raw) {
  const text = raw.trim();
  if (!text) return undefined;
  if (!NUMBER_RE.test(text)) throw new FieldError(`${full}: "${text}" is not a number (${type})`);
  const n = Number(text);
  if (!Number.isFinite(n)) throw new FieldError(`${full}: ${text} is not a finite number (${type})`);
  const range = INT_RANGE[type];
  if (range) {
    if (!Number.isInteger(n)) throw new FieldError(`${full}: ${text} is not an integer (${type})`);
    if (n < range[0] || n > range[1]) throw new FieldError(`${full}: ${text} is out of range for ${type} (${range[0]}..${range[1]})`);
  }
  return n;
}

/** A JSON field's text → its value (an array for `T[]` types, an object for messages); undefined when empty. */
export function parseJsonField(full, type, isArray, raw) {
  const text = raw.trim();
  if (!text) return undefined;
  let v;
  try { v = JSON.parse(text); } catch (e) { throw new FieldError(`${full}: not JSON (${e.message})`); }
  const bytes = /^(uint8|byte|char)\[/.test(type);  // byte arrays travel as base64 strings
  if (isArray && !bytes && !Array.isArray(v)) throw new FieldError(`${full}: expected a JSON array (${type})`);
  if (!isArray && !isLayout(v)) throw new FieldError(`${full}: expected a JSON object (${type})`);
  return v;
}

/** The typed value of a parameter's edit box, from its described type (a double also takes "1"; a string takes
 * the text as is). */
export function parseParam(type, raw, name) {
  const text = raw.trim();
  if (text === "" && type !== "string") throw new FieldError(`${name}: enter a value`);
  const num = (int) => {
    if (!NUMBER_RE.test(text) || !Number.isFinite(Number(text))) throw new FieldError(`${name}: "${raw}" is not a number (${type})`);
    const n = Number(text);
    if (int && !Number.isSafeInteger(n)) throw new FieldError(`${name}: "${raw}" is not an integer (${type})`);
    return n;
  };
  if (type === "double") return num(false);
  if (type === "integer") return num(true);
  if (type === "bool") {
    if (/^(true|false)$/i.test(text)) return text.toLowerCase() === "true";
    throw new FieldError(`${name}: "${raw}" is not true or false (bool)`);
  }
  if (type === "string") return raw;
  let v;
  try { v = JSON.parse(text); } catch (e) {
    if (!type || type === "not_set") return raw;  // an untyped parameter: the text as a string
    throw new FieldError(`${name}: not a JSON array (${type})`);
  }
  if (type.endsWith("_array") && !Array.isArray(v)) throw new FieldError(`${name}: expected a JSON array (${type})`);
  return v;
}

export const GOAL_ENDED = new Set(["succeeded", "aborted", "canceled", "timeout", "failed", "rejected", "refused",
                                   "no-answer"]);

/** A goal's progress fraction, when its feedback says one: a numeric field named like progress/percent, or an
 * array growing towards the goal's only integer field (fibonacci: the sequence towards `order`). */
export function progressOf(goal, feedback) {
  if (!isLayout(feedback)) return null;
  for (const [k, v] of Object.entries(feedback)) {
    if (typeof v === "number" && /progress|percent|fraction/i.test(k) && v >= 0) return v > 1 ? Math.min(1, v / 100) : v;
  }
  const ints = isLayout(goal) ? Object.values(goal).filter((v) => Number.isInteger(v) && v > 0) : [];
  const arrays = Object.values(feedback).filter(Array.isArray);
  if (ints.length === 1 && arrays.length === 1) return Math.max(0, Math.min(1, (arrays[0].length - 1) / ints[0]));
  return null;
}
