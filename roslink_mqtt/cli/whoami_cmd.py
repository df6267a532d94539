"""``roslink-mqtt whoami``: your login, and per robot you may see, your role and what you may call and send goals to.

Robots are found from their retained heartbeats (and the ones named on the command line, for brokers that
refuse wildcards); what you may do on each comes from the retained access report its bridge publishes for you
(``to/<user>/access``, docs/protocol.md "What you may do"). Both are retained, so an offline robot is listed
too, with what it last said.
"""

from __future__ import annotations

import argparse
import time

import orjson

from ..client import RobotClient
from ..protocol.control import AccessReport
from ..topics import TopicError, check_name
from .connect import add_connection_options, open_client

ACCESS_WAIT = 2.0  # s for every robot's retained access report after subscribing (it follows the SUBACK)
NO_REPORT = "no access report (its bridge has not connected since you were granted it, or is older)"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("whoami", help="your login, and your role, services and actions on every robot you may see",
                       description="Print who you are logged in as and, for every robot whose heartbeat you may "
                                   "read, your role and the services and actions you may use (from the access "
                                   "report its bridge keeps for you). Exit status 1 when no robot was seen.")
    p.add_argument("names", nargs="*", help="robots to look for (needed on brokers that refuse wildcards)")
    p.add_argument("--wait", type=float, default=1.5, help="seconds to collect heartbeats (default %(default)s)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_connection_options(p)
    p.set_defaults(run=run)


def collect(client: RobotClient, robots: list[str], wait: float = ACCESS_WAIT) -> dict[str, AccessReport | None]:
    """Each robot's access report for us (None where none came within ``wait`` s)."""
    for robot in robots:
        client.watch(robot)
    deadline = time.monotonic() + wait
    while any(client.access(r) is None for r in robots) and time.monotonic() < deadline:
        time.sleep(0.05)
    return {robot: client.access(robot) for robot in robots}


def run(args: argparse.Namespace) -> int:
    try:
        for name in args.names:
            check_name(name, "robot")
    except TopicError as err:
        raise SystemExit(f"roslink-mqtt whoami: {err}") from None
    client = open_client(args, robots=args.names, presence=False)
    try:
        time.sleep(args.wait)
        seen = client.robots()
        robots = sorted(set(seen) | set(args.names))
        reports = collect(client, robots)
    finally:
        client.close()
    online = {r: seen[r].online if r in seen else False for r in robots}
    if args.json:
        print(orjson.dumps({"user": client.username, "url": args.url, "robots": {
            r: {"online": online[r], **({"role": rep.role, "services": list(rep.services),
                                         "actions": list(rep.actions)} if rep else {"role": None})}
            for r, rep in reports.items()}}).decode())
    else:
        print(f"{client.username} @ {args.url}")
        if robots:
            print(f"{'robot':<12} {'presence':<9} {'role':<9} {'services':<24} actions")
        for robot, report in reports.items():
            presence = "online" if online[robot] else "offline" if robot in seen else "not seen"
            if report is None:
                print(f"{robot:<12} {presence:<9} {NO_REPORT}")
                continue
            services = ", ".join(report.services) or "-"
            print(f"{robot:<12} {presence:<9} {report.role:<9} {services:<24} {', '.join(report.actions) or '-'}")
    if not robots:
        if not args.json:
            print("no robots seen" + ("" if args.names else " (name them if your broker refuses wildcards)"))
        return 1
    return 0
