"""The simulated robot as a ROS 2 node (imported by :mod:`.node` only after its arguments are parsed).

Subscribes ``cmd_vel`` (geometry_msgs/Twist); publishes ``odom``
(nav_msgs/Odometry), ``battery_state`` (sensor_msgs/BatteryState), ``scan``
(sensor_msgs/LaserScan), ``gps/fix`` (sensor_msgs/NavSatFix) and, while
subscribed, ``camera/image_raw`` (sensor_msgs/Image, :mod:`.camera`); offers
``reset`` (std_srvs/Trigger). Like a real base it simply obeys the last
command it got: stopping it when the operator vanishes is the bridge's job.

It also has an endpoint for every other command the demo fleet maps, so each
example in the docs does something a user can see: ``mode``
(std_msgs/String, set_mode), ``takeoff`` (std_msgs/Float64), ``lights``
(std_msgs/Bool, an on-demand generic rule), ``armed``/``disarmed``/
``emergency_stop`` (std_msgs/Bool) and ``goal_pose`` (PoseStamped) are logged;
``land`` and ``get_map`` (std_srvs/Trigger) answer, and the bridge reports
the answer on ``state/ack``. A ground robot does not fly: takeoff and land
say so instead of pretending. ``fibonacci`` (test_msgs/action/Fibonacci) is a
ROS action whose goals take a while and report progress (:mod:`.fibonacci`);
``navigate_to_pose`` (Nav2's NavigateToPose shape) drives the robot to a pose
by itself (:mod:`.navigate`).
"""

from __future__ import annotations

import math
import os

from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import BatteryState, LaserScan, NavSatFix, NavSatStatus
from std_msgs.msg import Bool, Float64, String
from std_srvs.srv import Trigger

from .camera import SimCamera
from .fibonacci import FibonacciServer
from .navigate import NavigateServer, load_action_type
from .world import World

PHYSICS_RATE = 50.0  # Hz


class SimRobot(Node):
    """The robot: physics at PHYSICS_RATE, sensors on timers, commands logged so a demo can see them arrive."""

    def __init__(self) -> None:
        super().__init__("sim_robot")
        rate = {name: self.declare_parameter(f"{name}_rate", default).value
                for name, default in (("odom", 20.0), ("scan", 5.0), ("gps", 1.0), ("battery", 1.0))}
        self.beams = int(self.declare_parameter("scan_beams", 360).value)
        self.lat0 = float(self.declare_parameter("origin_lat", 24.7136).value)
        self.lon0 = float(self.declare_parameter("origin_lon", 46.6753).value)
        self.world = World(half_size=float(self.declare_parameter("room_half_size", 5.0).value))
        # max_speed is worth tuning live (ros2 param set, or over MQTT): the motion model reads it every command
        self.world.max_speed = float(self.declare_parameter(
            "max_speed", 1.0, ParameterDescriptor(description="top forward speed of the motors, m/s",
                                                  floating_point_range=[FloatingPointRange(from_value=0.0,
                                                                                           to_value=5.0)])).value)
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.battery = 100.0
        self.odom_pub = self.create_publisher(Odometry, "odom", 10)
        self.scan_pub = self.create_publisher(LaserScan, "scan", qos_profile_sensor_data)
        self.gps_pub = self.create_publisher(NavSatFix, "gps/fix", 10)
        self.battery_pub = self.create_publisher(BatteryState, "battery_state", 10)
        self.create_subscription(Twist, "cmd_vel", self.on_cmd_vel, 10)
        self.create_service(Trigger, "reset", self.on_reset)
        self.mode, self.lights = "MANUAL", False
        log = self.get_logger()
        self.create_subscription(String, "mode", self.on_mode, 10)
        self.create_subscription(Float64, "takeoff", self.on_takeoff, 10)
        self.create_subscription(Bool, "lights", self.on_lights, 10)
        # rclpy types a subscription callback's message as an unbound TypeVar: these say what arrives
        def on_goal(m: PoseStamped) -> None:
            log.info(f"goal ({m.pose.position.x:g}, {m.pose.position.y:g}) in {m.header.frame_id or '?'}: no "
                     "planner here, drive with cmd_vel")

        def on_armed(m: Bool) -> None:
            log.info(f"armed: {m.data}")

        def on_disarmed(m: Bool) -> None:
            log.info(f"disarmed: {m.data}")

        def on_emergency_stop(m: Bool) -> None:
            log.warning(f"emergency stop: {m.data}")

        self.create_subscription(PoseStamped, "goal_pose", on_goal, 10)
        self.create_subscription(Bool, "armed", on_armed, 10)
        self.create_subscription(Bool, "disarmed", on_disarmed, 10)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)  # as the bridge publishes it
        self.create_subscription(Bool, "emergency_stop", on_emergency_stop, latched)
        self.fibonacci = FibonacciServer(self)  # a ROS action: goals with feedback, cancelable
        navigate_type = load_action_type()  # drives itself to a pose (a VDA 5050 order's nodes: docs/vda5050.md)
        self.navigate = NavigateServer(self, self.world, navigate_type) if navigate_type is not None else None
        if self.navigate is None:
            self.get_logger().info("no navigate_to_pose: roslink_sim_msgs is not installed (make install builds it)")
        self.create_service(Trigger, "land", self.on_land)
        self.create_service(Trigger, "get_map", self.on_get_map)
        self.create_timer(1.0 / PHYSICS_RATE, self.on_physics)
        self.create_timer(1.0 / rate["odom"], self.publish_odom)
        self.create_timer(1.0 / rate["scan"], self.publish_scan)
        self.create_timer(1.0 / rate["gps"], self.publish_gps)
        self.create_timer(1.0 / rate["battery"], self.publish_battery)
        # a camera (camera/image_raw): rendered only while something subscribes (the bridge, while watched)
        self.camera = SimCamera(self, self.world, float(self.declare_parameter("camera_rate", 30.0).value),
                                int(self.declare_parameter("camera_width", 640).value),
                                int(self.declare_parameter("camera_height", 480).value))
        dds = f"ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')} " + " ".join(
            f"{k}={os.environ.get(k, '(unset)')}" for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "RMW_IMPLEMENTATION"))
        self.get_logger().info(f"simulated robot ready in a {2 * self.world.half_size:g} m room; DDS: {dds}")

    def on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Apply max_speed when it changes (the descriptor's range has refused values outside 0..5 already)."""
        for parameter in parameters:
            if parameter.name == "max_speed":
                self.world.max_speed = float(parameter.value)
                self.get_logger().info(f"max_speed is now {self.world.max_speed:g} m/s")
        return SetParametersResult(successful=True)

    def on_cmd_vel(self, msg: Twist) -> None:
        self.world.command(msg.linear.x, msg.angular.z)

    def on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.world.reset()
        response.success, response.message = True, "pose reset to the room centre"
        return response

    def on_mode(self, msg: String) -> None:
        self.mode = msg.data
        self.get_logger().info(f"mode: {msg.data}")

    def on_takeoff(self, msg: Float64) -> None:
        self.get_logger().info(f"takeoff to {msg.data:g} m requested: a ground robot stays on the ground")

    def on_lights(self, msg: Bool) -> None:
        self.lights = msg.data
        self.get_logger().info(f"lights {'on' if msg.data else 'off'}")

    def on_land(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.get_logger().info("land requested")
        response.success, response.message = True, "a ground robot is always landed"
        return response

    def on_get_map(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        size = 2 * self.world.half_size
        self.get_logger().info("map requested")
        response.success = True
        response.message = f"an empty {size:g} m x {size:g} m room centred on the start pose (no map server here)"
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
