// Parameter panels: each parameter entry of the description this user may read, its values (list, describe, get),
// an edit box and Set where the user may set them, kept current by state/parameter_events/<name>.
import { read } from "../decode.mjs";
import { FieldError, isLayout, parseParam, short } from "../forms.mjs";
import { mayUse } from "../model.mjs";
import { dash } from "../store.mjs";
import { addLog, el, setText, show, stamp, ui } from "./dom.mjs";
import { publishUser } from "./session.mjs";

const PARAMS_MAX = 200;  // parameters listed per node
const PARAM_TIMEOUT_MS = 10000;
let panels = new Map();  // entry name → its panel, for the robot shown

function paramRequest(robotName, node, body, onReply) {
  if (!dash.client || !dash.connected) { onReply(null, "not connected to the broker"); return; }
  const id = `${dash.clientId}-p${++dash.callCounter}`;
  const timer = setTimeout(() => {
    dash.pendingParams.delete(id);
    onReply(null, `no reply within ${PARAM_TIMEOUT_MS / 1000} s (robot offline, or the broker dropped the request)`);
  }, PARAM_TIMEOUT_MS);
  dash.pendingParams.set(id, { robot: robotName, node, onReply, timer });
  publishUser(robotName, "param", node, { id, ...body, client_id: dash.clientId });
}

/** An error report naming one of our parameter requests: its panel says why. */
export function refuseParamRequest(robotName, id, why) {
  const req = dash.pendingParams.get(id);
  if (!req || req.robot !== robotName) return;
  clearTimeout(req.timer);
  dash.pendingParams.delete(id);
  req.onReply(null, why);
}

export function clearParams() {
  for (const r of dash.pendingParams.values()) clearTimeout(r.timer);
  dash.pendingParams.clear();
  panels = new Map();
  ui.params.replaceChildren();
}

export function buildParams(robot) {
  const d = robot.description;
  const entries = robot.access && d && Array.isArray(d.parameters) ? d.parameters.filter(
    (e) => isLayout(e) && typeof e.name === "string" && mayUse(robot, e.who || "viewers")) : [];
  panels = new Map();
  ui.params.replaceChildren();
  for (const entry of entries) {
    const canSet = mayUse(robot, entry.set_by || "operators");
    const panel = el("div", { class: "params", "data-params": entry.name, "data-can-set": canSet ? "yes" : "no" });
    const h = el("h4", null, `${entry.name} `);
    h.append(el("small", null, `node ${entry.node || entry.name}; set by ${entry.set_by || "operators"}`));
    const refresh = el("button", { type: "button", class: "refresh", title: "read the values again" }, "↻");
    refresh.setAttribute("aria-label", `read the parameters of ${entry.name} again`);
    h.append(refresh);
    const table = el("table", { class: "param-table" });
    table.append(el("tbody"));
    const result = el("p", { class: "param-result", role: "status" });
    panel.append(h, table);
    if (!canSet) panel.append(el("p", { class: "hint" }, `read-only for you: ${entry.set_by || "operators"} may set these`));
    panel.append(result);
    ui.params.append(panel);
    const p = { robot: robot.name, entry, panel, table, result, canSet, rows: new Map(), types: new Map() };
    panels.set(entry.name, p);
    refresh.addEventListener("click", () => loadParams(robot, p));
    loadParams(robot, p);
  }
  show(ui.paramsBox, entries.length > 0);
}

function paramNote(p, result, text) {
  p.result.dataset.result = result;
  setText(p.result, text);
}

function loadParams(robot, p) {
  const node = p.entry.name;
  paramNote(p, "pending", "reading …");
  paramRequest(robot.name, node, { op: "list" }, (r, err) => {
    if (!r) { paramNote(p, "failed", `list failed: ${err}`); return; }
    const names = isLayout(r.values) && Array.isArray(r.values.names)
      ? r.values.names.filter((n) => typeof n === "string").sort().slice(0, PARAMS_MAX) : [];
    for (const [n, row] of p.rows) if (!names.includes(n)) { row.tr.remove(); p.rows.delete(n); }
    for (const n of names) paramRow(robot, p, n);
    if (!names.length) { paramNote(p, "ok", "no parameters"); return; }
    paramRequest(robot.name, node, { op: "describe", names }, (rd) => {
      if (!rd || !isLayout(rd.values)) return;
      for (const [n, info] of Object.entries(rd.values)) {
        const row = p.rows.get(n);
        if (!row || !isLayout(info)) continue;
        p.types.set(n, String(info.type || ""));
        row.name.title = `${info.type || "?"}${info.description ? ": " + info.description : ""}`;
        row.tr.dataset.type = String(info.type || "");
        if (info.read_only && row.set) { row.set.disabled = true; row.input.disabled = true; row.set.title = "read-only parameter"; }
      }
    });
    paramRequest(robot.name, node, { op: "get", names }, (rg, err2) => {
      if (!rg) { paramNote(p, "failed", `get failed: ${err2}`); return; }
      if (isLayout(rg.values)) for (const [n, v] of Object.entries(rg.values)) setParamValue(p, n, v);
      paramNote(p, "ok", `${names.length} parameters read at ${stamp()}`);
    });
  });
}

