"""The simulated robot's camera: ``camera/image_raw`` (sensor_msgs/Image, rgb8), rendered only while subscribed.

The picture (:mod:`roslink_mqtt.video.scene`) moves with the robot and carries its capture time in its pixels, so
a viewer's glass-to-glass age is measured from the picture itself. Rendering and publishing 640×480 at 30 Hz costs
the sim a third of a core, so nothing is rendered while nobody subscribes (the bridge subscribes only while someone
watches).
"""

from __future__ import annotations

import time

from builtin_interfaces.msg import Time
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from ..video.scene import render
from .world import World


class SimCamera:
    def __init__(self, node: Node, world: World, rate: float, width: int, height: int) -> None:
        self.world, self.width, self.height = world, width, height
        # reliable, newest only: a lost fragment of a ~0.9 MB picture is sent again rather than losing the picture
        # (bridge/ros/video.py camera_qos: 30 pictures a second arrive of 30, 23 best effort)
        self.publisher = node.create_publisher(Image, "camera/image_raw",
                                               QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        self.published = 0
        if rate > 0:
            node.create_timer(1.0 / rate, self.tick)

    def tick(self) -> None:
        if self.publisher.get_subscription_count() == 0:
            return
        now = time.time()
        pose = self.world.pose
        pixels = render(self.width, self.height, pose.x, pose.y, pose.yaw, now)
        msg = Image()
        sec = int(now)
        msg.header.stamp = Time(sec=sec, nanosec=int((now - sec) * 1e9))
        msg.header.frame_id = "camera"
        msg.height, msg.width, msg.encoding, msg.step = self.height, self.width, "rgb8", self.width * 3
        msg.data = pixels.tobytes()
        self.publisher.publish(msg)
        self.published += 1
