"""``roslink-mqtt action send ROBOT ACTION [GOAL] [--feedback]``: send a goal to a robot's ROS action.

Prints the goal's status lines, its feedback with ``--feedback`` (one JSON line each), then the result as JSON.
Ctrl-C cancels the goal and waits briefly for the canceled result. Exit status: 0 succeeded, 1 any other end
(refused, rejected, aborted, canceled, timeout), 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import orjson

from ..client import RoslinkError
from .connect import add_connection_options, json_object, open_client

CANCEL_WAIT = 5.0  # s to wait for the canceled result after Ctrl-C
EXIT_INTERRUPTED = 130


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("action", help="send a goal to a robot's ROS action (like ros2 action send_goal)",
                       description="ROS actions on a robot, over MQTT.")
    verbs = p.add_subparsers(dest="action_command", required=True, metavar="VERB")
    send = verbs.add_parser("send", help="send one goal and wait for its result (Ctrl-C cancels it)",
                            description="Send GOAL (a JSON object of the action's goal fields) to ACTION, e.g. "
                                        "`roslink-mqtt action send turtle1 fibonacci '{\"order\": 5}' --feedback`.")
    send.add_argument("robot")
    send.add_argument("action")
    send.add_argument("goal", nargs="?", default="{}", help="JSON object with the goal fields (default {})")
    send.add_argument("--feedback", action="store_true", help="print each feedback as a JSON line")
    send.add_argument("--timeout", type=float, default=120.0,
                      help="seconds to wait for the result (default %(default)s); then the goal is canceled")
    add_connection_options(send)
    send.set_defaults(run=run)


def _line(body: dict[str, Any]) -> None:
    print(orjson.dumps(body).decode(), flush=True)


def run(args: argparse.Namespace) -> int:
    goal = json_object(args.goal, "goal")
    client = open_client(args, robots=[args.robot], presence=True)  # the robot cancels our goal if we vanish
    feedback = (lambda fb: _line({"feedback": fb})) if args.feedback else None
    try:
        handle = client.send_goal(args.robot, args.action, goal, feedback)
        try:
            handle.accepted(timeout=min(args.timeout, 30.0))
            print(f"goal {handle.id} accepted by {args.robot}/{args.action}", file=sys.stderr, flush=True)
            result = handle.result(timeout=args.timeout)
        except KeyboardInterrupt:
            print(f"canceling goal {handle.id} …", file=sys.stderr, flush=True)
            handle.cancel()
            try:
                result = handle.result(timeout=CANCEL_WAIT)
            except (RoslinkError, KeyboardInterrupt):
                return EXIT_INTERRUPTED
            _line({"status": result.status, "result": result.result, "error": result.error})
            return EXIT_INTERRUPTED
        except RoslinkError as err:
            if not handle.done() and "no result within" in str(err):
                handle.cancel()
            raise
    except RoslinkError as err:  # refused, rejected, not connected, no answer
        print(f"roslink-mqtt action: {err}")
        return 1
    finally:
        client.close()
    _line({"status": result.status, "result": result.result, "error": result.error})
    return 0 if result.status == "succeeded" else 1
