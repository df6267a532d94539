"""``roslink-mqtt-sim``: the simulated robot as a ROS 2 node.

Subscribes ``cmd_vel`` (geometry_msgs/Twist); publishes ``odom``
(nav_msgs/Odometry), ``battery_state`` (sensor_msgs/BatteryState), ``scan``
(sensor_msgs/LaserScan) and ``gps/fix`` (sensor_msgs/NavSatFix); offers
``reset`` (std_srvs/Trigger). Like a real base it simply obeys the last
command it got: stopping it when the operator vanishes is the bridge's job.
"""

from __future__ import annotations

import math
import sys

import rclpy
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import BatteryState, LaserScan, NavSatFix, NavSatStatus
from std_srvs.srv import Trigger

from .world import World

PHYSICS_RATE = 50.0  # Hz


class SimRobot(Node):
    def __init__(self) -> None:
        super().__init__("sim_robot")
        rate = {name: self.declare_parameter(f"{name}_rate", default).value
                for name, default in (("odom", 20.0), ("scan", 5.0), ("gps", 1.0), ("battery", 1.0))}
        self.beams = int(self.declare_parameter("scan_beams", 360).value)
        self.lat0 = float(self.declare_parameter("origin_lat", 24.7136).value)
        self.lon0 = float(self.declare_parameter("origin_lon", 46.6753).value)
        self.world = World(half_size=float(self.declare_parameter("room_half_size", 5.0).value))
        self.battery = 100.0
        self.odom_pub = self.create_publisher(Odometry, "odom", 10)
        self.scan_pub = self.create_publisher(LaserScan, "scan", qos_profile_sensor_data)
        self.gps_pub = self.create_publisher(NavSatFix, "gps/fix", 10)
        self.battery_pub = self.create_publisher(BatteryState, "battery_state", 10)
        self.create_subscription(Twist, "cmd_vel", self.on_cmd_vel, 10)
        self.create_service(Trigger, "reset", self.on_reset)
        self.create_timer(1.0 / PHYSICS_RATE, self.on_physics)
        self.create_timer(1.0 / rate["odom"], self.publish_odom)
        self.create_timer(1.0 / rate["scan"], self.publish_scan)
        self.create_timer(1.0 / rate["gps"], self.publish_gps)
        self.create_timer(1.0 / rate["battery"], self.publish_battery)
        self.get_logger().info(f"simulated robot ready in a {2 * self.world.half_size:g} m room")

    def on_cmd_vel(self, msg: Twist) -> None:
        self.world.command(msg.linear.x, msg.angular.z)

    def on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.world.reset()
        response.success, response.message = True, "pose reset to the room centre"
        return response

    def on_physics(self) -> None:
        self.world.step(1.0 / PHYSICS_RATE)
        moving = abs(self.world.v) + abs(self.world.w)
        self.battery = max(0.0, self.battery - (0.0005 + 0.002 * moving) / PHYSICS_RATE)

    def publish_odom(self) -> None:
        p, msg = self.world.pose, Odometry()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.pose.pose.position.x, msg.pose.pose.position.y = p.x, p.y
        msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(p.yaw / 2), math.cos(p.yaw / 2)
        msg.twist.twist.linear.x, msg.twist.twist.angular.z = self.world.v, self.world.w
        self.odom_pub.publish(msg)

    def publish_scan(self) -> None:
        msg = LaserScan()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = "base_link"
        msg.angle_min = -math.pi
        msg.angle_increment = 2 * math.pi / self.beams
        msg.angle_max = msg.angle_min + (self.beams - 1) * msg.angle_increment
        msg.range_min, msg.range_max = 0.1, 8.0
        msg.scan_time = 1.0 / 5.0
        msg.ranges = [r if r <= msg.range_max else math.inf
                      for r in self.world.scan(self.beams, msg.angle_min, msg.angle_max)]
        self.scan_pub.publish(msg)

    def publish_gps(self) -> None:
        msg = NavSatFix()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = "gps"
        msg.status.status, msg.status.service = NavSatStatus.STATUS_FIX, NavSatStatus.SERVICE_GPS
        msg.latitude, msg.longitude = self.world.geodetic(self.lat0, self.lon0)
        msg.altitude = 612.0
        msg.position_covariance_type = NavSatFix.COVARIANCE_TYPE_APPROXIMATED
        self.gps_pub.publish(msg)

    def publish_battery(self) -> None:
        msg = BatteryState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.voltage = 11.1 + 1.5 * self.battery / 100.0
        msg.current = -0.8 - 2.0 * (abs(self.world.v) + abs(self.world.w))
        msg.percentage = self.battery / 100.0
        msg.present = True
        msg.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
        self.battery_pub.publish(msg)


def main(argv: list[str] | None = None) -> int:
    rclpy.init(args=sys.argv if argv is None else argv)
    node = SimRobot()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
