"""The bridge's ROS-free core: routing, authorization, the command path's safety, presence, the uplink's scheduler
and meters, the MQTT links. Imports neither rclpy nor amqtt, nor anything from :mod:`roslink_mqtt.bridge.ros`
(tests/unit/test_bridge_boundary.py): what it needs from ROS it is handed, as typed ports, by the ROS adapter.
Unit-tested with plain Python objects.
"""
