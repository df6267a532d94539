"""The rclpy-shaped API: code written against it has rclpy's structure, so porting it to a ROS node is mostly a
change of imports (docs/sdk.md, *Porting to rclpy*). Its modules are named as rclpy's are::

    from roslink_mqtt.client import rclpy                 # import rclpy
    from roslink_mqtt.client.rclpy.node import Node       # from rclpy.node import Node
    from roslink_mqtt.client.rclpy.qos import QoSProfile  # from rclpy.qos import QoSProfile
    from roslink_mqtt.client.rclpy.action import ActionClient, ActionServer
    from roslink_mqtt.client.rclpy.parameter import Parameter
    from roslink_mqtt.client.rclpy.exceptions import ParameterNotDeclaredException

Messages are dicts and types are names here, which rclpy refuses; underneath every node is a
:class:`~roslink_mqtt.client.RobotClient` (``node.robot_client``).
"""

from .context import create_node, init, ok, shutdown, spin, spin_once, spin_until_future_complete, try_shutdown

__all__ = ["create_node", "init", "ok", "shutdown", "spin", "spin_once", "spin_until_future_complete",
           "try_shutdown"]
