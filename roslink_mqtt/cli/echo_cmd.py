"""``roslink-mqtt echo ROBOT NAME``: print a robot's state messages as JSON lines."""

from __future__ import annotations

import argparse
import time

import orjson

from ..client import RoslinkMessage
from .connect import add_connection_options, open_client


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("echo", help="print a robot's state messages (like ros2 topic echo)",
                       description="Print each message on roslink/ROBOT/state/NAME as one JSON line.")
    p.add_argument("robot")
    p.add_argument("name", help="state name, e.g. global_motion, robot_status, ack")
    p.add_argument("-n", "--count", type=int, default=0, help="stop after COUNT messages (0 = until Ctrl-C)")
    p.add_argument("--timeout", type=float, default=0.0, help="give up after this many seconds (0 = never)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    client = open_client(args, robots=[args.robot], presence=False)
    seen = 0
    deadline = time.monotonic() + args.timeout if args.timeout else None
    try:
        sub = client.subscribe(args.robot, args.name)
        while not args.count or seen < args.count:
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                break
            try:
                item = sub.get(timeout=min(left, 1.0) if left is not None else 1.0)
            except TimeoutError:
                continue
            if item is None:
                continue
            body = item.payload() if isinstance(item, RoslinkMessage) else item
            print(orjson.dumps(body).decode(), flush=True)
            seen += 1
    except KeyboardInterrupt:
        pass
    finally:
        client.close()
    return 0 if seen or not args.count else 1
