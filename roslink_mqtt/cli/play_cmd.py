"""``roslink-mqtt play FILE.mcap``: publish a recording again as the robot it shows (client/player.py), or a ROS 2
bag through a robot's rules (bridge/ros/bag_play.py)."""

from __future__ import annotations

import argparse
import functools
import sys
from collections.abc import Callable, Iterator

from ..connection_options import ENV_PASSWORD, resolve_ca_file, resolve_password, resolve_url, resolve_username
from ..topics import TopicTree, check_name
from .connect import PROG, add_connection_options, stop_on_signals


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("play", help="publish a recording (roslink-mqtt record) or a ROS 2 bag again, as a robot",
                       description="Publish the heartbeats and state of a recording into a broker at the recorded "
                                   "pace, logged in as a robot (-u ROBOT): dashboards, scripts and tests see that "
                                   "robot as it was. What it sent one user is not played. With --rules, FILE is a "
                                   "ROS 2 bag in MCAP (ros2 bag record -s mcap, or a snapshot): its messages go "
                                   "through the robot's ros_to_mqtt rules as its bridge would convert them (needs "
                                   "the bridge's ROS packages).")
    p.add_argument("file", metavar="FILE.mcap")
    p.add_argument("--rate", type=float, default=1.0, help="speed: 2 plays twice as fast (default: %(default)s)")
    p.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    p.add_argument("--as", dest="rename", action="append", default=[], metavar="RECORDED=ROBOT",
                   help="play the recorded robot's topics as another robot's (log in as that one)")
    p.add_argument("--prefix", default="roslink", help="topic prefix of the fleet (default: %(default)s)")
    p.add_argument("--rules", metavar="ROBOTS.yaml", help="FILE is a ROS 2 bag: convert it with the rules of --robot "
                                                         "in this fleet or robot file")
    p.add_argument("--robot", metavar="NAME", help="with --rules: whose rules (default: the login, -u)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..client.errors import ConnectError
    from ..client.player import Frame, Player, frames

    if args.rate <= 0:
        print(f"{PROG} play: --rate must be above 0", file=sys.stderr)
        return 2
    rename = {}
    for item in args.rename:
        recorded, _, robot = item.partition("=")
        rename[check_name(recorded, "robot")] = check_name(robot, "robot")
    username, password = resolve_username(args), resolve_password(args, PROG)
    if not username or password is None:
        print(f"{PROG} play: needs the robot's login: -u ROBOT and {ENV_PASSWORD} or --password-file", file=sys.stderr)
        return 2
    tree = TopicTree(args.prefix)
    source: Callable[[], Iterator[Frame]] = functools.partial(frames, args.file, tree, rename)  # a pass per loop
    if args.rules:
        from ..config import ConfigError, load_fleet

        try:
            fleet = load_fleet(args.rules)
        except (ConfigError, OSError) as err:
            print(f"{PROG} play: {err}", file=sys.stderr)
            return 2
        robot = fleet.robots.get(args.robot or username)
        if robot is None:
            print(f"{PROG} play: no robot '{args.robot or username}' in {args.rules} (robots: "
                  f"{', '.join(fleet.robots)}); name it with --robot", file=sys.stderr)
            return 2
        try:
            from ..bridge.ros.bag_play import bag_frames
        except ImportError as err:
            print(f"{PROG} play: a ROS 2 bag is converted with the ROS message types, as the bridge does: {err} "
                  "(pip install 'roslink-mqtt[bridge]', or source ROS 2)", file=sys.stderr)
            return 2
        tree = fleet.topics
        source = functools.partial(bag_frames, args.file, robot, tree)
    player = Player(url=resolve_url(args, PROG), username=username, password=password, ca_file=resolve_ca_file(args),
                    tree=tree)
    try:
        player.connect()
    except (ConnectError, OSError) as err:
        print(f"{PROG} play: {err}", file=sys.stderr)
        return 1
    stop = stop_on_signals()
    played = 0
    try:
        while not stop.is_set():
            played += player.play(source(), rate=args.rate, stop=stop)
            if not args.loop:
                break
    except ValueError as err:  # RuleError: the bag and the rules have nothing in common, a type not installed
        print(f"{PROG} play: {err}", file=sys.stderr)
        return 1
    finally:
        player.close()
    print(f"played {played} messages of {args.file}", file=sys.stderr)
    return 0
