"""SDK log lines reach the robot's /rosout (rcl_interfaces/msg/Log) with the SDK node's name, filtered by its level.

Real processes: a broker (embedded, and Mosquitto with the exported ACL), simulated robot, bridge; an SDK node
in this process; an rclpy probe reading /rosout. A viewer's lines are refused (never on /rosout) and the refusal
is not logged in a loop.
"""

from __future__ import annotations

import logging

import pytest

from roslink_mqtt.client import rclpy as sdk
from tests.support.robot_stack import BROKERS, turtle1_online
from tests.support.ros import RosProbe
from tests.support.waits import never, wait_until

pytestmark = pytest.mark.timeout(120)


@pytest.mark.parametrize("broker", BROKERS)
def test_sdk_logger_reaches_rosout(tmp_path, broker: str) -> None:
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    probe = RosProbe()
    try:
        rosout = probe.watch(Log, "/rosout", QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                                        durability=DurabilityPolicy.TRANSIENT_LOCAL))
        with turtle1_online(tmp_path, broker) as port:
            url = f"mqtt://127.0.0.1:{port}"
            name = f"legacy_arm_{broker}"  # logger levels are per name for the whole process, as in rclpy
            node = sdk.create_node(name, robot="turtle1", url=url, username="alice", password="alice-demo")
            try:
                node.robot_client.wait_for_robot("turtle1", timeout=10)
                wait_until("turtle1's access report", lambda: node.robot_client.access("turtle1") is not None,
                           timeout=10)  # the access report says we are an operator
                log = node.get_logger()
                log.debug("not sent: below the default level")
                log.info("gripper closed")
                log.error("gripper jammed")
                _, line = rosout.wait_for(lambda m: m.name == name and m.msg == "gripper closed", timeout=10)
                assert line.level == Log.INFO and line.function == "test_sdk_logger_reaches_rosout"
                assert line.file.endswith("test_rosout.py") and line.line > 0
                _, jammed = rosout.wait_for(lambda m: m.msg == "gripper jammed", timeout=10)
                assert jammed.level == Log.ERROR
                log.set_level(logging.DEBUG)
                log.debug("now sent")
                rosout.wait_for(lambda m: m.msg == "now sent" and m.level == Log.DEBUG, timeout=10)
                log.get_child("wrist").warning("child logger")
                _, child = rosout.wait_for(lambda m: m.msg == "child logger", timeout=10)
                assert child.name == f"{name}.wrist" and child.level == Log.WARN
                never("the debug line below the default level on /rosout",
                      lambda: [m for _, m in rosout.since(0) if m.msg == "not sent: below the default level"],
                      seconds=0.5)
                assert not [m for _, m in rosout.since(0) if m.msg == "not sent: below the default level"]
            finally:
                node.destroy_node()
            viewer = sdk.create_node("viewer_prog", robot="turtle1", url=url, username="bob", password="bob-demo")
            try:
                viewer.robot_client.wait_for_robot("turtle1", timeout=10)
                viewer.get_logger().info("from a viewer")
                never("a viewer's line on /rosout", lambda: [m for _, m in rosout.since(0) if m.name == "viewer_prog"],
                      seconds=1.0)
                assert not [m for _, m in rosout.since(0) if m.name == "viewer_prog"]
            finally:
                viewer.destroy_node()
    finally:
        probe.close()
