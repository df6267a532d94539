"""Watching a robot's video stream from a program (``RobotClient.video``): frames in order, the watch kept alive.

The robot encodes a camera only while someone watches (docs/video.md), so a subscription here does two things: it
reads ``state/<stream>``, and it renews its watch every :data:`~roslink_mqtt.protocol.video.WATCH_RENEW` seconds
on ``from/<user>/watch/<stream>`` until it is closed, when it says it leaves. Frames arrive as
:class:`~roslink_mqtt.protocol.video.VideoFrame` (header and bitstream); :class:`~roslink_mqtt.video.decoder.
VideoDecoder` turns them into pictures where PyAV is installed (``pip install roslink-mqtt[video]``), and
``roslink-mqtt video`` saves them to a file without decoding.

Frames wait in a bounded queue that drops the oldest when full (a slow reader sees the newest video, not a
growing backlog); a dropped frame leaves a gap in ``seq``, after which a decoder waits for a keyframe, which
:meth:`VideoSubscription.ask_keyframe` asks for.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable, Iterator

from ..protocol import ProtocolError
from ..protocol.video import WATCH_RENEW, VideoFrame, WatchRequest
from ..topics import TopicTree, Verb
from .connection import Connection
from .dispatch import CallbackQueue, Scheduler
from .errors import WaitTimeout

log = logging.getLogger("roslink_mqtt.client")


class VideoSubscription:
    """One robot's video stream, watched until :meth:`close`."""

    def __init__(self, connection: Connection, scheduler: Scheduler, callbacks: CallbackQueue, topics: TopicTree,
                 user: str, client_id: str, robot: str, stream: str,
                 callback: Callable[[VideoFrame], None] | None = None, maxsize: int = 60) -> None:
        self.connection, self.scheduler, self.callbacks = connection, scheduler, callbacks
        self.robot, self.stream, self.callback, self.client_id = robot, stream, callback, client_id
        self.topic = topics.state(robot, stream)
        self.watch_topic = topics.user_topic(robot, user, Verb.WATCH, stream)
        self.received = 0
        self.dropped = 0  # frames the queue let go (the reader was slower than the stream)
        self.closed = False
        self._queue: queue.Queue[VideoFrame] = queue.Queue(maxsize)
        self._lock = threading.Lock()
        self._renewal: int | None = None

    def start(self) -> VideoSubscription:
        self.connection.subscribe(self.topic, self._deliver)
        self._renew(key=True)
        return self

    def _renew(self, key: bool = False) -> None:
        with self._lock:
            if self.closed:
                return
            self.connection.publish(self.watch_topic, WatchRequest(self.client_id, key=key).to_json(),
                                    qos=WatchRequest.QOS)
            self._renewal = self.scheduler.call_later(WATCH_RENEW, self._renew)

    def ask_keyframe(self) -> None:
        """Ask the robot for a keyframe now (after a gap; the robot sends at most one a second whoever asks)."""
        if not self.closed:
            self.connection.publish(self.watch_topic, WatchRequest(self.client_id, key=True).to_json(),
                                    qos=WatchRequest.QOS)

    # network thread
    def _deliver(self, _topic: str, payload: bytes, _retained: bool) -> None:
        if self.closed:
            return
        try:
            frame = VideoFrame.from_bytes(payload)
        except ProtocolError as err:
            log.debug("ignoring a malformed video frame on %s: %s", self.topic, err)
            return
        self.received += 1
        if self.callback is not None:
            callback = self.callback
            self.callbacks.put(lambda: callback(frame))
            return
        while True:
            try:
                self._queue.put_nowait(frame)
                return
            except queue.Full:
                try:
                    self._queue.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def get(self, timeout: float | None = None) -> VideoFrame:
        """The next frame; WaitTimeout when none arrives within ``timeout`` s."""
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            raise WaitTimeout(f"no video from {self.robot}/{self.stream} within {timeout} s") from None

    def __iter__(self) -> Iterator[VideoFrame]:
        while not self.closed:
            try:
                yield self._queue.get(timeout=0.5)
            except queue.Empty:
                continue

    def close(self) -> None:
        """Stop watching: the robot stops encoding once nobody else watches."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            if self._renewal is not None:
                self.scheduler.cancel(self._renewal)
        self.connection.unsubscribe(self.topic, self._deliver)
        if self.connection.connected.is_set():
            self.connection.publish(self.watch_topic, WatchRequest(self.client_id, leave=True).to_json(),
                                    qos=WatchRequest.QOS)

    def __enter__(self) -> VideoSubscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
