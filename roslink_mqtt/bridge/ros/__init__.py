"""The bridge's ROS adapter: the rclpy node, publishers and subscriptions of the rules, service and action clients
and servers, parameters, the camera and the snapshot ring's ROS side. Everything here may import rclpy; what is
decided without ROS lives in :mod:`roslink_mqtt.bridge.core`.
"""
