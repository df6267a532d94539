"""Video needs the scheduled uplink: a bridge whose robot file says ``bridge.uplink: fifo`` refuses a watch and says
why (a module of its own: it starts a turtle1 of its own, which must not run beside test_video.py's)."""

from __future__ import annotations

import pytest

from roslink_mqtt.protocol.video import WatchRequest
from roslink_mqtt.topics import TopicTree, Verb
from roslink_mqtt.video.watchers import NEEDS_SCHEDULED_UPLINK
from tests.support.broker_setup import write_fleet
from tests.support.mqtt_client import TestClient
from tests.support.robot_stack import turtle1_online

pytestmark = pytest.mark.timeout(180)

T = TopicTree()
STREAM = "front_camera"  # the demo fleet's video stream of turtle1
CAMERA = T.state("turtle1", STREAM)


def test_a_fifo_uplink_refuses_a_watch_with_the_reason(tmp_path) -> None:
    """``bridge.uplink: fifo`` hands everything over in order on the command connection: a frame there would hold
    the next emergency stop back, so the bridge refuses a watch and says why, and the camera never starts."""
    (tmp_path / "fleet").mkdir()
    fleet = write_fleet(tmp_path / "fleet", edit=lambda text: text.replace(
        "      keepalive: 2\n", "      keepalive: 2\n      uplink: fifo\n", 1))
    with turtle1_online(tmp_path, fleet=fleet) as port, TestClient(port, "bob", "bob-demo") as bob:
        assert bob.connect() == 0
        bob.subscribe(T.error("turtle1", "bob"))
        bob.subscribe(CAMERA, qos=0)
        bob.publish(T.user_topic("turtle1", "bob", Verb.WATCH, STREAM), WatchRequest("bob-web", key=True).to_json(),
                    qos=1)
        seen = bob.drain(3.0)
    errors = [m.json()["error"] for m in seen if m.topic == T.error("turtle1", "bob")]
    assert any(NEEDS_SCHEDULED_UPLINK in e for e in errors), errors
    assert not [m for m in seen if m.topic == CAMERA]
