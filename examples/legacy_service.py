"""A program without ROS provides two ROS services on a robot, through its bridge.

    .venv/bin/python examples/legacy_service.py [--url mqtt://127.0.0.1:1883] [--username alice]
                                                [--password-file FILE] [--robot turtle1]

Only the SDK is used (no rclpy: this runs on machines that cannot install ROS).
While it runs, the robot's ROS graph has

* ``enable_motors`` (std_srvs/srv/SetBool) — switches the (pretend) motor driver;
* ``self_test`` (std_srvs/srv/Trigger) — runs a (pretend) hardware check.

Any ROS node calls them like local services, e.g. ``examples/ros_caller.py`` or
``ros2 service call /enable_motors std_srvs/srv/SetBool "{data: true}"``. Stop
this program (Ctrl-C) and the services disappear from ROS; kill it and they
disappear too, when its presence last-will fires.

The code is written against the rclpy-shaped API; docs/sdk.md (*Porting to
rclpy*) lists the steps that make it a ROS node (the import, message classes
instead of type names and dicts, ROS names instead of MQTT ones).

Connection: ``--url``/``ROSLINK_URL``, ``--username``/``ROSLINK_USERNAME`` and the password from
``ROSLINK_PASSWORD`` or ``--password-file`` (never on the command line), as for every roslink-mqtt
program; without them, the local demo broker and the demo fleet's ``<user>-demo`` login.
"""

from __future__ import annotations

import argparse
import signal
import time

from roslink_mqtt.client import rclpy
from roslink_mqtt.connection_options import add_connection_options, resolve_login


class MotorDriver:
    """Stands in for the legacy system: a motor controller on a serial line, say."""

    def __init__(self, check_seconds: float) -> None:
        self.enabled = False
        self.check_seconds = check_seconds

    def self_test(self) -> tuple[bool, str]:
        time.sleep(self.check_seconds)  # the hardware check takes a while
        return True, f"self test passed: controller answers, motors {'enabled' if self.enabled else 'disabled'}"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_connection_options(p, old_password_option=True)  # --url, --username, --password-file, --ca-file
    p.add_argument("--robot", default="turtle1", help="(default: %(default)s)")
    p.add_argument("--self-test-seconds", type=float, default=0.2, help="how long self_test takes (%(default)s s)")
    p.add_argument("--run-seconds", type=float, help="stop after this many seconds (default: until Ctrl-C)")
    args = p.parse_args(argv)
    login = resolve_login(args, p.prog, default_username="alice")
    # Without ROSLINK_PASSWORD or --password-file: the demo fleet's published <user>-demo login (README.md).
    args.url, args.username, args.ca_file = login.url, login.username, login.ca_file
    args.password = login.password if login.password is not None else f"{login.username}-demo"
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    driver = MotorDriver(args.self_test_seconds)

    rclpy.init()
    node = rclpy.create_node("legacy_service", robot=args.robot, url=args.url, username=args.username,
                             password=args.password, ca_file=args.ca_file)
    log = node.get_logger()

    def enable_motors(request: dict, response: dict) -> dict:
        driver.enabled = bool(request.get("data", False))
        response["success"] = True
        response["message"] = "motors enabled" if driver.enabled else "motors disabled"
        log.info(response["message"])
        return response

    def self_test(_request: dict, response: dict) -> dict:
        response["success"], response["message"] = driver.self_test()
        log.info(response["message"])
        return response

    node.create_service("std_srvs/srv/SetBool", "enable_motors", enable_motors)
    # the robot lets a ROS caller wait this long for our answer
    node.create_service("std_srvs/srv/Trigger", "self_test", self_test, timeout=max(5.0, args.self_test_seconds + 5))
    log.info(f"providing enable_motors and self_test on {args.robot} as {args.username}")

    signal.signal(signal.SIGTERM, lambda *_: rclpy.shutdown())  # systemd stop: withdraw cleanly
    deadline = None if args.run_seconds is None else time.monotonic() + args.run_seconds
    try:
        while rclpy.ok() and (deadline is None or time.monotonic() < deadline):
            rclpy.spin_once(node, timeout_sec=0.5)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()  # withdraws both services: the ROS side goes away now, not at a timeout
        rclpy.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
