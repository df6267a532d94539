"""``roslink-mqtt call ROBOT SERVICE [JSON]``: call a ROS service on a robot and print the reply."""

from __future__ import annotations

import argparse

import orjson

from ..client import RoslinkError
from .connect import add_connection_options, json_object, open_client


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("call", help="call a ROS service on a robot (like ros2 service call)",
                       description="Call SERVICE with the JSON request, e.g. `roslink-mqtt call turtle1 reset`.")
    p.add_argument("robot")
    p.add_argument("service")
    p.add_argument("args", nargs="?", default="{}", help="JSON object with the request fields (default {})")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait (default %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    request = json_object(args.args, "request")
    client = open_client(args, robots=[args.robot], presence=False)
    try:
        values = client.call(args.robot, args.service, request, timeout=args.timeout)
    except RoslinkError as err:  # the robot's reason, a refusal from our access report, or no connection
        print(f"roslink-mqtt call: {err}")
        return 1
    finally:
        client.close()
    print(orjson.dumps(values, option=orjson.OPT_INDENT_2).decode())
    return 0
