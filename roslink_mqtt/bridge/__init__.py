"""The robot side: an rclpy node mapping ROS topics and services to MQTT. Needs the ``[bridge]`` extra.

Imports rclpy, never amqtt: a robot installs ``[bridge]`` without ``[broker]`` (pyproject.toml).
"""
