"""An rclpy node inside the test process, spinning in a background thread.

Lets a test watch what really reaches ROS topics (e.g. ``cmd_vel``) while the
robot, bridge and broker run as separate processes. The loopback-only DDS
environment is set by tests/conftest.py before rclpy is imported.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from tests.support.waits import wait_until


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
        try:
            wait_until("a publisher matched", lambda: self.subscription.get_publisher_count() > 0, timeout=timeout)
        except AssertionError:
            raise TimeoutError("no publisher matched") from None

    def since(self, t: float) -> list[tuple[float, Any]]:
        with self.cond:
            return [(at, m) for at, m in self.items if at >= t]


class RosProbe:
    """One rclpy context, node and executor of the test's own.

    The spin thread is stopped and joined before anything is destroyed: rclpy
    does not support destroying a node (or shutting down its context) while
    another thread waits on it, and in rclpy 7.1 ``Executor.shutdown`` returns
    without waiting for the spinning thread. The old order (destroy while the
    thread might still wait) is the likely cause of a CI run that sat stuck in
    C code between two test modules, where no Python timeout reaches.

    Known residual risk, measured here: deleting a Fast DDS 2.14 participant
    after peers were SIGKILLed mid-stream sometimes segfaults inside its
    shared-memory transport (about once per 90 killed peers flooding 2 kB
    messages). The suite kills a publishing ROS process only twice, at a low
    rate; ``faulthandler_timeout`` in pyproject.toml ends a run stuck in C.
    """

    SPIN_PERIOD = 0.05  # how soon the spin thread notices close()

    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(f"test_probe_{time.monotonic_ns()}", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stopping = threading.Event()
        self._calls: queue.SimpleQueue[tuple[Callable[[], Any], list[Any], threading.Event]] = queue.SimpleQueue()
        self.spin_error: BaseException | None = None
        self.thread = threading.Thread(target=self._spin, name="ros-probe-spin", daemon=True)
        self.thread.start()

    def on_spin(self, call: Callable[[], Any], timeout: float = 10.0) -> Any:
        """``call()`` run on the spin thread, between two turns of the executor; its return value.

        rclpy 7.1's ActionClient sends a goal, cancel or result request and only then files the request's future:
        a response handled by the spin thread in between is dropped ("Ignoring unexpected cancel response") and
        the future never completes. Sent from the spin thread itself, no response can be handled in between."""
        box: list[Any] = []
        done = threading.Event()
        self._calls.put((call, box, done))
        self.executor.wake()
        if not done.wait(timeout):
            raise TimeoutError(f"the probe's spin thread did not run the call within {timeout} s")
        if isinstance(box[0], BaseException):
            raise box[0]
        return box[0]

    def _spin(self) -> None:
        while not self._stopping.is_set():
            while not self._calls.empty():
                call, box, done = self._calls.get()
                try:
                    box.append(call())
                except BaseException as err:  # handed to the caller
                    box.append(err)
                done.set()
            try:
                self.executor.spin_once(timeout_sec=self.SPIN_PERIOD)
            except Exception as err:  # kept for close() to report; a test must not lose it silently
                self.spin_error = err
                return

    def watch(self, msg_type: type, topic: str, qos: Any = 10) -> Watch:
        w = Watch()
        w.subscription = self.node.create_subscription(msg_type, topic, w.add, qos)
        return w

    def publisher(self, msg_type: type, topic: str, qos: Any = 10) -> Any:
        return self.node.create_publisher(msg_type, topic, qos)

    def close(self, timeout: float = 10.0) -> None:
        self._stopping.set()
        self.executor.wake()
        self.thread.join(timeout)
        if self.thread.is_alive():
            # Destroying what the thread still waits on could hang this process for good; leak it instead.
            raise RuntimeError(f"ROS probe spin thread still running {timeout} s after close()")
        self.node.destroy_node()
        self.executor.shutdown(timeout_sec=0)
        self.context.try_shutdown()
        self.context.destroy()  # the DDS participant goes now, not whenever the garbage collector runs
        if self.spin_error is not None:
            raise RuntimeError("ROS probe spin thread failed") from self.spin_error
