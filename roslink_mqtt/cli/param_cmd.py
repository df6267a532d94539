"""``roslink-mqtt param get|set|list|describe ROBOT NODE …``: a robot's ROS node parameters (like ros2 param).

VALUE is read as JSON (``0.3``, ``true``, ``[1, 2]``, ``"text"``); anything that is not JSON is a string.
Output is JSON. Exit status 1 when the robot refused the request or the node did not answer, or when a set
was refused by the node's own validation.
"""

from __future__ import annotations

import argparse
from typing import Any

import orjson

from ..client import RoslinkError
from .connect import add_connection_options, open_client


def _value(text: str) -> Any:
    try:
        return orjson.loads(text)
    except orjson.JSONDecodeError:
        return text


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("param", help="get, set, list or describe a ROS node's parameters on a robot",
                       description="The parameters of the ROS nodes a robot exposes (robots.yaml parameters).")
    verbs = p.add_subparsers(dest="param_command", required=True, metavar="VERB")
    for verb, helptext in (("get", "print parameter values"), ("describe", "print parameter descriptors")):
        q = verbs.add_parser(verb, help=helptext)
        q.add_argument("robot")
        q.add_argument("node")
        q.add_argument("names", nargs="+", metavar="NAME")
        q.set_defaults(run=run)
        add_connection_options(q)
    q = verbs.add_parser("list", help="print the node's parameter names")
    q.add_argument("robot")
    q.add_argument("node")
    q.add_argument("prefixes", nargs="*", metavar="PREFIX")
    q.set_defaults(run=run)
    add_connection_options(q)
    q = verbs.add_parser("set", help="set one parameter (the node's own validation answers)")
    q.add_argument("robot")
    q.add_argument("node")
    q.add_argument("name")
    q.add_argument("value", type=_value, help="JSON (0.3, true, [1, 2]); other text is a string")
    q.set_defaults(run=run)
    add_connection_options(q)
    for q in verbs.choices.values():
        q.add_argument("--timeout", type=float, default=10.0, help="seconds to wait (default %(default)s)")


def run(args: argparse.Namespace) -> int:
    setting = args.param_command == "set"
    client = open_client(args, robots=[args.robot], presence=setting)  # a set needs presence, like commands
    try:
        if args.param_command == "get":
            out: Any = client.get_parameters(args.robot, args.node, args.names, timeout=args.timeout)
        elif args.param_command == "describe":
            out = client.describe_parameters(args.robot, args.node, args.names, timeout=args.timeout)
        elif args.param_command == "list":
            out = client.list_parameters(args.robot, args.node, args.prefixes, timeout=args.timeout)
        else:
            out = client.set_parameters(args.robot, args.node, {args.name: args.value}, timeout=args.timeout)
    except RoslinkError as err:
        print(f"roslink-mqtt param: {err}")
        return 1
    finally:
        client.close()
    print(orjson.dumps(out, option=orjson.OPT_INDENT_2).decode())
    return 0 if not setting or all(r.get("successful") for r in out.values()) else 1
