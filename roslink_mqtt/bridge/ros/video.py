"""The robot file's video streams with rclpy: the camera's subscription exists only while someone watches.

:class:`RosVideo` is the port of the ``watch`` capability (:mod:`.capabilities.watch`): each stream has its
watchers and a :class:`~roslink_mqtt.video.streamer.VideoStreamer` (its own thread: the encoder never runs on the
executor or on paho's thread), whose frames leave on a bulk lane of their own (:class:`UplinkVideo`). The ROS
callback keeps the newest message; the streamer converts it (``sensor_msgs/Image`` pixels, or a
``CompressedImage``'s JPEG or PNG decoded with PyAV) only when it will encode it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from functools import partial
from typing import Any, cast

import av
import numpy as np
from av.video.codeccontext import VideoCodecContext
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from ...config import Priority, Robot, VideoStream
from ...config.model import VIDEO_TYPES
from ...topics import TopicTree
from ...video.encoder import frame_from_pixels
from ...video.streamer import Picture, VideoStreamer
from ...video.watchers import NEEDS_SCHEDULED_UPLINK, Watchers
from ..core.camera_qos import reads_reliably
from ..core.on_executor import OnExecutor
from ..core.ros_types import load_interface
from ..core.uplink_sender import Uplink

log = logging.getLogger("roslink_mqtt.bridge.video")


class UplinkVideo:
    """A stream's :class:`~roslink_mqtt.video.streamer.VideoLane` on the uplink: a stream of its class (state by
    default, or bulk) on a lane of its own."""

    def __init__(self, uplink: Uplink, topic: str, label: str, priority: Priority) -> None:
        self.uplink, self.topic = uplink, topic
        self.stream = uplink.stream(topic, priority, latest_only=True, label=label)
        self.lane = uplink.lane_of(self.stream)

    def room(self) -> bool:
        return self.uplink.has_room(self.lane, self.stream)

    def share(self, wants: float) -> tuple[float, bool]:
        return self.uplink.share_of(self.lane, wants)

    def send(self, payload: bytes) -> bool:
        if not self.lane.link.connected.is_set():
            return False
        self.uplink.offer(self.stream, self.topic, payload, 0, False)
        return True


def camera_qos(offered: list[ReliabilityPolicy]) -> QoSProfile:
    """The camera's subscription: the newest picture only, reliable when its publishers allow it
    (:mod:`..core.camera_qos` says why)."""
    reliable = reads_reliably(policy == ReliabilityPolicy.RELIABLE for policy in offered)
    return QoSProfile(depth=1,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT)


def stamp_of(msg: Any) -> float:
    """The message's header stamp as seconds since the epoch (now, when the camera left it unset)."""
    stamp = msg.header.stamp
    return stamp.sec + stamp.nanosec * 1e-9 if stamp.sec or stamp.nanosec else time.time()


def image_converter(msg: Any) -> Callable[[], av.VideoFrame]:
    """How to turn a ``sensor_msgs/Image`` into a PyAV frame (called on the streamer's thread, if it encodes it)."""
    def convert() -> av.VideoFrame:
        channels = {"mono8": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}.get(msg.encoding)
        if channels is None:
            return frame_from_pixels(np.zeros((2, 2), np.uint8), msg.encoding)  # refused, naming the encoding
        rows = np.asarray(memoryview(msg.data) if isinstance(msg.data, (bytes, bytearray)) else msg.data,
                          np.uint8).reshape(msg.height, msg.step)
        pixels = rows[:, :msg.width * channels].reshape(msg.height, msg.width, channels)
        return frame_from_pixels(pixels[..., 0] if channels == 1 else pixels, msg.encoding)
    return convert


class _Compressed:
    """``CompressedImage`` → PyAV frames: JPEG or PNG, told by the data's own signature."""

    def __init__(self) -> None:
        self._decoders: dict[str, VideoCodecContext] = {}

    def converter(self, msg: Any) -> Callable[[], av.VideoFrame]:
        def convert() -> av.VideoFrame:
            data = bytes(msg.data)
            codec = "png" if data[:4] == b"\x89PNG" else "mjpeg"
            decoder = self._decoders.get(codec)
            if decoder is None:
                decoder = self._decoders[codec] = cast(VideoCodecContext, av.CodecContext.create(codec, "r"))
            frames = decoder.decode(av.Packet(data))
            if not frames:
                raise ValueError(f"a {msg.format or 'compressed'} image PyAV could not decode")
            frame: av.VideoFrame = frames[-1]
            return frame
        return convert


