"""Where user callbacks run: never on paho's network thread.

A callback that calls a service synchronously waits for a reply that only the
network thread can deliver; run there, it would deadlock. So the network
thread only *queues* user callbacks. A :class:`RobotClient` drains its queue in
a worker thread of its own; a ROS-like ``Node`` drains it in ``spin()``, as
rclpy runs callbacks in the executor that spins.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import queue
import threading
import time
from collections.abc import Callable

log = logging.getLogger("roslink_mqtt.client")

Callback = Callable[[], None]


class CallbackQueue:
    """A FIFO of zero-argument callables; exceptions are logged, never propagated to the network thread."""

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue[Callback | None] = queue.SimpleQueue()

    def put(self, callback: Callback) -> None:
        self._queue.put(callback)

    def wake(self) -> None:
        """Make a blocked :meth:`run_once` return (used on shutdown)."""
        self._queue.put(None)

    def run_once(self, timeout: float | None = None) -> bool:
        """Run one queued callback, waiting up to ``timeout`` s for one; True if one ran."""
        try:
            callback = self._queue.get(timeout=timeout) if timeout is None or timeout > 0 \
                else self._queue.get_nowait()
        except queue.Empty:
            return False
        if callback is None:
            return False
        try:
            callback()
        except Exception:  # a user's bug must not stop the dispatcher
            log.exception("callback failed")
        return True


class DispatchThread:
    """Drains a :class:`CallbackQueue` in a daemon thread (the RobotClient's callbacks)."""

    def __init__(self, callbacks: CallbackQueue, name: str) -> None:
        self.callbacks = callbacks
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.callbacks.run_once(0.5)

    def stop(self) -> None:
        self._stop.set()
        self.callbacks.wake()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=2)


class Scheduler:
    """One daemon thread that runs short callables at given times (timeouts, timers).

    One thread for every deadline instead of a ``threading.Timer`` per service
    call: a benchmark making thousands of calls would otherwise start
    thousands of threads. Callables must be quick; anything slow is handed to
    a :class:`CallbackQueue`.
    """

    def __init__(self, name: str = "roslink-scheduler") -> None:
        self._heap: list[tuple[float, int]] = []
        self._callbacks: dict[int, Callback] = {}  # pending only: cancel() removes, firing removes
        self._ids = itertools.count()
        self._cond = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def call_at(self, when: float, callback: Callback) -> int:
        """Run ``callback`` at ``time.monotonic() >= when``; returns a handle for :meth:`cancel`."""
        handle = next(self._ids)
        with self._cond:
            self._callbacks[handle] = callback
            heapq.heappush(self._heap, (when, handle))
            self._cond.notify()
        return handle

    def call_later(self, delay: float, callback: Callback) -> int:
        return self.call_at(time.monotonic() + delay, callback)

    def cancel(self, handle: int) -> None:
        with self._cond:
            self._callbacks.pop(handle, None)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._callbacks.clear()
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed:
                    now = time.monotonic()
                    if self._heap and self._heap[0][0] <= now:
                        _, handle = heapq.heappop(self._heap)
                        callback = self._callbacks.pop(handle, None)
                        if callback is None:  # cancelled
                            continue
                        break
                    self._cond.wait(self._heap[0][0] - now if self._heap else None)
                else:
                    return
            try:
                callback()
            except Exception:
                log.exception("scheduled callback failed")
