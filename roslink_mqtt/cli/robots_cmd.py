"""``roslink-mqtt robots``: which robots can I see, and are they online?"""

from __future__ import annotations

import argparse
import time

from ..protocol import RobotType, SystemStatus
from .connect import add_connection_options, open_client

CONTROL_WAIT = 1.0  # s for a robot's retained control state


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
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
        # who drives, since when: state/control of each robot someone drives (the heartbeat names only who)
        drivers = {}
        for name, info in robots.items():
            state = client.control(name, timeout=CONTROL_WAIT) if info.online and info.owner else None
            if state is not None and state.holder:
                drivers[name] = state.driver().removeprefix("driven by ")  # the status column shows a stop
    finally:
        client.close()
    if not robots:
        print("no robots seen" + ("" if args.names else " (name them if your broker refuses wildcards)"))
        return 1
    print(f"{'robot':<12} {'status':<10} {'type':<10} {'driven by':<28} {'session':<11} bridge")
    for name, info in sorted(robots.items()):
        status = SystemStatus(info.system_status).name.lower() if info.system_status in list(SystemStatus) \
            else str(info.system_status)
        rtype = RobotType(info.type).name.lower() if info.type in list(RobotType) else str(info.type)
        bridge = f"{info.host} (pid {info.pid})" if info.online and info.host else "-"
        print(f"{name:<12} {status if info.online else 'offline':<10} {rtype:<10} "
              f"{drivers.get(name, info.owner or '-'):<28} {info.session:<11} {bridge}")
    return 0