function paramRow(robot, p, name) {
  if (p.rows.has(name)) return p.rows.get(name);
  const tr = el("tr", { "data-param": name });
  const nameTd = el("td", { class: "name" }, name);
  const valueTd = el("td", { class: "value" }, "…");
  tr.append(nameTd, valueTd);
  const row = { tr, name: nameTd, value: valueTd, input: null, set: null };
  if (p.canSet) {
    const td = el("td", { class: "edit" });
    row.input = el("input", { type: "text", size: 8, spellcheck: false, "data-param": name, placeholder: "new value" });
    row.input.setAttribute("aria-label", `new value of ${name}`);
    row.set = el("button", { type: "button", class: "set", "data-param": name }, "Set");
    const send = () => setParam(robot, p, name, row);
    row.set.addEventListener("click", send);
    row.input.addEventListener("keydown", (ev) => { if (ev.key === "Enter") { ev.preventDefault(); send(); } });
    td.append(row.input, row.set);
    tr.append(td);
  }
  p.table.tBodies[0].append(tr);
  p.rows.set(name, row);
  return row;
}

function setParamValue(p, name, value) {
  const row = p.rows.get(name);
  if (!row) return;
  const text = value === null || value === undefined ? "(not set)" : typeof value === "string" ? value : short(value);
  setText(row.value, text);
  row.value.dataset.value = short(value === undefined ? null : value);
}

function setParam(robot, p, name, row) {
  let value;
  try {
    value = parseParam(p.types.get(name) || "", row.input.value, name);
  } catch (e) {
    if (!(e instanceof FieldError)) throw e;
    row.input.classList.add("invalid");
    paramNote(p, "invalid", `not sent: ${e.message}`);
    return;
  }
  row.input.classList.remove("invalid");
  paramNote(p, "pending", `setting ${name} to ${short(value)} …`);
  paramRequest(robot.name, p.entry.name, { op: "set", values: { [name]: value } }, (r, err) => {
    if (!r) { paramNote(p, "failed", `set ${name} failed: ${err}`); return; }
    const res = isLayout(r.values) ? r.values[name] : undefined;
    if (res && res.successful) {
      paramNote(p, "ok", `${name} set to ${short(value)}`);
      row.input.value = "";
    } else {
      const why = res && res.reason ? res.reason : "the node refused it";
      paramNote(p, "refused", `${name} not set: ${why}`);
      addLog(ui.errors, `${robot.name} refused parameter ${name} = ${short(value)}: ${why}`, { robot: robot.name });
    }
    paramRequest(robot.name, p.entry.name, { op: "get", names: [name] }, (rg) => {
      if (rg && isLayout(rg.values) && name in rg.values) setParamValue(p, name, rg.values[name]);
    });
  });
}

export function onParamReply(name, body) {
  if (!body || (body.client_id && body.client_id !== dash.clientId)) return;
  const req = dash.pendingParams.get(body.id);
  if (!req || req.robot !== name) return;
  clearTimeout(req.timer);
  dash.pendingParams.delete(body.id);
  if (body.result) req.onReply(body, null);
  else req.onReply(null, body.error || "failed");
}

/** state/parameter_events/<name>: values changed by anyone (MQTT, ros2 param set, the node itself). */
export function onParamEvent(robot, name, payload) {
  const p = panels.get(name);
  if (!p || p.robot !== robot.name || dash.selected !== robot.name) return;
  const ev = read("parameter_event", payload);
  if (!ev) return;
  for (const key of ["new", "changed"]) {
    for (const [n, v] of Object.entries(ev[key])) {
      if (key === "new" && p.rows.size < PARAMS_MAX) paramRow(robot, p, n);
      setParamValue(p, n, v);
    }
  }
  for (const n of ev.deleted) {
    const row = p.rows.get(n);
    if (row) { row.tr.remove(); p.rows.delete(n); }
  }
}
