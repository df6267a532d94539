"""``roslink-mqtt-bridge``: run the bridge for one robot of the fleet.

    roslink-mqtt-bridge --config config/robots.yaml --robot turtle1 [--broker mqtt://127.0.0.1:1883]
                        [--ros-args -r __ns:=/robot1 -r cmd_vel:=/base/cmd_vel]

The robot's password comes from ``ROSLINK_MQTT_PASSWORD``, ``--password-file``,
the config's ``bridge.password_file`` or (demo only) ``bridge.password`` —
never from the command line, where ``ps`` would show it. SIGHUP re-reads the
fleet file's users and grants (as the broker does); rule changes need a restart.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Any

PASSWORD_ENV = "ROSLINK_MQTT_PASSWORD"


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="roslink-mqtt-bridge", description=__doc__.split("\n\n")[0],
                                epilog="Everything after --ros-args goes to ROS (remapping, namespace, parameters).")
    p.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    p.add_argument("--robot", required=True, help="robot name in the fleet file")
    p.add_argument("--broker", help="broker URL, overrides bridge.broker (mqtt://, mqtts://, ws://, wss://)")
    p.add_argument("--password-file", help=f"file whose first line is the robot's password (or set {PASSWORD_ENV})")
    p.add_argument("--ca-file", help="CA bundle for mqtts:// / wss:// brokers")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    return p.parse_args(argv)


def resolve_password(args: argparse.Namespace, bridge_password: str | None, bridge_password_file: str | None,
                     config_dir: Path) -> str:
    if os.environ.get(PASSWORD_ENV):
        return os.environ[PASSWORD_ENV]
    file = args.password_file or bridge_password_file
    if file:
        path = Path(file) if Path(file).is_absolute() or args.password_file else config_dir / file
        try:
            return path.read_text(encoding="utf-8").splitlines()[0].strip()
        except (OSError, IndexError) as err:
            raise SystemExit(f"roslink-mqtt-bridge: cannot read password file {path}: {err}") from None
    if bridge_password:
        return bridge_password
    raise SystemExit(f"roslink-mqtt-bridge: no password for robot '{args.robot}': set {PASSWORD_ENV}, "
                     "--password-file or bridge.password_file in the config")


def reload_grants(bridge: Any, config: str) -> None:
    """SIGHUP: re-read the fleet file; a broken file keeps the running grants (and says why)."""
    from ..config import ConfigError, load_fleet

    try:
        fleet = load_fleet(config)
    except ConfigError as err:
        logging.getLogger("roslink_mqtt.bridge").error("reload failed, keeping the current grants: %s", err)
        return
    bridge.reload(fleet)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args

    from ..config import ConfigError, load_fleet
    from ..mqtt import parse_broker_url
    from .node import Bridge
    from .rules import RuleError

    args = parse_args(remove_ros_args(argv)[1:])
    logging.basicConfig(level=args.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        fleet = load_fleet(args.config)
    except ConfigError as err:
        print(f"roslink-mqtt-bridge: {err}", file=sys.stderr)
        return 2
    robot = fleet.robots.get(args.robot)
    if robot is None:
        print(f"roslink-mqtt-bridge: no robot '{args.robot}' in {args.config} "
              f"(robots: {', '.join(fleet.robots)})", file=sys.stderr)
        return 2
    try:
        url = parse_broker_url(args.broker or robot.bridge.broker_url)
    except ValueError as err:
        print(f"roslink-mqtt-bridge: {err}", file=sys.stderr)
        return 2
    password = resolve_password(args, robot.bridge.password, robot.bridge.password_file,
                                Path(args.config).resolve().parent)
    # We handle SIGINT/SIGTERM ourselves: rclpy's handler would invalidate the context before we
    # could publish the final zero velocity and the offline heartbeat.
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = rclpy.create_node("roslink_mqtt_bridge")
        bridge = Bridge(fleet, robot, node, password=password, broker_url=url, ca_file=args.ca_file)
    except RuleError as err:
        line = f":{err.rule.line}" if err.rule is not None and err.rule.line else ""
        print(f"roslink-mqtt-bridge: {args.config}{line} robots.{robot.name}.{err}", file=sys.stderr)
        rclpy.shutdown()
        return 2
    # One thread: every callback is short and nothing blocks in one (a provided service's call waits
    # as a coroutine). rclpy 7.1's MultiThreadedExecutor stalled ~1 in 20 service replies by 0.2-0.8 s.
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stopping, wake, reload_asked = threading.Event(), threading.Event(), threading.Event()

    def on_signal(flag: threading.Event) -> None:
        flag.set()
        wake.set()

    signal.signal(signal.SIGINT, lambda *_: on_signal(stopping))
    signal.signal(signal.SIGTERM, lambda *_: on_signal(stopping))
    signal.signal(signal.SIGHUP, lambda *_: on_signal(reload_asked))

    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass
        finally:
            stopping.set()

    spinner = threading.Thread(target=spin, name="ros-executor", daemon=True)
    spinner.start()
    bridge.start()
    try:
        while not stopping.is_set():
            wake.wait(0.5)
            wake.clear()
            if reload_asked.is_set() and not stopping.is_set():
                reload_asked.clear()
                reload_grants(bridge, args.config)
    finally:
        bridge.stop()  # zero velocity and the offline heartbeat while ROS and MQTT still work
        executor.shutdown(timeout_sec=2)
        spinner.join(timeout=2)
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
