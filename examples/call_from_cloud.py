"""Call a ROS service on a robot from anywhere: the robot's ``reset`` (std_srvs/srv/Trigger) over MQTT.

    .venv/bin/python examples/call_from_cloud.py [--url mqtt://127.0.0.1:1883] [--username alice]
                                                 [--password-file FILE] [--robot turtle1] [--service reset]

Uses only the SDK's RobotClient (no ROS on this machine). The call goes
through the broker to the robot's bridge, which calls the ROS service and
sends the response back; the same call is made twice, blocking and with
asyncio. A viewer (``--username bob``) is refused: the error is the robot's
reason. Exits 0 on success, 1 when the call failed.

Connection: ``--url``/``ROSLINK_URL``, ``--username``/``ROSLINK_USERNAME`` and the password from
``ROSLINK_PASSWORD`` or ``--password-file`` (never on the command line), as for every roslink-mqtt
program; without them, the local demo broker and the demo fleet's ``<user>-demo`` login.
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from roslink_mqtt.client import ConnectError, RobotClient, ServiceError
from roslink_mqtt.connection_options import add_connection_options, resolve_login


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_connection_options(p, old_password_option=True)  # --url, --username, --password-file, --ca-file
    p.add_argument("--robot", default="turtle1", help="(default: %(default)s)")
    p.add_argument("--service", default="reset", help="(default: %(default)s)")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds (default: %(default)s)")
    args = p.parse_args(argv)
    login = resolve_login(args, p.prog, default_username="alice")
    # Without ROSLINK_PASSWORD or --password-file: the demo fleet's published <user>-demo login (README.md).
    args.url, args.username, args.ca_file = login.url, login.username, login.ca_file
    args.password = login.password if login.password is not None else f"{login.username}-demo"
    return args


async def call_with_asyncio(client: RobotClient, robot: str, service: str, timeout: float) -> dict:
    # several calls in flight at once; the event loop is never blocked
    _first, second = await asyncio.gather(client.call_async(robot, service, timeout=timeout),
                                         client.call_async(robot, service, timeout=timeout))
    return second


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        with RobotClient(args.username, args.password, url=args.url, robots=[args.robot],
                         ca_file=args.ca_file) as client:
            info = client.wait_for_robot(args.robot, timeout=args.timeout)
            status = getattr(info.system_status, "name", info.system_status)
            print(f"{args.robot} is online (status {status}, bridge session {info.session})")
            values = client.call(args.robot, args.service, timeout=args.timeout)
            print(f"{args.service} (blocking): {values}")
            values = asyncio.run(call_with_asyncio(client, args.robot, args.service, args.timeout))
            print(f"{args.service} (asyncio):  {values}")
    except (ConnectError, TimeoutError) as err:
        print(f"call_from_cloud: {err}", file=sys.stderr)
        return 1
    except ServiceError as err:
        print(f"call_from_cloud: {args.service} failed: {err.reason}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
