"""Waiting inside the simulated robot's action callbacks without holding its one thread."""

from __future__ import annotations

from rclpy.node import Node
from rclpy.task import Future


async def executor_sleep(node: Node, seconds: float) -> None:
    """Yield to the executor for ``seconds`` (a one-shot timer resolves the future): a goal in progress must not
    hold up the robot's physics or sensors, which run on the same thread."""
    done = Future()

    def fire() -> None:
        timer.cancel()
        if not done.done():
            done.set_result(None)

    timer = node.create_timer(seconds, fire)
    try:
        await done
    finally:
        node.destroy_timer(timer)
