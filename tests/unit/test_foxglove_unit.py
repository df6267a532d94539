"""The Foxglove gateway's pure parts: twists from Foxglove's JSON, and the names it gives services and parameters."""

from __future__ import annotations

import math

import pytest

from roslink_mqtt.cli.foxglove_gateway import twist_of
from roslink_mqtt.topics import TopicTree, Verb

pytestmark = pytest.mark.unit


def test_a_teleop_panels_twist_and_the_roslink_body_read_alike() -> None:
    ros = twist_of({"linear": {"x": 0.3, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": -0.5}})
    assert ros == {"lx": 0.3, "ly": 0.0, "lz": 0.0, "ax": 0.0, "ay": 0.0, "az": -0.5}
    assert twist_of({"lx": 0.3, "az": -0.5}) == ros
    assert twist_of({"linear": {"x": 1}}) == {"lx": 1.0, "ly": 0.0, "lz": 0.0, "ax": 0.0, "ay": 0.0, "az": 0.0}


@pytest.mark.parametrize(("value", "words"), [
    ({"linear": {"x": math.nan}}, "linear.x must be a finite number"),
    ({"linear": {"x": math.inf}}, "linear.x must be a finite number"),
    ({"angular": {"z": "fast"}}, "angular.z must be a finite number"),
    ({"angular": {"z": True}}, "angular.z must be a finite number"),
    ({"linear": [1, 2, 3]}, "linear must be an object"),
    ({"speed": 3}, "unknown twist field(s) speed"),
    ([0.3, 0.5], "a twist must be a JSON object"),
])
def test_a_twist_that_is_not_one_says_which_field(value: object, words: str) -> None:
    with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")):
        twist_of(value)


def test_gateway_names_read_back() -> None:
    tree = TopicTree("fleet/site")
    name = tree.gateway_name("turtle1", Verb.CALL, "reset")
    assert name == "fleet/site/turtle1/call/reset"
    assert tree.parse_gateway_name(name) == ("turtle1", Verb.CALL, "reset")
    param = tree.gateway_param("turtle1", "sim_robot", "qos_overrides./odom.depth")
    assert tree.parse_gateway_param(param) == ("turtle1", "sim_robot", "qos_overrides./odom.depth")
    for other in ("roslink/turtle1/call/reset", "fleet/site/turtle1/nonsense/x", "fleet/site/turtle1/call",
                  "fleet/site/turtle1/call/reset/"):
        assert tree.parse_gateway_name(other) is None, other
    assert tree.parse_gateway_param(tree.gateway_name("turtle1", Verb.PARAM, "sim_robot")) is None
