"""The robot's ``/rosout`` with rclpy: the port of the ``log`` capability (docs/protocol.md, "Logging").

Who may log and how much is :mod:`roslink_mqtt.bridge.core.capabilities.logs`' (ROS-free). Here a line becomes an
``rcl_interfaces/msg/Log`` named after the SDK node, so a program without ROS shows up in
``ros2 topic echo /rosout``, rqt_console and bags like any ROS node.
"""

from __future__ import annotations

from rcl_interfaces.msg import Log
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from ...protocol.rosout import LogLine
from ..core.capabilities.logs import ROSOUT_PORT
from .ports import PortMaker

# rclpy's own /rosout publisher profile: late joiners (rqt_console) get the recent lines
ROSOUT_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class RosRosout:
    """One publisher on ``/rosout`` (publishing on an rclpy publisher is thread-safe)."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.publisher = node.create_publisher(Log, "/rosout", ROSOUT_QOS)

    def publish_log(self, node_name: str, line: LogLine) -> None:
        now = self.node.get_clock().now().to_msg()
        self.publisher.publish(Log(stamp=now, level=line.level, name=node_name, msg=line.msg, file=line.file,
                                   function=line.function, line=line.line))


# the port of log/* (capabilities/logs.py), made from the bridge's node (bridge/ros/ports.py)
MAKES = (PortMaker(ROSOUT_PORT, lambda side: RosRosout(side.node)),)
