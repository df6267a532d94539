"""``roslink-mqtt play``: a recording (``roslink-mqtt record``) published again, as the robot it shows.

For demos, tests and dashboards without a robot: the heartbeats and state of the recorded robots go back into a
broker at the recorded pace (or ``rate`` times faster), logged in as a robot, so every client sees a robot that
behaves as the recorded one did. What the robot sent one user (``to/<user>/…``) is not played: it was addressed
to someone who is not there. ``rename`` plays robot A's topics as robot B's (log in as B). Retained topics (the
heartbeat, the description, who drives, the link report, state the description marks retained) are published
retained, as the bridge does; the recording's ``log_time`` orders and paces everything.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import orjson

from ..protocol import SystemStatus
from ..protocol.description import RobotDescription
from ..protocol.errors import ProtocolError
from ..protocol.lease import CONTROL
from ..protocol.link import LINK
from ..topics import Kind, ParsedTopic, TopicTree
from .plain_login import PlainLogin

ALWAYS_RETAINED = ("description", CONTROL, LINK)  # state names the bridge itself retains


@dataclass(frozen=True, slots=True)
class Frame:
    """One message to publish: when (s after the first), where, what, retained or not."""

    at: float
    topic: str
    payload: bytes
    retain: bool


def frames(path: str | Path, tree: TopicTree, rename: dict[str, str] | None = None) -> Iterator[Frame]:
    """The recording's robot messages in log-time order, with their topics renamed as asked."""
    from mcap.reader import make_reader

    rename = rename or {}
    retained_state: dict[str, set[str]] = {}  # robot → state names its description marks retained
    first: int | None = None
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            parsed = tree.parse(channel.topic)
            if parsed is None or parsed.robot is None or parsed.kind not in (Kind.HEARTBEAT, Kind.STATE):
                continue
            if parsed.kind is Kind.STATE and parsed.name == "description":
                try:
                    described = RobotDescription.from_json(message.data)
                    retained_state[parsed.robot] = {e.name for e in described.state if e.retained}
                except ProtocolError:
                    pass
            robot = rename.get(parsed.robot, parsed.robot)
            if parsed.kind is Kind.HEARTBEAT:
                topic, retain = tree.heartbeat(robot), True
            else:
                name = parsed.name or ""
                topic = tree.state(robot, name)
                retain = name in ALWAYS_RETAINED or name in retained_state.get(parsed.robot, set())
            first = message.log_time if first is None else first
            payload = bytes(message.data)
            if robot != parsed.robot:
                payload = _renamed(payload, parsed, robot)
            yield Frame((message.log_time - first) / 1e9, topic, payload, retain)


def _renamed(payload: bytes, parsed: ParsedTopic, robot: str) -> bytes:
    """The robot's name inside the two bodies that carry it: the heartbeat's ``name``, the description's ``robot``."""
    try:
        body = orjson.loads(payload)
        if parsed.kind is Kind.HEARTBEAT and isinstance(body.get("payload"), dict):
            body["payload"]["name"] = robot
        elif parsed.name == "description" and isinstance(body, dict):
            body["robot"] = robot
        else:
            return payload
        return orjson.dumps(body)
    except (orjson.JSONDecodeError, AttributeError):
        return payload


class Player(PlainLogin):
    """Publish :func:`frames` into a broker as ``username`` (a robot's login)."""

    def __init__(self, *, url: str, username: str, password: str, ca_file: str | None = None,
                 tree: TopicTree | None = None) -> None:
        super().__init__(url=url, username=username, password=password, ca_file=ca_file, role="play")
        self.tree = tree or TopicTree()
        self._heartbeats: dict[str, bytes] = {}  # topic → the last heartbeat played

    def play(self, source: Iterator[Frame], *, rate: float = 1.0, stop: threading.Event,
             on_frame: Callable[[Frame], None] | None = None) -> int:
        """Publish each frame at its time (divided by ``rate``); how many were published."""
        started = time.monotonic()
        count = 0
        for frame in source:
            delay = started + frame.at / rate - time.monotonic()
            if delay > 0 and stop.wait(delay):
                break
            if stop.is_set():
                break
            self.client.publish(frame.topic, frame.payload, qos=1 if frame.retain else 0, retain=frame.retain)
            if self.tree_kind(frame.topic) is Kind.HEARTBEAT:
                self._heartbeats[frame.topic] = frame.payload
            count += 1
            if on_frame is not None:
                on_frame(frame)
        return count

    def tree_kind(self, topic: str) -> Kind | None:
        parsed = self.tree.parse(topic)
        return parsed.kind if parsed is not None else None

    def close(self) -> None:
        """Leave each played robot offline (its last heartbeat, retained, saying so), as a stopping bridge does."""
        for topic, payload in self._heartbeats.items():
            try:
                heartbeat = orjson.loads(payload)
                heartbeat["payload"]["system_status"] = int(SystemStatus.OFFLINE)
            except (orjson.JSONDecodeError, KeyError, TypeError):
                continue
            self.client.publish(topic, orjson.dumps(heartbeat), qos=1, retain=True).wait_for_publish(5)
        self.disconnect()
