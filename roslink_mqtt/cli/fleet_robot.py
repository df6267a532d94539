"""``roslink-mqtt fleet robot add``: a new robot in robots.yaml, and the bundle its computer needs
(config/provision.py)."""

from __future__ import annotations

import argparse

RELOAD = "then `roslink-mqtt fleet apply` (the broker learns its login)"


def register(actions: argparse._SubParsersAction[argparse.ArgumentParser], edited: object) -> None:
    robot = actions.add_parser("robot", help="add a robot (and write its provisioning bundle)",
                               description="Add a robot to the fleet file (keeping its comments and layout) with a "
                                           "generated key and password, and write the robot's provisioning bundle: "
                                           "its robot file, its password file, the bridge unit's environment file "
                                           "and a systemd drop-in.")
    robots = robot.add_subparsers(dest="robot_action", metavar="{add,rotate}", required=True)
    add = robots.add_parser("add", help="add a robot and write its bundle")
    add.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    add.add_argument("name")
    add.add_argument("--bundle", required=True, metavar="DIR", help="where the bundle goes (created, mode 700)")
    add.add_argument("--like", metavar="ROBOT", help="share this robot's rules, services, actions, parameters, type "
                                                     "and bridge settings (default: none)")
    add.add_argument("--broker-url", metavar="URL", help="where its bridge dials (bridge.broker and --url), e.g. "
                                                         "mqtts://broker.example.net:8883")
    add.add_argument("--prefix", default="/opt/roslink-mqtt", help="deploy/install.sh's --prefix on the robot "
                                                                  "(default: %(default)s)")
    add.set_defaults(run=edited(run_add))  # type: ignore[operator]
    rotate = robots.add_parser(
        "rotate", help="give a robot a new password, the old one still accepted until --finish",
        description="Rotate a robot's password without dropping it: the new password's hash goes into robots.yaml "
                    "with the current one kept as previous_password (the embedded broker accepts both after "
                    "`fleet apply`). Put the new password in the robot's password file and reload its bridge "
                    "(SIGHUP: its next connection uses it; none is dropped), then run this again with --finish "
                    "and `fleet apply`: the old password stops working.")
    rotate.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    rotate.add_argument("name")
    group = rotate.add_mutually_exclusive_group(required=True)
    group.add_argument("--password-file", metavar="FILE", help="the new password (first line); when FILE does not "
                                                               "exist a random one is written there (mode 600)")
    group.add_argument("--finish", action="store_true", help="stop accepting the previous password")
    rotate.set_defaults(run=edited(run_rotate))  # type: ignore[operator]


def run_add(args: argparse.Namespace) -> int:
    from ..config.edit import FleetEdit
    from ..config.passwords import hash_password
    from ..config.provision import ETC, ROBOT_ITERATIONS, new_key, new_password, write_bundle

    edit = FleetEdit(args.config)
    password = new_password()
    system_id = edit.add_robot(args.name, key=new_key(), password_hash=hash_password(password,
                                                                                  iterations=ROBOT_ITERATIONS),
                               like=args.like, broker_url=args.broker_url)
    edit.save()
    bundle = write_bundle(args.config, args.name, password, args.bundle, url=args.broker_url, prefix=args.prefix)
    print(f"{args.config}: added robot {args.name} (system_id {system_id}"
          + (f", like {args.like}" if args.like else "") + f"); {RELOAD}")
    print(f"its bundle in {args.bundle}, for the robot's computer:")
    print(f"  {bundle.robot_file}  → {ETC}/{args.name}.yaml (its rules; no secrets of anyone else)")
    print(f"  {bundle.password}  → {ETC}/{args.name}.password (its password: install -m 640 -g roslink, the "
          "bridge's group)")
    print(f"  {bundle.env}  → {ETC}/{args.name}.env (the bridge unit's environment)")
    print(f"  {bundle.drop_in}  → /etc/systemd/system/roslink-mqtt-bridge.service.d/")
    print("on the robot (after deploy/install.sh bridge): sudo systemctl daemon-reload && "
          "sudo systemctl restart roslink-mqtt-bridge")
    return 0


def run_rotate(args: argparse.Namespace) -> int:
    from ..config.edit import FleetEdit
    from ..config.passwords import hash_password
    from ..config.provision import ROBOT_ITERATIONS
    from .fleet_cmd import read_or_make_password

    edit = FleetEdit(args.config)
    if args.finish:
        edit.finish_rotation(args.name)
        edit.save()
        print(f"{args.config}: {args.name}'s previous password is no longer accepted; {RELOAD}")
        return 0
    password, made = read_or_make_password(args.password_file)
    edit.rotate_password(args.name, hash_password(password, iterations=ROBOT_ITERATIONS))
    edit.save()
    print(f"{args.config}: {args.name} has a new password" + (f" (written to {args.password_file}, mode 600)"
                                                              if made else "")
          + f"; the previous one is still accepted. Next: `roslink-mqtt fleet apply`; put the new password in the "
            f"robot's password file and `systemctl reload roslink-mqtt-bridge`; then `roslink-mqtt fleet robot "
            f"rotate {args.name} --finish` and `fleet apply`")
    return 0
