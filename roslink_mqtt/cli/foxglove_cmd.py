"""``roslink-mqtt foxglove``: robots in Foxglove or Lichtblick on ws://localhost:8765 (cli/foxglove_gateway.py)."""

from __future__ import annotations

import argparse
import sys

from ..topics import check_name, state_name
from .connect import PROG, add_connection_options, open_client, stop_on_signals


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("foxglove", help="serve robots to Foxglove or Lichtblick (Foxglove WebSocket protocol)",
                       description="Log in as you and serve the robots you may see on a Foxglove WebSocket "
                                   "(foxglove.websocket.v1): their state as channels with schemas, their services, "
                                   "parameters and, for operators, twists published by Foxglove's Teleop panel on "
                                   "<prefix>/<robot>/cmd/twist. Open ws://localhost:PORT in Foxglove or Lichtblick. "
                                   "Nothing is opened on the robots.")
    p.add_argument("robots", nargs="*", metavar="ROBOT", help="only these robots (default: every one you see)")
    p.add_argument("--port", type=int, default=8765, help="WebSocket port (default: %(default)s; 0 picks one)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default: %(default)s: this machine only; the WebSocket has no login, "
                        "so anyone who reaches it acts as you)")
    p.add_argument("--topic", action="append", default=[], metavar="NAME",
                   help="only this state (global_motion, image …; repeatable); heartbeats always")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        from .foxglove_gateway import FoxgloveGateway
    except ImportError:
        print(f"{PROG} foxglove: needs the foxglove-sdk package: pip install 'roslink-mqtt[cli]'", file=sys.stderr)
        return 2
    for robot in args.robots:
        check_name(robot, "robot")
    client = open_client(args, robots=args.robots)
    gateway = FoxgloveGateway(client, args.robots, host=args.host, port=args.port,
                              topics=[state_name(t) for t in args.topic])
    stop = stop_on_signals()
    try:
        port = gateway.start()
    except Exception as err:  # noqa: BLE001 - the port is taken, the address is not ours: say so, no traceback
        client.close()
        print(f"{PROG} foxglove: cannot listen on {args.host}:{args.port}: {err}", file=sys.stderr)
        return 1
    print(f"serving {', '.join(args.robots) or 'every robot ' + args.username + ' sees'} to Foxglove on "
          f"ws://{args.host}:{port} (Ctrl-C ends it)", file=sys.stderr, flush=True)
    try:
        stop.wait()
    finally:
        gateway.close()
        client.close()
    return 0
