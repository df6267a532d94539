"""``roslink-mqtt fleet``: validate robots.yaml and show who may do what."""

from __future__ import annotations

import argparse

from ..config import Fleet, load_fleet
from ..config.interfaces import interface_table


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fleet", help="validate robots.yaml and print robots, users and grants",
                       description="Load the fleet file, report the first error with file:line, "
                                   "or print a summary. ROS types are checked without ROS: names and fields "
                                   "of the common_interfaces types, and which types each preset accepts; a "
                                   "type from another package is listed as not checked (the bridge checks it "
                                   "when it starts).")
    p.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    p.set_defaults(run=run)


def summary(fleet: Fleet) -> str:
    """The fleet in a few lines: robots with their users and roles, then what could not be checked here."""
    lines = [f"fleet {fleet.file}: {len(fleet.robots)} robots, {len(fleet.users)} users, prefix '{fleet.prefix}'"]
    for robot in fleet.robots.values():
        lines.append(f"  robot {robot.name:<10} system_id={robot.system_id:<5} type={robot.type.name.lower():<8}"
                     f" rules={len(robot.rules)} services={len(robot.services)}")
        for user, role in sorted(fleet.users_of(robot.name).items()):
            lines.append(f"      {role.value:<8} {user}" + ("  (supervisor)" if user in robot.supervisors else ""))
        stoppers = "every granted user" if robot.estop == "viewers" else "operators"
        lines.append(f"      control: {robot.control}; emergency stop: {stoppers}")
    lines.append(f"ROS types checked against {interface_table().source}"
                 + (f"; {len(fleet.notes)} not checked here:" if fleet.notes else ""))
    lines += [f"  note: {note}" for note in fleet.notes]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    print(summary(load_fleet(args.config)))
    return 0
