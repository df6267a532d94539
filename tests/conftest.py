"""Session-wide test setup.

DDS must stay on this machine: the loopback-only ROS environment and a fresh
ROS_DOMAIN_ID are set before anything imports rclpy, and every subprocess a
test starts inherits them.
"""

from __future__ import annotations

from roslink_mqtt.ros_env import apply_local_ros_env

ROS_ENV = apply_local_ros_env()
