"""``roslink-mqtt-sim``: a simulated ground robot (ROS 2 node) for demos and tests.

    roslink-mqtt-sim [--ros-args -r __ns:=/robot1 -p odom_rate:=50.0]

Arguments are parsed before rclpy is imported, so ``--help`` (or a typo) never
starts a ROS node. The sim is a demo and test robot, so it always runs with the
loopback-only DDS settings (:mod:`roslink_mqtt.ros_env`): whatever the shell
says, it is never visible beyond this machine. ``ROS_DOMAIN_ID`` is kept when
set (so a bridge started in another terminal with the same id finds it), else 0.
"""

from __future__ import annotations

import argparse
import os
import sys

PARAMETERS = ("odom_rate (20.0 Hz), scan_rate (5.0), gps_rate (1.0), battery_rate (1.0), scan_beams (360), "
              "origin_lat (24.7136), origin_lon (46.6753), room_half_size (5.0 m)")


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """``(ours, ros)``: every ``--ros-args …`` section (up to ``--`` or the end) goes to ROS, as rcl reads it."""
    ours: list[str] = []
    ros: list[str] = []
    in_ros = False
    for arg in argv:
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--" and in_ros:
            in_ros = False
            ros.append(arg)
            continue
        (ros if in_ros else ours).append(arg)
    return ours, ros


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="roslink-mqtt-sim", description="A simulated ground robot as a ROS 2 node: subscribes cmd_vel, "
        "publishes odom, scan, gps/fix and battery_state, offers reset; also takes mode, takeoff, lights, armed, "
        "disarmed, emergency_stop, goal_pose and offers land and get_map, as the demo fleet maps them.",
        epilog=f"ROS arguments go after --ros-args (remapping, namespace, parameters: {PARAMETERS}). DDS stays on "
               "this machine: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and the bundled loopback Fast DDS profile "
               "are always applied; ROS_DOMAIN_ID is kept (default 0).")
    return p.parse_args(argv)


def local_dds_env() -> None:
    """Loopback-only DDS for this process, keeping the caller's domain id (set before rclpy is imported)."""
    from ..ros_env import apply_local_ros_env

    raw = os.environ.get("ROS_DOMAIN_ID", "").strip()
    try:
        domain = int(raw) if raw else 0
    except ValueError:
        raise SystemExit(f"roslink-mqtt-sim: ROS_DOMAIN_ID must be a number, got {raw!r}") from None
    apply_local_ros_env(domain)


def main(argv: list[str] | None = None) -> int:
    """Parse arguments, make DDS local, then (only then) start ROS and spin until Ctrl-C."""
    argv = sys.argv if argv is None else argv
    ours, ros = split_ros_args(list(argv[1:]))
    parse_args(ours)  # --help and usage errors exit here, before anything of ROS is loaded
    local_dds_env()
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from .robot import SimRobot

    rclpy.init(args=[argv[0] if argv else "roslink-mqtt-sim", *ros])
    node = SimRobot()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
