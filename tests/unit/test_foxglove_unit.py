"""The Foxglove gateway's pure parts: twists from Foxglove's JSON, the names it gives services and parameters, and
who its front admits (issue 49; tests/integration/test_foxglove_gateway.py tries it with real clients)."""

from __future__ import annotations

import math

import pytest

from roslink_mqtt.cli.foxglove_front import Admission, check_token, normalize_origin
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


TOKEN = "s3cret-token-of-this-run_0123456789"


@pytest.mark.parametrize(("origins", "path", "status"), [
    ([], f"/?token={TOKEN}", None),  # a program
    (["https://app.foxglove.dev"], f"/?token={TOKEN}", None),
    (["https://lichtblick-suite.github.io"], f"/?token={TOKEN}", None),
    (["null"], f"/?token={TOKEN}", None),  # a page opened from disk: desktop Foxglove and Lichtblick
    (["file://"], f"/?token={TOKEN}", None),  # the same before Chromium 92
    (["http://localhost:3000"], f"/?x=1&token={TOKEN}", None),  # added with --allow-origin
    (["http://evil.example"], f"/?token={TOKEN}", 403),  # the origin first: a right token does not help
    (["https://app.foxglove.dev.evil.example"], f"/?token={TOKEN}", 403),
    (["http://app.foxglove.dev"], f"/?token={TOKEN}", 403),  # not the https app
    (["https://app.foxglove.dev", "https://app.foxglove.dev"], f"/?token={TOKEN}", 403),
    (["not an origin"], f"/?token={TOKEN}", 403),
    ([], "/", 401), ([], "/?token=", 401), (["https://app.foxglove.dev"], "/", 401), (["null"], "/", 401),
    ([], "/?token=guess", 403), ([], f"/?token={TOKEN}x", 403), ([], f"/?token={TOKEN}&token={TOKEN}", 403),
    ([], f"/{TOKEN}", 401),  # only the query carries it
])
def test_who_the_front_admits(origins: list[str], path: str, status: int | None) -> None:
    refusal = Admission(TOKEN, frozenset({"http://localhost:3000"})).check(origins, path)
    assert (refusal.status if refusal else None) == status, refusal


def test_without_a_token_pages_from_disk_are_refused() -> None:
    """A sandboxed frame of any web site also says ``Origin: null``: without a token nothing would tell it apart."""
    admission = Admission(None)
    assert admission.check([], "/") is None
    assert admission.check(["https://app.foxglove.dev"], "/") is None
    assert admission.check(["null"], "/").status == 403  # type: ignore[union-attr]
    assert Admission(None, frozenset({"null"})).check(["null"], "/") is None  # --allow-origin null: the user's call


def test_origins_and_tokens_given_by_the_user_are_checked() -> None:
    assert normalize_origin("HTTPS://Foxglove.Example.com/") == "https://foxglove.example.com"
    assert normalize_origin("http://localhost:8080") == "http://localhost:8080"
    assert normalize_origin("null") == "null"
    for bad in ("foxglove.example.com", "https://x.example/app", "https://x.example/?a=1", "ws://x.example",
                "https://user@x.example", "*"):
        with pytest.raises(ValueError, match="not an origin"):
            normalize_origin(bad)
    assert check_token(TOKEN) == TOKEN
    for bad in ("short", "x" * 15, "has space in it, long enough", "a&token=b-long-enough-1234", "é" * 20):
        with pytest.raises(ValueError, match="at least 16 characters"):
            check_token(bad)
