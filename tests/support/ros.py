"""An rclpy node inside the test process, spinning in a background thread.

Lets a test watch what really reaches ROS topics (e.g. ``cmd_vel``) while the
robot, bridge and broker run as separate processes. The loopback-only DDS
environment is set by tests/conftest.py before rclpy is imported.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any


class Watch:
    """Every message seen on one topic, with its arrival time (monotonic)."""

    def __init__(self) -> None:
        self.subscription: Any = None
        self.items: list[tuple[float, Any]] = []
        self.cond = threading.Condition()

    def add(self, msg: Any) -> None:
        with self.cond:
            self.items.append((time.monotonic(), msg))
            self.cond.notify_all()

    def wait_for(self, predicate: Callable[[Any], bool], timeout: float = 10.0,
                 after: float = 0.0) -> tuple[float, Any]:
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                for at, msg in self.items:
                    if at >= after and predicate(msg):
                        return at, msg
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no matching message in {timeout} s ({len(self.items)} seen)")
                self.cond.wait(left)

    def wait_matched(self, timeout: float = 10.0) -> None:
        """Block until a publisher is matched, so a one-shot message cannot be missed."""
        deadline = time.monotonic() + timeout
        while self.subscription.get_publisher_count() == 0:
            if time.monotonic() > deadline:
                raise TimeoutError("no publisher matched")
            time.sleep(0.05)

    def since(self, t: float) -> list[tuple[float, Any]]:
        with self.cond:
            return [(at, m) for at, m in self.items if at >= t]


class RosProbe:
    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(f"test_probe_{time.monotonic_ns()}", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # shutdown races end the thread quietly
            pass

    def watch(self, msg_type: type, topic: str, qos: Any = 10) -> Watch:
        w = Watch()
        w.subscription = self.node.create_subscription(msg_type, topic, w.add, qos)
        return w

    def publisher(self, msg_type: type, topic: str, qos: Any = 10) -> Any:
        return self.node.create_publisher(msg_type, topic, qos)

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1)
        self.node.destroy_node()
        self.context.try_shutdown()
