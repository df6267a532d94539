// Forms from the robot's description (retained on state/description), which carries the field layout of every
// ROS type it maps: name → "float64" / "string" / "int32[]" …, or {type, fields} for a nested message. Built with
// createElement/textContent only (the description comes from the robot: never innerHTML); values read by forms.mjs.
import { FLOATS, FieldError, INT_RANGE, isLayout, parseJsonField, parseNumber } from "../forms.mjs";
import { el, show } from "./dom.mjs";

const MAX_FORM_DEPTH = 4;  // nested messages deeper than this are edited as JSON
const MAX_FIELDS = 200;    // inputs per form (a huge type gets a JSON box for the rest)

function invalidOn(input, read) {
  return () => {
    try { return read(); } catch (e) {
      if (e instanceof FieldError) { input.classList.add("invalid"); input.setAttribute("aria-invalid", "true"); }
      throw e;
    }
  };
}

function clearInvalid(input) {
  input.addEventListener("input", () => { input.classList.remove("invalid"); input.removeAttribute("aria-invalid"); });
}

// One input per primitive field, a fieldset per nested message, a JSON box for arrays (and what is too deep).
// Returns a collector: () → the JSON object to send, or throws FieldError naming the field.
function buildFields(container, fields, path, depth, budget) {
  const collectors = [];
  for (const [name, spec] of Object.entries(fields)) {
    const full = path ? `${path}.${name}` : name;
    if (budget.n-- <= 0 || (isLayout(spec) && depth >= MAX_FORM_DEPTH) ||
        (isLayout(spec) && !isLayout(spec.fields)) || (typeof spec !== "string" && !isLayout(spec))) {
      collectors.push([name, jsonField(container, full, isLayout(spec) ? String(spec.type || "message") : "JSON", false)]);
    } else if (isLayout(spec)) {
      const fs = el("fieldset", { "data-field": full });
      fs.append(el("legend", null, `${name} (${spec.type || "message"})`));
      container.append(fs);
      const inner = buildFields(fs, spec.fields, full, depth + 1, budget);
      collectors.push([name, () => { const v = inner(); return Object.keys(v).length ? v : undefined; }]);
    } else {
      collectors.push([name, primitiveField(container, full, name, spec)]);
    }
  }
  return () => {
    const out = {};
    for (const [name, get] of collectors) {
      const v = get();
      if (v !== undefined) out[name] = v;
    }
    return out;
  };
}

function primitiveField(container, full, name, type) {
  const label = el("label", { class: "field" });
  label.append(el("span", { class: "field-name" }, name), el("span", { class: "field-type" }, type));
  container.append(label);
  if (/\[.*\]$/.test(type)) return jsonField(label, full, type, true);
  if (type === "bool" || type === "boolean") {
    const box = el("input", { type: "checkbox", "data-field": full, "data-type": type });
    label.prepend(box);
    return () => box.checked;
  }
  const input = el("input", { type: "text", spellcheck: false, "data-field": full, "data-type": type });
  clearInvalid(input);
  label.append(input);
  if (INT_RANGE[type] || FLOATS.has(type)) {
    input.inputMode = INT_RANGE[type] ? "numeric" : "decimal";
    input.placeholder = "0";
    return invalidOn(input, () => parseNumber(full, type, input.value));
  }
  const bound = /^w?string<=(\d+)$/.exec(type);
  if (bound) input.maxLength = Number(bound[1]);
  return () => (input.value === "" ? undefined : input.value);
}

function jsonField(container, full, type, isArray) {
  const area = el("textarea", { rows: 2, spellcheck: false, "data-field": full, "data-type": type,
                                placeholder: isArray ? "JSON array, e.g. [1, 2]" : "JSON object" });
  clearInvalid(area);
  if (container.tagName === "LABEL") container.append(area);
  else {
    const label = el("label", { class: "field" });
    label.append(el("span", { class: "field-name" }, full.split(".").pop()), el("span", { class: "field-type" }, type), area);
    container.append(label);
  }
  return invalidOn(area, () => parseJsonField(full, type, isArray, area.value));
}

/** A form: fields, a submit button, a line for what is wrong. onSubmit(values) is called only when every field is
 * valid; an invalid field is said so in the form and nothing is sent. */
export function rosForm(attrs, layout, buttonText, onSubmit) {
  const form = el("form", { class: "ros-form", noValidate: true, ...attrs });
  const collect = isLayout(layout) ? buildFields(form, layout, "", 0, { n: MAX_FIELDS })
    : buildFields(form, { "(goal)": { type: "unknown type: JSON", fields: null } }, "", 0, { n: MAX_FIELDS });
  const row = el("div", { class: "form-buttons" });
  const submit = el("button", { type: "submit", class: "submit" }, buttonText);
  row.append(submit);
  const error = el("p", { class: "form-error", role: "alert", hidden: true });
  form.append(row, error);
  form.addEventListener("submit", (ev) => {
    ev.preventDefault();
    let values;
    try {
      values = collect();
      if (!isLayout(layout)) values = values["(goal)"] || {};
    } catch (e) {
      if (!(e instanceof FieldError)) throw e;
      error.textContent = `not sent: ${e.message}`;
      form.dataset.state = "invalid";
      show(error, true);
      return;
    }
    error.textContent = "";
    show(error, false);
    form.dataset.state = "sent";
    onSubmit(values);
  });
  return { form, row, error };
}