class RosVideo:
    """Every video stream of the robot: watchers, streamers, and the camera subscriptions they need."""

    def __init__(self, node: Node, robot: Robot, topics: TopicTree, uplink: Uplink,
                 is_live: Callable[[str, str], bool], on_executor: OnExecutor) -> None:
        self.node, self.on_executor = node, on_executor
        # fifo: every message in order on the command connection; frames there would hold stops back: not served
        self.refusal = NEEDS_SCHEDULED_UPLINK if uplink.fifo else None
        if self.refusal and robot.video:
            log.warning("%s: %s; watches of %s are refused", robot.name, self.refusal,
                        ", ".join(v.name for v in robot.video))
        self._settings = {v.name: v for v in robot.video}
        self.watchers = {v.name: Watchers(is_live) for v in robot.video}
        self.streamers = {
            v.name: VideoStreamer(v, UplinkVideo(uplink, topics.state(robot.name, v.name), v.name, v.priority),
                                  self.watchers[v.name], on_watched=partial(self._watched, v.name))
            for v in robot.video}
        self._subscriptions: dict[str, Any] = {}
        self._lock = threading.Lock()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._settings)

    def start(self) -> None:
        for streamer in self.streamers.values():
            streamer.start()

    def stop(self) -> None:
        for streamer in self.streamers.values():
            streamer.stop()

    # -- WatchPort (MQTT threads) ------------------------------------------------------------------------------
    def watch(self, stream: str, user: str, client_id: str, key: bool) -> str | None:
        if self.refusal is not None:
            return self.refusal
        why = self.watchers[stream].watch(user, client_id, time.monotonic(), key=key)
        self.streamers[stream].wake()
        return why

    def leave(self, stream: str, user: str, client_id: str) -> None:
        self.watchers[stream].leave(user, client_id)
        self.streamers[stream].wake()

    def withdraw_user(self, user: str, reason: str = "") -> None:
        """``user`` lost the robot (a reload, new grants): their watches end (the frames simply stop coming)."""
        for name, watchers in self.watchers.items():
            watchers.forget_user(user)
            self.streamers[name].wake()

    # -- the camera's subscription, only while watched -----------------------------------------------------------
    def _watched(self, name: str, watched: bool) -> None:
        """From a streamer's thread: subscribe or unsubscribe on the executor's thread (rclpy's entities are made
        and destroyed there)."""
        self.on_executor.run(partial(self._subscribe if watched else self._unsubscribe, name))

    def _subscribe(self, name: str) -> None:
        with self._lock:
            if name in self._subscriptions:
                return
            settings = self._settings[name]
            offer = self.streamers[name].offer
            callback = self._callback(settings, offer)
            qos = camera_qos([info.qos_profile.reliability
                              for info in self.node.get_publishers_info_by_topic(settings.ros_topic)])
            self._subscriptions[name] = self.node.create_subscription(
                load_interface(settings.ros_type), settings.ros_topic, callback, qos)
            log.info("video %s: subscribed to %s (%s)", name, settings.ros_topic, qos.reliability.name.lower())

    @staticmethod
    def _callback(settings: VideoStream, offer: Callable[[Picture], None]) -> Callable[[Any], None]:
        if settings.ros_type == VIDEO_TYPES[1]:  # sensor_msgs/msg/CompressedImage
            compressed = _Compressed()
            return lambda msg: offer(Picture(stamp_of(msg), compressed.converter(msg)))
        return lambda msg: offer(Picture(stamp_of(msg), image_converter(msg)))

    def _unsubscribe(self, name: str) -> None:
        with self._lock:
            subscription = self._subscriptions.pop(name, None)
            if subscription is not None:
                self.node.destroy_subscription(subscription)
                log.info("video %s: unsubscribed from %s", name, self._settings[name].ros_topic)
