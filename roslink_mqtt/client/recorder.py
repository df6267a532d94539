"""``roslink-mqtt record``: what a user may read of some robots, kept as MCAP (Foxglove, Lichtblick, ``mcap``).

It logs in as the user, so the broker's ACL decides what is recorded: each robot's heartbeat, every state topic the
user may read (acknowledgements, the description, the link report, who drives …) and what the robot sends this
user (replies, errors, the access report). One MCAP channel per MQTT topic, named by the topic, each with a
``jsonschema`` schema; payloads as JSON (CBOR converted, raw images as ``foxglove.CompressedImage``, video frames as
``foxglove.CompressedVideo``): :mod:`.json_channels`, which the Foxglove gateway shares. The recorder watches a video
stream (the robot encodes it only while someone does) only when ``--topic`` names it.

Log time is the arrival on this machine; publish time is the message's own stamp where it has one (a ROS
``header.stamp``), else the arrival. The file is valid after Ctrl-C (the summary is written on the way out), and
``split_size`` starts a new file (``name-001.mcap`` …) once one grows past it. Messages wait in a bounded queue
between paho's thread and the writer: if the disk cannot keep up, the newest are dropped and counted.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import orjson
import paho.mqtt.client as mqtt

from ..protocol.video import WATCH_RENEW, WatchRequest
from ..topics import TopicTree, Verb
from .json_channels import JsonChannels
from .plain_login import PlainLogin

log = logging.getLogger("roslink_mqtt.record")

QUEUE_LIMIT = 10_000  # messages between paho's thread and the writer
NS = 1_000_000_000


@dataclass
class Progress:
    """What has been written: messages and bytes in all, messages per topic, and what was dropped."""

    messages: int = 0
    bytes: int = 0
    dropped: int = 0
    files: list[Path] = field(default_factory=list)
    per_topic: Counter[str] = field(default_factory=Counter)


class _McapFile:
    """One MCAP file being written: schemas and channels registered once per topic."""

    def __init__(self, path: Path) -> None:
        from mcap.writer import Writer

        self.path = path
        self._stream: IO[bytes] = path.open("wb")
        self.writer = Writer(self._stream)
        self.writer.start(profile="", library="roslink-mqtt")
        self.channels: dict[str, int] = {}
        self.sequence: Counter[int] = Counter()

    def channel(self, topic: str, schema: dict[str, Any]) -> int:
        if topic not in self.channels:
            schema_id = self.writer.register_schema(str(schema.get("title", topic)), "jsonschema",
                                                    orjson.dumps(schema))
            self.channels[topic] = self.writer.register_channel(topic, "json", schema_id)
        return self.channels[topic]

    def write(self, channel: int, log_time: int, publish_time: int, data: bytes) -> None:
        self.sequence[channel] += 1
        self.writer.add_message(channel, log_time, data, publish_time, self.sequence[channel])

    def size(self) -> int:
        return self._stream.tell()

    def close(self) -> None:
        self.writer.finish()
        self._stream.close()


class Recorder(PlainLogin):
    """Record ``robots`` as ``username`` into ``out`` (see the module's docstring); :meth:`run` until stopped."""

    def __init__(self, *, url: str, username: str, password: str, robots: Sequence[str], out: str | Path,
                 prefix: str = "roslink", ca_file: str | None = None, split_size: int = 0,
                 topics: Sequence[str] = ()) -> None:
        self.tree = TopicTree(prefix)
        self.username, self.robots, self.out = username, list(robots), Path(out)
        self.split_size, self.wanted = split_size, list(topics)
        self.progress = Progress()
        self.channels = JsonChannels(self.tree, self.robots, topics)
        self._inbox: queue.Queue[tuple[str, bytes, int, bool]] = queue.Queue(QUEUE_LIMIT)
        self._retained_seen: set[tuple[str, int]] = set()  # a retained message is recorded once, whatever matched it
        self._file: _McapFile | None = None
        super().__init__(url=url, username=username, password=password, ca_file=ca_file, role="record")
        self.client.on_message = self._on_message

    # -- MQTT (paho's thread) ------------------------------------------------------------------------------
    def filters(self) -> list[str]:
        out = []
        for robot in self.robots:
            out += [self.tree.state(robot, "description"), self.tree.heartbeat(robot), self.tree.state_filter(robot),
                    self.tree.to_user_filter(robot, self.username)]
        return out

    def on_connected(self, client: mqtt.Client) -> None:
        client.subscribe([(f, 1) for f in self.filters()])

    def _on_message(self, _client: mqtt.Client, _userdata: Any, message: mqtt.MQTTMessage) -> None:
        try:
            self._inbox.put_nowait((message.topic, bytes(message.payload), time.time_ns(), bool(message.retain)))
        except queue.Full:
            self.progress.dropped += 1

    # -- writing -------------------------------------------------------------------------------------------
    def _path(self) -> Path:
        index = len(self.progress.files)
        if not self.split_size or index == 0:
            return self.out
        return self.out.with_name(f"{self.out.stem}-{index:03d}{self.out.suffix}")

    def _open(self) -> _McapFile:
        if self._file is None:
            self._file = _McapFile(self._path())
            self.progress.files.append(self._file.path)
        return self._file

    def write(self, topic: str, payload: bytes, arrived: int, retained: bool = False) -> None:
        if not payload:
            return  # a retained message cleared
        if retained:  # the description comes first on a filter of its own, then again through state/#: once
            key = (topic, hash(payload))
            if key in self._retained_seen:
                return
            self._retained_seen.add(key)
        route = self.channels.route(topic)
        if route is None:
            self.channels.learn_unrouted(topic, payload)
            return
        if route.description:
            self.channels.learn(route, payload)
        try:
            data, published = self.channels.encode(route, payload, arrived)
        except Exception as err:  # a malformed CBOR or image payload: kept out, counted, the recording goes on
            log.warning("%s: not recorded: %s", topic, err)
            self.progress.dropped += 1
            return
        mcap_file = self._open()
        mcap_file.write(mcap_file.channel(topic, route.schema), arrived, published, data)
        self.progress.messages += 1
        self.progress.bytes += len(data)
        self.progress.per_topic[topic] += 1
        if self.split_size and mcap_file.size() >= self.split_size:
            self.close()

    def _watch_videos(self, leave: bool = False) -> None:
        """Keep watching the video streams ``topics`` names (``--topic front_camera``): their frames flow only while
        someone watches, and a recording of telemetry must not pull video over a thin link unasked."""
        for robot, description in list(self.channels.descriptions.items()):
            for entry in description.video:
                if entry.name in self.wanted:
                    self.client.publish(self.tree.user_topic(robot, self.username, Verb.WATCH, entry.name),
                                        WatchRequest(self.client_id, leave=leave).to_json(), qos=WatchRequest.QOS)

    def close(self) -> None:
        """Finish the file being written (its summary and index): a complete MCAP file."""
        if self._file is not None:
            self._file.close()
            self._file = None

    # -- running -------------------------------------------------------------------------------------------
    def run(self, *, duration: float | None, stop: threading.Event,
            on_progress: Callable[[Progress, float], None] | None = None, every: float = 1.0) -> Progress:
        """Write until ``duration`` s have passed or ``stop`` is set; the file is complete when this returns."""
        started = time.monotonic()
        next_report = started + every
        renew_at = started
        try:
            while not stop.is_set():
                now = time.monotonic()
                if duration is not None and now - started >= duration:
                    break
                if now >= renew_at:
                    self._watch_videos()
                    renew_at = now + WATCH_RENEW
                try:
                    self.write(*self._inbox.get(timeout=0.1))
                except queue.Empty:
                    pass
                if on_progress is not None and time.monotonic() >= next_report:
                    on_progress(self.progress, time.monotonic() - started)
                    next_report += every
        finally:
            self._watch_videos(leave=True)
            self.disconnect()
            while not self._inbox.empty():  # what arrived before the disconnect
                self.write(*self._inbox.get_nowait())
            if self._file is None and not self.progress.files:
                self._open()  # nothing came: still a valid (empty) file
            self.close()
        return self.progress

