"""``roslink-mqtt pub ROBOT COMMAND [JSON]``: send a command, once or as a bounded stream."""

from __future__ import annotations

import argparse
import sys
import time

from ..client import CommandRefused, NotConnectedError, RobotNotice, RoslinkError
from ..client.commands import command_leaf, roslink_command
from ..client.rclpy.node import ros_shaped_to_roslink
from ..protocol import ProtocolError
from .connect import add_connection_options, json_object, open_client
from .control_cmd import claim_if_free

RECONNECT_WAIT = 3.0  # s: after losing the connection mid-stream, how long we wait to learn why (a revoked grant)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("pub", help="send a command to a robot (twist, go_to_waypoint, arm, …)",
                       description="Send COMMAND with the JSON payload, e.g. "
                                   "`roslink-mqtt pub turtle1 twist '{\"lx\": 0.2}' --rate 10 --duration 2`; "
                                   "the ROS shape works too: '{\"linear\": {\"x\": 0.2}}'. "
                                   "Runs operator presence, as robots require. Velocity streams stop by "
                                   "themselves: the robot's dead-man halts it when the stream ends. What the "
                                   "robot changed (a twist clamped to its limits) is printed.")
    p.add_argument("robot")
    p.add_argument("command", help="ROSLink command (twist, go_to_waypoint, takeoff, land, arm, disarm, "
                                   "set_mode, get_map, emergency_stop) or a generic rule's topic")
    p.add_argument("payload", nargs="?", default="{}",
                   help="JSON object (default {}); ROSLink fields, or for twist and go_to_waypoint the ROS "
                        "message's shape (geometry_msgs/Twist, PoseStamped), as the SDK takes")
    p.add_argument("--rate", type=float, default=0.0, help="repeat at this many Hz (needs --duration)")
    p.add_argument("--duration", type=float, default=0.0, help="seconds to repeat for (at most 600)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    payload = json_object(args.payload, "payload")
    if args.rate and not 0 < args.duration <= 600:
        raise SystemExit("roslink-mqtt pub: --rate needs --duration between 0 and 600 s")
    command = roslink_command(command_leaf(args.command))
    if command is not None:
        try:
            payload = ros_shaped_to_roslink(command, payload)  # the SDK's conversion: {"linear": {"x": …}} → lx …
        except RoslinkError as err:  # {"data": false} on arm: it would do nothing
            raise SystemExit(f"roslink-mqtt pub: {err}") from None
    client = open_client(args, robots=[args.robot])
    # a notice (the robot clamped the twist) arrives once per stream, while we send or wait for refusals
    client.on_notice = _print_notice
    try:
        client.wait_for_robot(args.robot, timeout=5.0)
        if command != "emergency_stop":  # a stop needs no control
            held = claim_if_free(client, args.robot)
            if held:
                print(f"roslink-mqtt pub: refused: {held}")
                return 1
        count = max(1, int(args.rate * args.duration)) if args.rate else 1
        period = 1.0 / args.rate if args.rate else 0.0
        start = time.monotonic()
        for i in range(count):
            last = i == count - 1
            client.command(args.robot, args.command, dict(payload), check=0.5 if last else None)
            if not last:
                time.sleep(max(0.0, start + (i + 1) * period - time.monotonic()))
        print(f"sent {count} × {args.command} to {args.robot}")
        return 0
    except (CommandRefused, ProtocolError) as err:
        print(f"roslink-mqtt pub: refused: {err}")
        return 1
    except NotConnectedError as err:  # lost mid-stream: say why if the broker tells us on reconnecting
        print(f"roslink-mqtt pub: {err}", file=sys.stderr)
        if client.connection.connected.wait(RECONNECT_WAIT):
            try:
                client.wait_for_robot(args.robot, timeout=RECONNECT_WAIT)
            except RoslinkError as why:  # NotGranted: "your grant to turtle1 was removed by the fleet: ..."
                print(f"roslink-mqtt pub: {why}", file=sys.stderr)
        return 1
    except (TimeoutError, RoslinkError) as err:  # robot offline, no grant, stop not acknowledged
        print(f"roslink-mqtt pub: {err}", file=sys.stderr)
        return 1
    finally:
        client.close()


def _print_notice(notice: RobotNotice) -> None:
    print(f"{notice.robot}: {notice.notice}", flush=True)
