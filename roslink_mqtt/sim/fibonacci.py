"""The simulated robot's ROS action: ``fibonacci`` (test_msgs/action/Fibonacci), slow enough to watch.

An action type from a wheel every bridge install has (``ros-jazzy-test-msgs``): the robot computes the
sequence one term per ``step_period`` seconds, publishing the sequence so far as feedback after each term,
so a goal runs long enough to watch its progress and to cancel it. Orders outside 0..MAX_ORDER are
rejected (the int32 terms would overflow), which gives the tests a real ROS-side rejection.

The execute callback is a coroutine that awaits timer-resolved futures: the robot runs on one thread,
and a goal in progress must not hold up its physics or sensors.
"""

from __future__ import annotations

from typing import Any

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from test_msgs.action import Fibonacci

from .wait import executor_sleep

MAX_ORDER = 40


class FibonacciServer:
    def __init__(self, node: Node, name: str = "fibonacci", step_period: float = 0.1) -> None:
        self.node, self.step_period = node, step_period
        self.server = ActionServer(node, Fibonacci, name, execute_callback=self.execute,
                                   goal_callback=self.on_goal, cancel_callback=lambda _goal: CancelResponse.ACCEPT,
                                   callback_group=ReentrantCallbackGroup())

    def on_goal(self, goal: Any) -> GoalResponse:
        if not 0 <= goal.order <= MAX_ORDER:
            self.node.get_logger().info(f"fibonacci: rejected order {goal.order} (0..{MAX_ORDER})")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    async def execute(self, goal_handle: Any) -> Any:
        order = goal_handle.request.order
        sequence = [0, 1][: order + 1] if order < 2 else [0, 1]
        for _ in range(2, order + 1):
            if goal_handle.is_cancel_requested:
                goal_handle.canceled()
                self.node.get_logger().info(f"fibonacci: canceled after {len(sequence)} terms")
                return Fibonacci.Result(sequence=sequence)
            await executor_sleep(self.node, self.step_period)
            sequence.append(sequence[-1] + sequence[-2])
            goal_handle.publish_feedback(Fibonacci.Feedback(sequence=sequence))
        if goal_handle.is_cancel_requested:
            goal_handle.canceled()
            return Fibonacci.Result(sequence=sequence)
        goal_handle.succeed()
        return Fibonacci.Result(sequence=sequence)
