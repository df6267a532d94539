"""``roslink-mqtt fleet``: validate robots.yaml and show who may do what."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from ..config import Fleet, Role, load_fleet
from ..config.interfaces import interface_table


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("fleet", help="validate robots.yaml and print robots, users and grants",
                       description="Load the fleet file, report the first error with file:line, "
                                   "or print a summary. ROS types are checked without ROS: names and fields "
                                   "of the common_interfaces types, and which types each preset accepts; a "
                                   "type from another package is listed as not checked (the bridge checks it "
                                   "when it starts).")
    p.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    p.set_defaults(run=run)
    actions = p.add_subparsers(dest="fleet_action", metavar="{split,user,robot,grant,revoke,apply}")
    split = actions.add_parser("split", help="write one robot file per robot: its part of the fleet, no passwords",
                               description="Write OUT/<robot>.yaml for each robot (or the ones named): its rules, "
                                           "services, actions, parameters and bridge settings -- no password hash "
                                           "of any login, no other robot's key and no users (its bridge takes the "
                                           "robot's grants from the broker), so that a stolen robot exposes no "
                                           "login. Run its bridge with --config "
                                           "OUT/<robot>.yaml and the robot's password in ROSLINK_PASSWORD or "
                                           "--password-file. Split again after every change of the fleet file.")
    split.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    split.add_argument("--out", required=True, help="directory for the robot files (created if missing)")
    split.add_argument("robots", nargs="*", metavar="ROBOT", help="only these robots (default: every robot)")
    split.set_defaults(run=run_split)
    _register_edits(actions)
    from .fleet_apply import register as register_apply
    from .fleet_robot import register as register_robot

    register_robot(actions, _edited)
    register_apply(actions)


EDIT_NOTE = ("Edits the fleet file in place, keeping its comments and layout, after checking the result as the "
             "broker would (nothing is written otherwise). Then `roslink-mqtt fleet apply`: the broker (embedded, or "
             "Mosquitto with dynamic security) enforces it at once and each robot's bridge gets its grants; "
             "a removed user's connections are closed.")


def _register_edits(actions: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    def editing(name: str, help_text: str) -> argparse.ArgumentParser:
        p = actions.add_parser(name, help=help_text, description=f"{help_text[0].upper()}{help_text[1:]}. "
                                                                 f"{EDIT_NOTE}")
        p.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
        return p

    user = actions.add_parser("user", help="add or remove a user", description=f"Add or remove a user. {EDIT_NOTE}")
    users = user.add_subparsers(dest="user_action", metavar="{add,remove}", required=True)
    add = users.add_parser("add", help="add a user (no grants yet, or an administrator)")
    add.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    add.add_argument("name")
    add.add_argument("--password-file", required=True, metavar="FILE",
                     help="the user's password (first line); when FILE does not exist a random one is written "
                          "there (mode 600) for you to hand over")
    add.add_argument("--admin", action="store_true", help="every robot, every role (the fleet's administrators)")
    add.add_argument("--iterations", type=int, default=None, help="PBKDF2 iterations of the hash (default: "
                                                                  "passwd's)")
    add.set_defaults(run=run_user_add)
    remove = users.add_parser("remove", help="remove a user (and every grant of theirs)")
    remove.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    remove.add_argument("name")
    remove.set_defaults(run=run_user_remove)
    grant = editing("grant", "give a user a role on a robot (operator or viewer), by the robot's key")
    grant.add_argument("user")
    grant.add_argument("robot")
    grant.add_argument("--role", choices=[r.value for r in Role], default=Role.OPERATOR.value,
                       help="default: %(default)s")
    grant.set_defaults(run=run_grant)
    revoke = editing("revoke", "take a user's grant on a robot away")
    revoke.add_argument("user")
    revoke.add_argument("robot")
    revoke.set_defaults(run=run_revoke)


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


RELOAD_HINT = "apply it with `roslink-mqtt fleet apply` (the broker and the robots' grants, live)"


def _edited(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """Run an edit; an edit that cannot be made says why on stderr and exits 2."""
    import functools

    @functools.wraps(run)
    def wrapper(args: argparse.Namespace) -> int:
        from ..config.edit import FleetEditError

        try:
            return run(args)
        except FleetEditError as err:
            print(f"roslink-mqtt fleet: {err}", file=sys.stderr)
            return 2
    return wrapper


def read_or_make_password(path: str) -> tuple[str, bool]:
    """The password in ``path`` (first line), or a new random one written there (mode 600): (password, made)."""
    import os
    import secrets
    from pathlib import Path

    from ..connection_options import read_password_file
    from .passwd_cmd import MIN_LENGTH

    if Path(path).exists():
        password = read_password_file(path, "roslink-mqtt fleet")
        if len(password) < MIN_LENGTH:
            from ..config.edit import FleetEditError

            raise FleetEditError(f"{path}: the password must have at least {MIN_LENGTH} characters")
        return password, False
    password = secrets.token_urlsafe(18)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(password + "\n")
    return password, True


@_edited
def run_user_add(args: argparse.Namespace) -> int:
    from ..config.edit import FleetEdit
    from ..config.passwords import DEFAULT_ITERATIONS, hash_password

    edit = FleetEdit(args.config)
    password, made = read_or_make_password(args.password_file)
    edit.add_user(args.name, hash_password(password, iterations=args.iterations or DEFAULT_ITERATIONS),
                  admin=args.admin)
    edit.save()
    made_text = f"; a new password is in {args.password_file} (mode 600)" if made else ""
    what = "administrator" if args.admin else "no grants yet: `roslink-mqtt fleet grant`"
    print(f"{args.config}: added user {args.name} ({what}){made_text}; {RELOAD_HINT}")
    return 0


@_edited
def run_user_remove(args: argparse.Namespace) -> int:
    from ..config.edit import FleetEdit

    edit = FleetEdit(args.config)
    edit.remove_user(args.name)
    edit.save()
    print(f"{args.config}: removed user {args.name}; {RELOAD_HINT} (their connections are closed)")
    return 0


@_edited
def run_grant(args: argparse.Namespace) -> int:
    from ..config.edit import FleetEdit

    edit = FleetEdit(args.config)
    changed = edit.grant(args.user, args.robot, Role(args.role))
    if not changed:
        print(f"{args.config}: {args.user} is already {args.role} of {args.robot}; nothing changed")
        return 0
    edit.save()
    print(f"{args.config}: {args.user} is now {args.role} of {args.robot}; {RELOAD_HINT}")
    return 0


@_edited
def run_revoke(args: argparse.Namespace) -> int:
    from ..config.edit import FleetEdit

    edit = FleetEdit(args.config)
    edit.revoke(args.user, args.robot)
    edit.save()
    print(f"{args.config}: {args.user} has no grant on {args.robot} any more; {RELOAD_HINT} (deliveries to them "
          "stop at once)")
    return 0
