"""Hand work from MQTT threads to the ROS executor's thread, whichever executor spins the bridge.

rclpy objects (action clients and servers, parameter service clients) are used from the executor's thread
only, so what arrives on paho's threads is queued and drained there. A guard condition did the waking, but
rclpy 7.1's EventsExecutor supports none ("Guard conditions not supported"); both executors offer
``create_task`` (thread-safe) and ``wake``, which is all the bridge needs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class OnExecutor:
    """``run(fn)`` calls ``fn()`` soon on the executor's thread; :meth:`wake` re-checks its futures.

    Set :attr:`executor` before the bridge connects to MQTT: nothing can be queued before that, and after
    shutdown nothing is (work queued then has nobody left to answer).
    """

    __slots__ = ("executor",)

    def __init__(self) -> None:
        self.executor: Any = None

    def run(self, fn: Callable[[], Any]) -> None:
        executor = self.executor
        if executor is None:
            return
        try:
            executor.create_task(fn)
        except Exception:  # noqa: BLE001 - shutting down
            pass

    def wake(self) -> None:
        executor = self.executor
        if executor is None:
            return
        try:
            executor.wake()
        except Exception:  # noqa: BLE001 - shutting down
            pass
