"""``roslink-mqtt foxglove``: robots in Foxglove or Lichtblick on ws://localhost:8765 (cli/foxglove_gateway.py)."""

from __future__ import annotations

import argparse
import logging
import os
import sys

from ..topics import check_name, state_name
from .connect import PROG, add_connection_options, open_client, stop_on_signals

ENV_TOKEN = "ROSLINK_FOXGLOVE_TOKEN"  # a token of the user's own (a saved connection keeps working across runs)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("foxglove", help="serve robots to Foxglove or Lichtblick (Foxglove WebSocket protocol)",
                       description="Log in as you and serve the robots you may see on a Foxglove WebSocket "
                                   "(foxglove.websocket.v1): their state as channels with schemas, their services, "
                                   "parameters and, for operators, twists published by Foxglove's Teleop panel on "
                                   "<prefix>/<robot>/cmd/twist. Open the URL it prints (ws://127.0.0.1:PORT/"
                                   "?token=…) in Foxglove or Lichtblick. Nothing is opened on the robots. Whoever "
                                   "connects acts as you: web pages from other origins are refused, and the URL "
                                   f"carries a secret made for this run (or ${ENV_TOKEN}).")
    p.add_argument("robots", nargs="*", metavar="ROBOT", help="only these robots (default: every one you see)")
    p.add_argument("--port", type=int, default=8765, help="WebSocket port (default: %(default)s; 0 picks one)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default: %(default)s: this machine only; anyone who reaches it "
                        "with the token acts as you)")
    p.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                   help="also accept WebSockets from pages of this origin (https://foxglove.example.com; "
                        "repeatable). Always accepted: programs (no Origin), Foxglove's web app "
                        "https://app.foxglove.dev, Lichtblick's https://lichtblick-suite.github.io and, with a "
                        "token, pages opened from disk (Origin null: desktop Lichtblick, tools/foxglove-view.html)")
    p.add_argument("--no-token", action="store_true",
                   help="accept clients without the per-run token (for a client that cannot pass one): then any "
                        "program on this machine, and any page of an allowed origin, acts as you")
    p.add_argument("--topic", action="append", default=[], metavar="NAME",
                   help="only this state (global_motion, image …; repeatable); heartbeats always")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        import cryptography  # noqa: F401 - the certificate of the SDK's own port (cli/foxglove_front.py)

        from .foxglove_gateway import FoxgloveGateway
    except ImportError:
        print(f"{PROG} foxglove: needs the foxglove-sdk and cryptography packages: pip install 'roslink-mqtt[cli]'",
              file=sys.stderr)
        return 2
    for robot in args.robots:
        check_name(robot, "robot")
    # the front's refusals and the SDK's dropped clients are warnings: the terminal shows them
    logging.basicConfig(level=logging.WARNING, format=f"{PROG} foxglove: %(levelname)s: %(message)s")
    token = os.environ.get(ENV_TOKEN) or None
    try:  # before logging in: a bad option is the user's to fix, not a reason to touch the broker
        from .foxglove_front import check_token, normalize_origin

        origins = [normalize_origin(origin) for origin in args.allow_origin]
        if token and not args.no_token:
            check_token(token)
    except ValueError as err:
        print(f"{PROG} foxglove: {err}", file=sys.stderr)
        return 2
    client = open_client(args, robots=args.robots)
    gateway = FoxgloveGateway(client, args.robots, host=args.host, port=args.port,
                              topics=[state_name(t) for t in args.topic], require_token=not args.no_token,
                              token=token, allow_origins=origins)
    stop = stop_on_signals()
    try:
        port = gateway.start()
    except Exception as err:  # noqa: BLE001 - the port is taken, the address is not ours: say so, no traceback
        client.close()
        print(f"{PROG} foxglove: cannot listen on {args.host}:{args.port}: {err}", file=sys.stderr)
        return 1
    if args.no_token:
        print(f"{PROG} foxglove: WARNING: --no-token: any program on this machine (and any page of an allowed "
              f"origin) that connects to port {port} acts as {args.username}", file=sys.stderr)
    print(f"serving {', '.join(args.robots) or 'every robot ' + args.username + ' sees'} to Foxglove on "
          f"{gateway.url} (Ctrl-C ends it)", file=sys.stderr, flush=True)
    try:
        stop.wait()
    finally:
        gateway.close()
        client.close()
    return 0
