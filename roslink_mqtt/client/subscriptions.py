"""A subscription to one robot state stream, consumed by callback, blocking iteration or ``async for``.

ROSLink state (``state/global_motion`` …) arrives as typed message objects;
generic rules (``state/<anything>`` carrying a plain ROS message as JSON, CBOR
or, for a compressed image, its raw bytes: :mod:`.encodings`) arrive as dicts.
Without a callback, messages wait in a bounded queue that drops the *oldest*
when full: for robot state the newest value matters, and a slow consumer must not grow memory without bound.

When the connection fails for good (the broker refused our login on a
reconnect), :meth:`StateSubscription.fail` makes a waiting ``get`` or loop
raise that error instead of waiting forever for messages that cannot come.
"""

from __future__ import annotations

import asyncio
import logging
import queue
import threading
from collections.abc import AsyncIterator, Callable, Iterator
from typing import Any

from ..protocol import ProtocolError, loads
from ..protocol.json_value import JsonObject
from ..protocol.lease import CONTROL, ControlState
from ..protocol.link import LINK, LinkReport
from .dispatch import CallbackQueue
from .encodings import JSON, decode_state, sniff
from .errors import SubscriptionFailed, WaitTimeout
from .messages import RoslinkMessage, state_message

log = logging.getLogger("roslink_mqtt.client")

StateItem = RoslinkMessage | LinkReport | ControlState | JsonObject  # a generic rule's payload: its ROS type's fields
_FAILED: Any = object()  # queued by fail(): wakes a blocked get() or loop
_CLOSED: Any = object()  # queued by close(): ends an ``async for`` blocked on an empty queue


def parse_state_item(payload: bytes, robot: str, name: str, encoding: str | None = None) -> StateItem | None:
    """Typed message for ROSLink payloads, a dict for generic state, None for anything else.

    ``encoding`` (``json``, ``cbor``, ``raw``) is the rule's, from the robot description; None tells it from
    the payload (:func:`.encodings.sniff`: the three cannot be confused).
    """
    if name in (LINK, CONTROL):  # the bridge's uplink report and control state: typed, like ROSLink state
        try:
            return LinkReport.from_json(payload) if name == LINK else ControlState.from_json(payload)
        except ProtocolError as err:
            log.debug("ignoring malformed %s report of %s: %s", name, robot, err)
            return None
    encoding = encoding or sniff(payload)
    if encoding != JSON:  # ROSLink messages are always JSON
        try:
            body = decode_state(payload, encoding)
        except ProtocolError as err:
            log.debug("ignoring malformed %s state message on %s/%s: %s", encoding, robot, name, err)
            return None
        return body if isinstance(body, dict) else None
    try:
        body = loads(payload)  # once: a ROSLink message, or else a generic rule's ROS message
    except ProtocolError as err:
        log.debug("ignoring malformed state message on %s/%s: %s", robot, name, err)
        return None
    try:
        return state_message(body, robot=robot, state_name=name)
    except ProtocolError as err:
        if isinstance(body, dict) and "message_id" not in body:
            return body  # a generic rule's ROS message
        log.debug("ignoring malformed state message on %s/%s: %s", robot, name, err)
        return None


class StateSubscription:
    """Messages from ``<prefix>/<robot>/state/<name>``; close() to stop."""

    def __init__(self, robot: str, name: str, topic: str, callback: Callable[[StateItem], None] | None,
                 callbacks: CallbackQueue, maxsize: int = 100,
                 on_close: Callable[[StateSubscription], None] | None = None, encoding: str | None = None) -> None:
        self.robot, self.name, self.topic, self.encoding = robot, name, topic, encoding
        self.callback, self._callbacks, self._on_close = callback, callbacks, on_close
        self.latest: StateItem | None = None
        self.received = 0
        self.closed = False
        self._queue: queue.Queue[StateItem] = queue.Queue(maxsize)
        self._async: tuple[asyncio.AbstractEventLoop, asyncio.Queue[StateItem]] | None = None
        self._lock = threading.Lock()
        self.failure: BaseException | None = None  # set by fail(): nothing more will arrive

    # network thread
    def deliver(self, topic: str, payload: bytes, _retained: bool) -> None:
        item = parse_state_item(payload, self.robot, self.name, self.encoding)
        if item is None or self.closed:
            return
        self.latest = item
        self.received += 1
        if self.callback is not None:
            callback = self.callback
            self._callbacks.put(lambda: callback(item))
        elif self._async is not None:
            loop, aqueue = self._async
            loop.call_soon_threadsafe(_put_latest, aqueue, item)
        else:
            _put_latest(self._queue, item)

    def get(self, timeout: float | None = None) -> StateItem:
        """The next message; raises TimeoutError when none arrives within ``timeout`` s (or the failure)."""
        if self.failure is not None and self._queue.empty():
            raise self.failure
        try:
            item = self._queue.get(timeout=timeout)
        except queue.Empty:
            raise WaitTimeout(f"no {self.name} from {self.robot} within {timeout} s") from None
        if item is _FAILED:
            raise self.failure or SubscriptionFailed("subscription failed")
        return item

    def __iter__(self) -> Iterator[StateItem]:
        while not self.closed:
            try:
                item = self._queue.get(timeout=0.5)
            except queue.Empty:
                if self.failure is not None:
                    raise self.failure from None
                continue
            if item is _FAILED:
                raise self.failure or SubscriptionFailed("subscription failed")
            yield item

    async def __aiter__(self) -> AsyncIterator[StateItem]:
        aqueue: asyncio.Queue[StateItem] = asyncio.Queue(self._queue.maxsize)
        with self._lock:
            self._async = (asyncio.get_running_loop(), aqueue)
        while not self.closed:
            if self.failure is not None and aqueue.empty():
                raise self.failure
            item = await aqueue.get()
            if item is _CLOSED:
                return
            if item is _FAILED:
                raise self.failure or SubscriptionFailed("subscription failed")
            yield item

    def fail(self, error: BaseException) -> None:
        """Nothing more will arrive (any thread): waiting readers raise ``error`` instead of waiting on."""
        self.failure = error
        _put_latest(self._queue, _FAILED)
        with self._lock:
            target = self._async
        if target is not None:
            loop, aqueue = target
            loop.call_soon_threadsafe(_put_latest, aqueue, _FAILED)

    def close(self) -> None:
        """Stop delivery (any thread); an ``async for`` waiting on this subscription ends.

        The async loop awaits its queue, so setting ``closed`` alone is never seen
        while no message arrives: a sentinel wakes it. (Blocking iteration polls
        ``closed`` on its own.)
        """
        if not self.closed:
            self.closed = True
            with self._lock:
                target = self._async
            if target is not None:
                loop, aqueue = target
                try:
                    loop.call_soon_threadsafe(_put_latest, aqueue, _CLOSED)
                except RuntimeError:  # that loop is closed already: nobody is waiting on it
                    pass
            if self._on_close is not None:
                self._on_close(self)

    def __enter__(self) -> StateSubscription:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def _put_latest(q: queue.Queue[StateItem] | asyncio.Queue[StateItem], item: StateItem) -> None:
    """Put, dropping the oldest item when the queue is full."""
    while True:
        try:
            q.put_nowait(item)
            return
        except (queue.Full, asyncio.QueueFull):
            try:
                q.get_nowait()
            except (queue.Empty, asyncio.QueueEmpty):
                pass
