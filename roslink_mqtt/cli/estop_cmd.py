"""``roslink-mqtt estop ROBOT… | --all``: emergency-stop robots, and say which ones acknowledged."""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING, Any

from .connect import add_connection_options, open_client

if TYPE_CHECKING:
    from ..client import RobotClient


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("estop", help="emergency-stop robots (--all: every robot you may stop)",
                       description="Send an emergency stop to the robots named, or with --all to every robot whose "
                                   "heartbeat you see and that you may stop (viewers too, unless a robot says "
                                   "`estop: operators`), then print per robot whether its bridge acknowledged it "
                                   "within --timeout. Exit status 1 when any did not. Only the holder of control "
                                   "(or a supervisor) can resume a robot: `roslink-mqtt pub ROBOT arm`.")
    p.add_argument("robots", nargs="*", help="robots to stop")
    p.add_argument("--all", action="store_true", help="every robot you may stop")
    p.add_argument("--reason", default="", help="said in the stop (and the robot's log)")
    p.add_argument("--timeout", type=float, default=1.0, help="seconds each robot has to acknowledge "
                                                              "(default %(default)s)")
    p.add_argument("--wait", type=float, default=1.5, help="with --all: seconds to watch for robots' heartbeats; "
                                                           "the stops go out as soon as they have come, and a robot "
                                                           "seen later within this time is stopped too "
                                                           "(default %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if bool(args.robots) == bool(args.all):
        raise SystemExit("roslink-mqtt estop: name the robots to stop, or pass --all (not both)")
    client = open_client(args, robots=args.robots, presence=False)
    reason = args.reason or "roslink-mqtt estop"
    try:
        if args.all:
            reports = stop_every_robot_seen(client, reason, args.wait, args.timeout)
            if not reports:
                print("roslink-mqtt estop: no robots seen (name them if your broker refuses wildcards)",
                      file=sys.stderr)
                return 1
        else:
            reports = client.emergency_stop_all(reason, robots=args.robots, timeout=args.timeout)
    finally:
        client.close()
    for report in reports.values():
        print(report.line())
    return 0 if reports and all(r.acknowledged for r in reports.values()) else 1


QUIET = 0.25  # s without a new robot: the broker has sent every retained heartbeat (they come in one burst)


def stop_every_robot_seen(client: RobotClient, reason: str, wait: float, timeout: float) -> dict[str, Any]:
    """``estop --all``: stop the robots as soon as their retained heartbeats have come, then keep watching until
    ``wait`` is over and stop any robot seen later (a heartbeat held up on a slow link); a report per robot."""
    start = time.monotonic()
    _wait_for_heartbeats(client, wait)
    reports: dict[str, Any] = {}
    tried: set[str] = set()  # a robot this user may not stop gets no report, and is not tried again
    while True:
        new = sorted(set(client.robots()) - tried)
        if new:
            tried.update(new)
            reports.update(client.emergency_stop_all(reason, robots=new, timeout=timeout))
        elif time.monotonic() - start >= wait:
            return reports
        else:
            time.sleep(0.02)


def _wait_for_heartbeats(client: RobotClient, longest: float) -> None:
    """Until the robots' retained heartbeats have arrived: they follow the subscription in one burst, so once
    some came and no new robot appeared for QUIET, the stops go out (they must not wait longer); a robot seen
    later is stopped as it appears."""
    start = last_change = time.monotonic()
    seen = 0
    while time.monotonic() - start < longest:
        count = len(client.robots())
        now = time.monotonic()
        if count != seen:
            seen, last_change = count, now
        elif seen and now - last_change >= QUIET:
            return
        time.sleep(0.02)
