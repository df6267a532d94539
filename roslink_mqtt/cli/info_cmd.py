"""``roslink-mqtt info ROBOT``: what a robot maps (its retained description), and what of it you may use.

The description is the same for every user granted the robot (docs/protocol.md, "Robot description"); each
entry says who may use it. Your own rights come from your access report, so entries you may not use are marked
``(not you)``. ``--types`` adds the field layout of every ROS type, as ``ros2 interface show`` prints it;
``--json`` prints the description body as it came.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from ..client import RobotClient, RoslinkError
from ..protocol.control import AccessReport
from ..protocol.description import RobotDescription
from ..protocol.lease import ControlState
from ..protocol.link import LinkReport
from ..topics import TopicError, check_name
from .connect import add_connection_options, open_client

ACCESS_WAIT = 1.0  # s for the retained access report (it follows the SUBACK at once)
LINK_WAIT = 1.0  # s for the retained link report (an older bridge publishes none: info goes on without it)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("info", help="what a robot maps: state, commands, services, actions and their types",
                       description="Print a robot's description (retained by its bridge): every state, command, "
                                   "service and action it maps, who may use each, and with --types the field "
                                   "layout of every ROS type. Entries you may not use are marked (not you).")
    p.add_argument("robot")
    p.add_argument("--json", action="store_true", help="print the description body as JSON")
    p.add_argument("--types", action="store_true", help="also print the field layout of every ROS type")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for it (default %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def _access(client: RobotClient, robot: str) -> AccessReport | None:
    deadline = time.monotonic() + ACCESS_WAIT
    while client.access(robot) is None and time.monotonic() < deadline:
        time.sleep(0.05)
    return client.access(robot)


def run(args: argparse.Namespace) -> int:
    try:
        check_name(args.robot, "robot")
    except TopicError as err:
        print(f"roslink-mqtt info: {err}", file=sys.stderr)
        return 2
    client = open_client(args, robots=[args.robot], presence=False)
    try:
        try:
            description = client.description(args.robot, timeout=args.timeout)
        except RoslinkError as err:
            print(f"roslink-mqtt info: {err}", file=sys.stderr)
            return 1
        report = _access(client, args.robot)
        link = None if args.json else client.link(args.robot, timeout=LINK_WAIT)
        control = None if args.json else client.control(args.robot, timeout=LINK_WAIT)
    finally:
        client.close()
    if args.json:
        print(description.to_json().decode())
        return 0
    print(summary(description, report, client.username, types=args.types, link=link, control=control))
    return 0


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:g}"


def _limits(limits: dict[str, Any]) -> str:
    if not limits:
        return ""
    return (f"{_num(limits.get('linear'))} m/s, {_num(limits.get('angular'))} rad/s"
            + (f" ({limits['mode']})" if limits.get("mode") else ""))


def _carries(message: str | None, ros_type: str | None) -> str:
    if message and ros_type:
        return f"ROSLink {message} ({ros_type})"
    if message:
        return f"ROSLink {message}"
    return f"{ros_type} as JSON" if ros_type else "-"


def summary(d: RobotDescription, report: AccessReport | None, user: str, *, types: bool = False,
            link: LinkReport | None = None, control: ControlState | None = None) -> str:
    """The human-readable form: one line per entry, ``(not you)`` where ``report`` says you may not use it."""
    def mark(kind: str, name: str) -> str:
        if report is None or report.operator:
            return ""
        ok = kind == "state" or (kind == "service" and name in report.services) or (
            kind == "action" and name in report.actions) or (
            kind == "command" and report.estop and name.endswith("emergency_stop"))
        return "" if ok else "  (not you)"

    you = f"{report.role}" if report is not None else "unknown (no access report from its bridge)"
    out = [f"{d.robot}: {d.type} robot, system_id {d.system_id}, ROSLink protocol {d.protocol_version}",
           f"  limits: {_limits(d.limits) or 'none'}",
           f"  you ({user}): {you}"]
    if link is not None:
        out.append(f"  uplink: {link.summary()}")
    if control is not None:
        who = "every granted user" if control.estop == "viewers" else "operators"
        sup = f"; supervisors: {', '.join(control.supervisors)}" if control.supervisors else ""
        out.append(f"  control: {control.summary()} (claim: {control.mode}{sup}; emergency stop: {who})")
    out += ["", f"state (every user granted {d.robot} reads it):"]
    for s in d.state:
        extra = [f"≤ {s.max_rate:g} Hz"] if s.max_rate else []
        extra += ["retained"] if s.retained else []
        extra += [f"fields {', '.join(s.fields)}"] if s.fields else []
        out.append(f"  {s.name:<22} {_carries(s.message, s.ros_type):<54} {', '.join(extra)}".rstrip())
        out += [f"    ! the rule {s.warning}"] if s.warning else []
    out += ["", "commands (operators):" if all(c.who == "operators" for c in d.commands) else "commands:"]
    for c in d.commands:
        extra = [f"limits {_limits(c.limits)}"] if c.limits else []
        extra += ["on demand"] if c.on_demand else []
        out.append(f"  {c.name:<22} {_carries(c.message, c.ros_type):<54} {c.who:<9} {', '.join(extra)}".rstrip()
                   + mark("command", c.name))
        out += [f"    ! the rule {c.warning}"] if c.warning else []
    out += ["", "services:"] + ([line for s in d.services for line in (
        f"  {s.name:<22} {s.ros_type:<54} {s.who:<9} timeout {_num(s.timeout)} s" + mark("service", s.name),
        *([f"    ! the rule {s.warning}"] if s.warning else []))] or ["  none"])
    out += ["", "actions:"] + ([f"  {a.name:<22} {a.ros_type:<54} {a.who:<9} timeout {_num(a.timeout)} s, "
                                f"feedback ≤ {_num(a.feedback_rate)} Hz" + mark("action", a.name)
                                for a in d.actions] or ["  none"])
    viewer = report is not None and not report.operator
    out += ["", "parameters (everyone granted reads them):"] + (
        [f"  {p.name:<22} node {p.node:<49} set by {p.set_by:<9} timeout {_num(p.timeout)} s"
         + ("  (you may read, not set)" if viewer and p.set_by != "viewers" else "") for p in d.parameters]
        or ["  none"])
    if types:
        out += ["", "types:"]
        for name, layout in d.types.items():
            out.append(f"  {name}")
            out += interface_lines(layout, "    ")
    return "\n".join(out)


def interface_lines(layout: dict[str, Any], indent: str) -> list[str]:
    """A layout as ``ros2 interface show`` prints one: ``type name`` lines, nested fields indented, ``---``
    between a service's request and response (an action's goal, result and feedback)."""
    if set(layout) in ({"request", "response"}, {"goal", "result", "feedback"}) and all(
            isinstance(v, dict) and "fields" not in v for v in layout.values()):
        lines: list[str] = []
        for i, part in enumerate(layout.values()):
            if i:
                lines.append(f"{indent}---")
            lines += interface_lines(part, indent)
        return lines
    lines = []
    for field, kind in layout.items():
        if isinstance(kind, dict):
            lines.append(f"{indent}{kind.get('type', '?')} {field}")
            lines += interface_lines(kind.get("fields") or {}, indent + "  ")
        else:
            lines.append(f"{indent}{kind} {field}")
    return lines
