"""Client SDK for programs without ROS (core install: paho-mqtt, orjson, pyyaml — no rclpy, no amqtt)."""

from .presence import OperatorPresence

__all__ = ["OperatorPresence"]
