"""VDA 5050 (2.1.0) for a ROSLink robot: the standard's topics and messages, spoken by the bridge.

A factory's master control speaks VDA 5050 over MQTT (``uagv/v2/<manufacturer>/<serialNumber>/...``). This
package is the ROS-free part of the robot's side: the wire (topics, headers, timestamps), orders read and checked
the standard's way, and the vehicle's order state machine (which node to drive to next, what ``state`` says).
The bridge's ROS adapter feeds it poses and the navigation action's results and carries out what it decides.
Nothing here imports rclpy or amqtt (docs/architecture.md, "Layers").
"""
