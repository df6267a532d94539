"""The simulated robot's navigation: ``navigate_to_pose``, an action of Nav2's NavigateToPose shape
(``roslink_sim_msgs/action/NavigateToPose``, built into the venv by ``make install``: tools/interfaces/).

Like Nav2, it drives by publishing ``cmd_vel`` (so a bridge's stop zeroes the same topic, and cancelling the goal is
what ends the motion) toward the goal's position, then turns to its heading; feedback carries the pose and the
distance left. Goals in another frame than ``map`` or ``odom`` are rejected. A newer goal replaces the one under way
(Nav2's preemption). The steering is :mod:`.steer`; the execute callback awaits timer-resolved futures, as
:mod:`.fibonacci` does, so physics and sensors never wait on a goal.
"""

from __future__ import annotations

import math
import time
from typing import Any

from geometry_msgs.msg import Twist
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from .steer import Steering, wrap
from .wait import executor_sleep
from .world import World

CONTROL_RATE = 20.0  # Hz
FRAMES = ("", "map", "odom")  # the sim's map is its odometry frame
TIMEOUT_PER_METRE = 10.0  # s: a goal not reached in this much per metre (plus 10 s) fails


def load_action_type() -> Any | None:
    """The NavigateToPose-shaped type, or None when the venv has no roslink_sim_msgs (the sim runs without it)."""
    try:
        from roslink_sim_msgs.action import NavigateToPose
    except ImportError:
        return None
    return NavigateToPose


class NavigateServer:
    def __init__(self, node: Node, world: World, action_type: Any, name: str = "navigate_to_pose") -> None:
        self.node, self.world, self.action = node, world, action_type
        self.steering = Steering(max_speed=0.5)
        self.cmd_vel = node.create_publisher(Twist, "cmd_vel", 10)
        self.current: Any = None  # the goal handle being driven
        self.server = ActionServer(node, action_type, name, execute_callback=self.execute,
                                   goal_callback=self.on_goal, handle_accepted_callback=self.on_accepted,
                                   cancel_callback=lambda _goal: CancelResponse.ACCEPT,
                                   callback_group=ReentrantCallbackGroup())

    def on_goal(self, goal: Any) -> GoalResponse:
        frame = goal.pose.header.frame_id
        p = goal.pose.pose.position
        if frame not in FRAMES or not all(math.isfinite(v) for v in (p.x, p.y)):
            self.node.get_logger().info(f"navigate_to_pose: rejected a goal in frame {frame!r} at ({p.x}, {p.y})")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def on_accepted(self, goal_handle: Any) -> None:
        """A new goal preempts the one under way (Nav2 does the same): the old one ends aborted."""
        self.current = goal_handle
        goal_handle.execute()

    async def execute(self, goal_handle: Any) -> Any:
        goal = goal_handle.request.pose.pose
        gx, gy = goal.position.x, goal.position.y
        q = goal.orientation
        gtheta = None if (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 0.0) else \
            math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        started = time.monotonic()
        pose = self.world.pose
        deadline = started + 10.0 + TIMEOUT_PER_METRE * self.steering.remaining(pose.x, pose.y, gx, gy)
        log = self.node.get_logger()
        log.info(f"navigate_to_pose: to ({gx:.2f}, {gy:.2f})" + (f", heading {gtheta:.2f}" if gtheta is not None
                                                                  else ""))
        while True:
            if self.current is not goal_handle:
                goal_handle.abort()  # preempted: the newer goal drives now
                return self._result(1, "preempted by a newer goal")
            if goal_handle.is_cancel_requested:
                self._drive(0.0, 0.0)
                goal_handle.canceled()
                log.info("navigate_to_pose: canceled")
                return self._result(0, "canceled")
            pose = self.world.pose
            v, w, arrived = self.steering.command(pose.x, pose.y, pose.yaw, gx, gy, gtheta)
            if arrived:
                self._drive(0.0, 0.0)
                goal_handle.succeed()
                log.info(f"navigate_to_pose: arrived at ({pose.x:.2f}, {pose.y:.2f}, {wrap(pose.yaw):.2f})")
                return self._result(0, "")
            if time.monotonic() > deadline:
                self._drive(0.0, 0.0)
                goal_handle.abort()
                log.warning("navigate_to_pose: gave up (took too long: a wall in the way?)")
                return self._result(2, "took too long: the goal may be outside the room")
            self._drive(v, w)
            goal_handle.publish_feedback(self._feedback(pose, started, self.steering.remaining(pose.x, pose.y, gx, gy)))
            await executor_sleep(self.node, 1.0 / CONTROL_RATE)

    def _drive(self, v: float, w: float) -> None:
        twist = Twist()
        twist.linear.x, twist.angular.z = v, w
        self.cmd_vel.publish(twist)

    def _result(self, code: int, text: str) -> Any:
        result = self.action.Result()
        result.error_code, result.error_msg = code, text
        return result

    def _feedback(self, pose: Any, started: float, remaining: float) -> Any:
        feedback = self.action.Feedback()
        feedback.current_pose.header.frame_id = "odom"
        feedback.current_pose.pose.position.x, feedback.current_pose.pose.position.y = pose.x, pose.y
        feedback.current_pose.pose.orientation.z = math.sin(pose.yaw / 2.0)
        feedback.current_pose.pose.orientation.w = math.cos(pose.yaw / 2.0)
        elapsed = time.monotonic() - started
        feedback.navigation_time.sec, feedback.navigation_time.nanosec = int(elapsed), int(elapsed % 1 * 1e9)
        feedback.distance_remaining = float(remaining)
        return feedback
