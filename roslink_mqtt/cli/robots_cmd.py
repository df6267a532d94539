"""``roslink-mqtt robots``: which robots can I see, and are they online?"""

from __future__ import annotations

import argparse
import time

from ..protocol import RobotType, SystemStatus
from .connect import add_connection_options, open_client


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("robots", help="list the robots you may see, with their presence",
                       description="Collect retained heartbeats for a moment and print one line per robot.")
    p.add_argument("names", nargs="*", help="robots to look for (needed on brokers that refuse wildcards)")
    p.add_argument("--wait", type=float, default=1.5, help="seconds to collect heartbeats (default %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    client = open_client(args, robots=args.names, presence=False)
    try:
        time.sleep(args.wait)
        robots = client.robots()
    finally:
        client.close()
    if not robots:
        print("no robots seen" + ("" if args.names else " (name them if your broker refuses wildcards)"))
        return 1
    print(f"{'robot':<12} {'status':<10} {'type':<10} {'owner':<10} session")
    for name, info in sorted(robots.items()):
        status = SystemStatus(info.system_status).name.lower() if info.system_status in iter(SystemStatus) \
            else str(info.system_status)
        rtype = RobotType(info.type).name.lower() if info.type in iter(RobotType) else str(info.type)
        print(f"{name:<12} {status if info.online else 'offline':<10} {rtype:<10} {info.owner or '-':<10} "
              f"{info.session}")
    return 0
