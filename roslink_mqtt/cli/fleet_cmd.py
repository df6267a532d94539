"""``roslink-mqtt fleet``: validate robots.yaml and show who may do what."""

from __future__ import annotations

import argparse
import sys

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
    actions = p.add_subparsers(dest="fleet_action", metavar="{split}")
    split = actions.add_parser("split", help="write one robot file per robot: its part of the fleet, no passwords",
                               description="Write OUT/<robot>.yaml for each robot (or the ones named): its rules, "
                                           "services, actions, parameters, bridge settings and who may do what with "
                                           "it -- no password hash of any login and no other robot's key, so that "
                                           "a stolen robot exposes no login. Run its bridge with --config "
                                           "OUT/<robot>.yaml and the robot's password in ROSLINK_PASSWORD or "
                                           "--password-file. Split again after every change of the fleet file.")
    split.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    split.add_argument("--out", required=True, help="directory for the robot files (created if missing)")
    split.add_argument("robots", nargs="*", metavar="ROBOT", help="only these robots (default: every robot)")
    split.set_defaults(run=run_split)


def summary(fleet: Fleet) -> str:
    """The fleet in a few lines: robots with their users and roles, then what could not be checked here."""
    kind = f"robot file of {fleet.robot_file} (no password hashes)" if fleet.robot_file else "fleet"
    lines = [f"{kind} {fleet.file}: {len(fleet.robots)} robots, {len(fleet.users)} users, prefix '{fleet.prefix}'"]
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
    """The summary; exit 2 when the broker would refuse to start from this file (config/exposure.py)."""
    from ..config.exposure import exposure_problems

    fleet = load_fleet(args.config)
    print(summary(fleet))
    problems = [] if fleet.robot_file else exposure_problems(fleet)
    for problem in problems:
        print(f"roslink-mqtt fleet: the broker would refuse to start: {problem}", file=sys.stderr)
    return 2 if problems else 0


def run_split(args: argparse.Namespace) -> int:
    from ..config.split import split_fleet

    for path in split_fleet(args.config, args.out, args.robots or None):
        print(f"wrote {path} (mode 0600; no password hashes)")
    return 0
