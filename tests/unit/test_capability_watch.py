"""``watch/<stream>`` without ROS: the watchers' leases (roslink_mqtt/video/watchers.py) with a clock of the test's
own, and the capability (bridge/core/capabilities/watch.py) through the command endpoint with a recording port.

Any granted user may watch, a viewer too; a user without a grant on the robot, a stream the robot does not have
and a malformed request are refused on the sender's error topic. A watch lapses unless renewed, ends with its
client's presence, and a user cannot pin the robot's memory with made-up client ids or turn the stream into
keyframes by asking for them.
"""

from __future__ import annotations

from dataclasses import replace

import orjson
import pytest

from roslink_mqtt.bridge.core.capabilities import Watch
from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.config import VideoStream
from roslink_mqtt.topics import Verb
from roslink_mqtt.video.watchers import KEY_MIN_GAP, MAX_CLIENTS_PER_USER, Watchers
from tests.unit.test_bridge_endpoint import FLEET, ROBOT, ROUTES, Harness, T

pytestmark = pytest.mark.unit

LEASE = 10.0


class Presence:
    def __init__(self) -> None:
        self.live: set[tuple[str, str]] = set()

    def __call__(self, user: str, client_id: str) -> bool:
        return (user, client_id) in self.live


def test_a_watch_lapses_unless_renewed() -> None:
    watchers = Watchers(Presence(), lease=LEASE)
    assert watchers.watch("bob", "bob-web", now=0.0) is None
    assert watchers.expire(LEASE - 1) == 1
    watchers.watch("bob", "bob-web", now=LEASE - 1)  # renewed
    assert watchers.expire(2 * LEASE - 2) == 1
    assert watchers.expire(2 * LEASE - 1) == 0


def test_a_watch_ends_with_its_clients_presence_but_a_client_without_presence_keeps_its_lease() -> None:
    presence = Presence()
    watchers = Watchers(presence, lease=LEASE)
    presence.live.add(("alice", "alice-web"))
    watchers.watch("alice", "alice-web", now=0.0)
    watchers.watch("alice", "script", now=0.0)  # a plain MQTT client: no presence, only its lease
    assert watchers.expire(1.0) == 2
    presence.live.clear()  # the browser tab closed: its last-will cleared its presence
    assert watchers.expire(2.0) == 1
    watchers.leave("alice", "script")
    assert watchers.expire(2.0) == 0


def test_one_user_cannot_pin_memory_with_made_up_client_ids() -> None:
    watchers = Watchers(Presence(), lease=LEASE)
    for i in range(MAX_CLIENTS_PER_USER):
        assert watchers.watch("bob", f"bob-{i}", now=0.0) is None
    why = watchers.watch("bob", "bob-one-more", now=0.0)
    assert why is not None and f"already watches from {MAX_CLIENTS_PER_USER} clients" in why
    assert watchers.watch("bob", "bob-0", now=1.0) is None  # renewing one it has is fine
    assert watchers.watch("alice", "alice-web", now=1.0) is None  # and other users are not affected
    assert len(watchers) == MAX_CLIENTS_PER_USER + 1


def test_keyframes_asked_for_come_at_most_once_per_gap() -> None:
    watchers = Watchers(Presence(), lease=LEASE)
    watchers.watch("bob", "bob-web", now=0.0)  # joining asks for one
    assert watchers.take_key(0.0) and not watchers.take_key(0.01)
    keys = 0
    for i in range(1000):  # a flood of key requests over 2 s
        now = 0.01 + i * 0.002
        watchers.watch("bob", "bob-web", now=now, key=True)
        keys += watchers.take_key(now)
    assert keys <= 2.0 / KEY_MIN_GAP + 1


class Port:
    def __init__(self) -> None:
        self.watches: list[tuple[str, str, str, bool]] = []
        self.left: list[tuple[str, str, str]] = []
        self.refuse_with: str | None = None

    def watch(self, stream: str, user: str, client_id: str, key: bool) -> str | None:
        self.watches.append((stream, user, client_id, key))
        return self.refuse_with

    def leave(self, stream: str, user: str, client_id: str) -> None:
        self.left.append((stream, user, client_id))


ROBOT_WITH_CAMERA = replace(ROBOT, video=(VideoStream("camera", "camera/image_raw", "sensor_msgs/msg/Image"),))


def _harness() -> tuple[Harness, Port]:
    h, port = Harness(), Port()
    h.endpoint = CommandEndpoint(FLEET, ROBOT_WITH_CAMERA, h.link, h.ros, ROUTES,
                                 capabilities=[Watch("turtle1", ("camera",), port, h.endpoint.refuse)])
    h.endpoint.link_up()
    return h, port


def _send(h: Harness, user: str, stream: str, body: dict | bytes) -> None:
    h.endpoint.on_mqtt(T.user_topic("turtle1", user, Verb.WATCH, stream),
                       body if isinstance(body, bytes) else orjson.dumps(body))


def test_a_viewer_watches_and_leaves() -> None:
    h, port = _harness()
    _send(h, "bob", "camera", {"client_id": "bob-web", "key": True})
    _send(h, "bob", "camera", {"client_id": "bob-web", "leave": True})
    assert port.watches == [("camera", "bob", "bob-web", True)]
    assert port.left == [("camera", "bob", "bob-web")]
    assert not h.link.errors("bob")


@pytest.mark.parametrize(("user", "stream", "body", "words"), [
    ("carol", "camera", {"client_id": "c"},  # carol has no grant on turtle1
     "user 'carol' may not watch 'camera' (any granted user may): no grant on turtle1"),
    ("bob", "rear", {"client_id": "b"}, "no video stream 'rear' on turtle1 (streams: camera)"),
    ("bob", "camera", {}, "client_id: missing"),
    ("bob", "camera", {"client_id": "b", "key": "yes"}, "key: expected boolean"),
    ("bob", "camera", b"[1]", "expected a JSON object"),
])
def test_refusals_reach_the_senders_error_topic(user: str, stream: str, body: dict | bytes, words: str) -> None:
    h, port = _harness()
    _send(h, user, stream, body)
    errors = h.link.errors(user)
    assert errors and words in errors[0].error, errors
    assert port.watches == []


def test_the_ports_refusal_is_reported_with_the_client_id() -> None:
    h, port = _harness()
    port.refuse_with = "user 'bob' already watches from 8 clients"
    _send(h, "bob", "camera", {"client_id": "bob-9"})
    errors = h.link.errors("bob")
    assert errors and errors[0].error == port.refuse_with and errors[0].client_id == "bob-9"
