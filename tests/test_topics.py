"""Topic tree: every topic in docs/protocol.md's tree is built and parsed back; bad names refused."""

from __future__ import annotations

import pytest

from roslink_mqtt.topics import Kind, TopicError, TopicTree


@pytest.fixture(params=["roslink", "fleet/eu/roslink"])
def tree(request) -> TopicTree:
    return TopicTree(request.param)


def test_build_and_parse_every_topic(tree: TopicTree) -> None:
    p = tree.prefix
    cases = [
        (tree.heartbeat("turtle1"), f"{p}/turtle1/heartbeat", Kind.HEARTBEAT, "turtle1", None, None),
        (tree.state("turtle1", "global_motion"), f"{p}/turtle1/state/global_motion", Kind.STATE, "turtle1", None,
         "global_motion"),
        (tree.command("turtle1", "alice", "twist"), f"{p}/turtle1/from/alice/cmd/twist", Kind.FROM, "turtle1",
         "alice", "cmd/twist"),
        (tree.call("turtle1", "alice", "reset"), f"{p}/turtle1/from/alice/call/reset", Kind.FROM, "turtle1",
         "alice", "call/reset"),
        (tree.reply("turtle1", "alice", "reset"), f"{p}/turtle1/to/alice/reply/reset", Kind.TO, "turtle1",
         "alice", "reply/reset"),
        (tree.provide("turtle1", "alice", "self_test"), f"{p}/turtle1/from/alice/provide/self_test", Kind.FROM,
         "turtle1", "alice", "provide/self_test"),
        (tree.request("turtle1", "alice", "self_test"), f"{p}/turtle1/to/alice/request/self_test", Kind.TO,
         "turtle1", "alice", "request/self_test"),
        (tree.response("turtle1", "alice", "self_test"), f"{p}/turtle1/from/alice/response/self_test", Kind.FROM,
         "turtle1", "alice", "response/self_test"),
        (tree.error("turtle1", "bob"), f"{p}/turtle1/to/bob/error", Kind.TO, "turtle1", "bob", "error"),
    ]
    for built, expected, kind, robot, user, name in cases:
        assert built == expected
        parsed = tree.parse(built)
        assert (parsed.kind, parsed.robot, parsed.user, parsed.name) == (kind, robot, user, name)
    op = tree.operator("alice", "laptop-1")
    assert op == f"{p}/operators/alice/laptop-1"
    parsed = tree.parse(op)
    assert (parsed.kind, parsed.user, parsed.client_id) == (Kind.OPERATOR, "alice", "laptop-1")


def test_filters(tree: TopicTree) -> None:
    p = tree.prefix
    assert tree.all_from_users("turtle1") == f"{p}/turtle1/from/+/#"
    assert tree.operators_of("alice") == f"{p}/operators/alice/+"
    assert tree.all_heartbeats() == f"{p}/+/heartbeat"
    assert tree.all_state() == f"{p}/+/state/#"


@pytest.mark.parametrize("bad", ["", "+", "#", "a/b", "tur+tle", "x#", "$SYS", "a\0b"])
def test_bad_names_refused(bad: str) -> None:
    t = TopicTree()
    for build in (lambda: t.heartbeat(bad), lambda: t.command("r", bad, "twist"),
                  lambda: t.operator("alice", bad), lambda: t.command("r", "u", bad)):
        with pytest.raises(TopicError):
            build()


def test_bad_prefix_and_foreign_topics() -> None:
    with pytest.raises(TopicError):
        TopicTree("roslink/#")
    with pytest.raises(TopicError):
        TopicTree("a//b")
    t = TopicTree()
    for foreign in ["other/turtle1/heartbeat", "roslink", "roslink/turtle1", "roslink/turtle1/unknown/x",
                    "roslink/turtle1/from/alice", "roslink/operators/alice", "roslink//heartbeat",
                    "roslink/turtle1/state/"]:
        assert t.parse(foreign) is None, foreign
