"""Robots' MQTT topics as JSON channels with schemas: what ``record`` writes to MCAP and the Foxglove gateway serves.

Both keep one channel per MQTT topic, named by the topic itself, so a Foxglove layout made on a live robot opens its
recordings too. Each channel has a ``jsonschema`` schema (protocol/schemas.py) so Foxglove shows fields, not text:

* JSON payloads are passed on as they came (``json`` message encoding);
* ``encoding: cbor`` state is converted to JSON (byte strings as base64): every MCAP reader and Foxglove decode
  JSON, while a CBOR channel would need a decoder Foxglove does not have;
* ``encoding: raw`` state (compressed images) becomes ``foxglove.CompressedImage`` in JSON (``data`` base64), the
  schema Foxglove's Image panel reads;
* video streams (the description's ``video`` entries) become ``foxglove.CompressedVideo`` in JSON (one frame each,
  ``data`` base64, stamped with the capture time), which the Image panel decodes too. Their frames flow only while
  someone watches: the gateway and ``record`` renew a watch while they carry one.

How a topic is carried is worked out once per topic, from its robot's description (:class:`JsonChannels`), so the
per-message path parses nothing and searches no description.
"""

from __future__ import annotations

import base64
import logging
from collections.abc import Collection
from dataclasses import dataclass
from typing import Any

import orjson

from ..protocol.description import RobotDescription
from ..protocol.errors import ProtocolError
from ..protocol.schemas import schema_for
from ..protocol.video import VideoFrame
from ..topics import Kind, TopicTree

log = logging.getLogger("roslink_mqtt.channels")

NS = 1_000_000_000
VIDEO = "video"  # a route's encoding for a video stream (the description's `video` entries)


@dataclass(frozen=True, slots=True)
class Route:
    """How one topic becomes a channel: its robot and state name, its schema, its payload encoding."""

    robot: str
    name: str
    schema: dict[str, Any]
    encoding: str | None  # "cbor", "raw", VIDEO or None (JSON)
    description: bool  # the robot's description: read (it shapes the other routes), then carried like any state

    @property
    def schema_name(self) -> str:
        return str(self.schema.get("title") or self.name)


class JsonChannels:
    """The routes of ``robots``' topics (``wanted``: only these state names, heartbeats and replies still come)."""

    def __init__(self, tree: TopicTree, robots: Collection[str], wanted: Collection[str] = ()) -> None:
        self.tree, self.robots, self.wanted = tree, robots, set(wanted)
        self.descriptions: dict[str, RobotDescription] = {}
        self._routes: dict[str, Route | None] = {}

    def route(self, topic: str) -> Route | None:
        """How ``topic`` is carried (None: not a topic of the tree, another robot's, or one ``wanted`` leaves out)."""
        if topic in self._routes:
            return self._routes[topic]
        parsed = self.tree.parse(topic)
        route = None
        if parsed is not None and parsed.robot in self.robots and not (
                self.wanted and parsed.kind is Kind.STATE and parsed.name not in self.wanted):
            description = self.descriptions.get(parsed.robot or "")
            entry = next((e for e in description.state if e.name == parsed.name), None) \
                if description is not None and parsed.kind is Kind.STATE else None
            video = description is not None and parsed.kind is Kind.STATE and any(
                v.name == parsed.name for v in description.video)
            route = Route(parsed.robot or "", parsed.name or "", schema_for(parsed, topic, description),
                          VIDEO if video else entry.encoding if entry is not None else None,
                          parsed.kind is Kind.STATE and parsed.name == "description")
        self._routes[topic] = route
        return route

    def learn(self, route: Route, payload: bytes) -> RobotDescription | None:
        """Read a robot's description (``route.description``): the robot's routes not yet used follow it (a channel
        keeps the schema it started with). None, logged, when it does not parse."""
        try:
            description = RobotDescription.from_json(payload)
        except ProtocolError as err:
            log.warning("%s: %s (its topics get plain object schemas)", self.tree.state(route.robot, route.name), err)
            return None
        self.use(route.robot, description)
        return description

    def learn_unrouted(self, topic: str, payload: bytes) -> None:
        """A robot's description that ``wanted`` leaves out of the recording is still read: it says which state
        names are video streams (and how the wanted topics are carried)."""
        parsed = self.tree.parse(topic)
        if parsed is not None and parsed.kind is Kind.STATE and parsed.name == "description" and \
                parsed.robot in self.robots and payload:
            self.learn(Route(parsed.robot or "", parsed.name, {}, None, True), payload)

    def use(self, robot: str, description: RobotDescription) -> None:
        """Route ``robot``'s topics by ``description`` from now on (routes already used keep their schemas)."""
        self.descriptions[robot] = description
        self._routes = {t: r for t, r in self._routes.items() if r is None or r.robot != robot or r.description}

    @staticmethod
    def encode(route: Route, payload: bytes, arrived: int) -> tuple[bytes, int]:
        """(JSON for the channel, publish time in ns) of one payload that arrived at ``arrived`` (ns). A malformed
        CBOR payload raises (the caller counts it); text that is not JSON is carried as ``{"text": …}``."""
        if route.encoding == VIDEO:
            return video_message(route.name, VideoFrame.from_bytes(payload))
        if route.encoding == "raw":
            image = {"timestamp": {"sec": arrived // NS, "nsec": arrived % NS}, "frame_id": route.name,
                     "data": base64.b64encode(payload).decode(), "format": image_format(payload)}
            return orjson.dumps(image), arrived
        if route.encoding == "cbor":
            import cbor2

            value = jsonable(cbor2.loads(payload))
            return orjson.dumps(value), stamp_of(value, arrived)
        try:
            value = orjson.loads(payload)
        except orjson.JSONDecodeError:
            return orjson.dumps({"text": payload.decode("utf-8", "replace")}), arrived
        return payload, stamp_of(value, arrived)


def video_message(name: str, frame: VideoFrame) -> tuple[bytes, int]:
    """(``foxglove.CompressedVideo`` JSON, the capture time in ns) of one video frame of stream ``name``."""
    stamp = int(frame.stamp * NS)
    video = {"timestamp": {"sec": stamp // NS, "nsec": stamp % NS}, "frame_id": name,
             "data": base64.b64encode(frame.data).decode(), "format": frame.codec}
    return orjson.dumps(video), stamp


def jsonable(value: Any) -> Any:
    """A decoded CBOR value as JSON can carry it: byte strings as base64 text, tags as their values."""
    from cbor2 import CBORTag

    if isinstance(value, CBORTag):
        return jsonable(value.value)
    if isinstance(value, (bytes, bytearray)):
        return base64.b64encode(value).decode()
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    return value


def image_format(data: bytes) -> str:
    """``foxglove.CompressedImage.format`` of a compressed image, from its magic bytes (JPEG when unknown)."""
    if data.startswith(b"\x89PNG"):
        return "png"
    if data[8:12] == b"WEBP":
        return "webp"
    return "jpeg"


def stamp_of(value: Any, arrived: int) -> int:
    """A ROS ``header.stamp`` in the message (generic rules carry it), in ns; else the arrival."""
    header = value.get("header") if isinstance(value, dict) else None
    stamp = header.get("stamp") if isinstance(header, dict) else None
    if isinstance(stamp, dict) and isinstance(stamp.get("sec"), int):
        nanos = stamp.get("nanosec", stamp.get("nsec", 0))
        sec: int = stamp["sec"]  # an int: checked above
        return sec * NS + (nanos if isinstance(nanos, int) else 0)
    return arrived
