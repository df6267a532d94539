// A button per service without arguments, a form per service with some (from the robot's description).
import { isLayout } from "../forms.mjs";
import { el } from "./dom.mjs";
import { rosForm } from "./forms.mjs";
import { callService } from "./commands.mjs";
import { entryOf, typeLayout } from "./robot.mjs";

export function serviceControl(robot, svc) {
  const entry = entryOf(robot, "services", svc);
  const t = entry && typeLayout(robot, entry.ros_type);
  const request = t && isLayout(t.request) ? t.request : undefined;
  if (!request || Object.keys(request).length === 0) {
    const b = el("button", { type: "button", "data-service": svc, class: "service-button" }, svc);
    b.title = request ? `call ${svc} (${entry.ros_type}: no arguments)` : `call ${svc} with empty arguments ({})`;
    b.addEventListener("click", () => callService(robot.name, svc, {}));
    return b;
  }
  const box = el("div", { class: "service-form" });
  box.append(el("h4", null, `${svc} `));
  box.firstChild.append(el("small", null, entry.ros_type));
  const { form } = rosForm({ "data-service": svc }, request, `Call ${svc}`, (args) => callService(robot.name, svc, args));
  box.append(form);
  return box;
}
