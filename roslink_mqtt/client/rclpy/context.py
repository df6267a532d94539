"""rclpy's module-level functions: ``init``, ``create_node``, ``spin``, ``spin_once``, ``shutdown``.

There is no ROS graph to join, so ``init`` only marks the context live and
``shutdown`` destroys the nodes still alive (withdrawing their services and
clearing their presence). ``create_node`` works without ``init``: a program
without ROS should not fail for a missing ceremony.

As in rclpy, the context does not import ``Node`` at run time: ``node.py``
imports this module (a node registers with its context), so this module sees
``Node`` only for type checkers and ``create_node`` imports it when called
(rclpy's ``create_node`` does the same). Importing the context alone never
loads the node module.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .node import Node


class Context:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._nodes: list[Node] = []
        self._ok = False

    def init(self) -> None:
        self._ok = True

    def ok(self) -> bool:
        return self._ok

    def add(self, node: Node) -> None:
        with self._lock:
            self._ok = True
            self._nodes.append(node)

    def remove(self, node: Node) -> None:
        with self._lock:
            if node in self._nodes:
                self._nodes.remove(node)

    def shutdown(self) -> None:
        with self._lock:
            nodes, self._nodes = list(self._nodes), []
            self._ok = False
        for node in nodes:
            node.destroy_node()


_DEFAULT = Context()


def default_context() -> Context:
    return _DEFAULT


def init(args: Any = None, *, context: Context | None = None, **_rclpy_options: Any) -> None:
    """Mark the context live (``args`` accepted for rclpy compatibility and ignored)."""
    (context or _DEFAULT).init()


def ok(*, context: Context | None = None) -> bool:
    return (context or _DEFAULT).ok()


def shutdown(*, context: Context | None = None, **_rclpy_options: Any) -> None:
    """Destroy every node still alive."""
    (context or _DEFAULT).shutdown()


def try_shutdown(*, context: Context | None = None) -> None:
    shutdown(context=context)


def create_node(node_name: str, *, robot: str | None = None, url: str | None = None, username: str | None = None,
                password: str | None = None, **options: Any) -> Node:
    """Connect a :class:`Node` for ``robot`` (see Node for the options and their environment defaults)."""
    from .node import Node  # here, not at the top: node.py imports this module

    return Node(node_name, robot=robot, url=url, username=username, password=password, **options)


def _check_login(node: Node) -> None:
    """A node whose login the broker refused on a reconnect will never hear anything again: say so."""
    failure = node.robot_client.login_refused
    if failure is not None:
        raise failure


def spin_once(node: Node, *, executor: Any = None, timeout_sec: float | None = None) -> None:
    """Run at most one callback, waiting up to ``timeout_sec`` (None: until one comes); LoginRefused if refused."""
    _check_login(node)
    node.callback_queue.run_once(timeout_sec)


def spin(node: Node, executor: Any = None) -> None:
    """Run the node's callbacks until it is destroyed, ``shutdown()``, or Ctrl-C.

    Ctrl-C ends the spin quietly (rclpy raises KeyboardInterrupt or ExternalShutdownException
    there, and every ROS program wraps ``spin`` in a try for it; code that does keeps working
    here). Raises LoginRefused when the broker refused the node's login on a reconnect (a
    changed password): the connection is over, and spinning on would wait forever.
    """
    try:
        while not node.destroyed and ok():
            _check_login(node)
            node.callback_queue.run_once(0.5)
    except KeyboardInterrupt:
        node.get_logger().info("interrupted (Ctrl-C)")


def spin_until_future_complete(node: Node, future: Future[Any], executor: Any = None,
                               timeout_sec: float | None = None) -> None:
    """Spin until ``future`` is done or ``timeout_sec`` passes."""
    future.add_done_callback(lambda _f: node.callback_queue.wake())  # no polling delay when it completes
    deadline = None if timeout_sec is None else time.monotonic() + timeout_sec
    while not future.done() and not node.destroyed:
        _check_login(node)
        left = 0.5 if deadline is None else min(0.5, deadline - time.monotonic())
        if left <= 0:
            return
        node.callback_queue.run_once(left)
