"""Topic grammar: every topic in docs/protocol.md's tree is built and parsed back; bad names refused;
verbs, leaves and filters come from one module."""

from __future__ import annotations

import pytest

from roslink_mqtt.topics import (
    ANY,
    RESERVED_RULE_LEVELS,
    ROBOT_VERBS,
    USER_VERBS,
    Kind,
    TopicError,
    TopicTree,
    Verb,
    check_filter_path,
    join_leaf,
    split_leaf,
    state_name,
)


@pytest.fixture(params=["roslink", "fleet/eu/roslink"])
def tree(request) -> TopicTree:
    return TopicTree(request.param)


def test_build_and_parse_every_topic(tree: TopicTree) -> None:
    p = tree.prefix
    cases = [
        (tree.heartbeat("turtle1"), f"{p}/turtle1/heartbeat", Kind.HEARTBEAT, "turtle1", None, None, None),
        (tree.state("turtle1", "global_motion"), f"{p}/turtle1/state/global_motion", Kind.STATE, "turtle1", None,
         None, "global_motion"),
        (tree.command("turtle1", "alice", "twist"), f"{p}/turtle1/from/alice/cmd/twist", Kind.FROM, "turtle1",
         "alice", Verb.CMD, "twist"),
        (tree.call("turtle1", "alice", "reset"), f"{p}/turtle1/from/alice/call/reset", Kind.FROM, "turtle1",
         "alice", Verb.CALL, "reset"),
        (tree.call("turtle1", "alice", "nav/reset"), f"{p}/turtle1/from/alice/call/nav/reset", Kind.FROM, "turtle1",
         "alice", Verb.CALL, "nav/reset"),
        (tree.reply("turtle1", "alice", "reset"), f"{p}/turtle1/to/alice/reply/reset", Kind.TO, "turtle1",
         "alice", Verb.REPLY, "reset"),
        (tree.provide("turtle1", "alice", "self_test"), f"{p}/turtle1/from/alice/provide/self_test", Kind.FROM,
         "turtle1", "alice", Verb.PROVIDE, "self_test"),
        (tree.request("turtle1", "alice", "self_test"), f"{p}/turtle1/to/alice/request/self_test", Kind.TO,
         "turtle1", "alice", Verb.REQUEST, "self_test"),
        (tree.response("turtle1", "alice", "self_test"), f"{p}/turtle1/from/alice/response/self_test", Kind.FROM,
         "turtle1", "alice", Verb.RESPONSE, "self_test"),
        (tree.advertise("turtle1", "alice", "lights"), f"{p}/turtle1/from/alice/advertise/lights", Kind.FROM,
         "turtle1", "alice", Verb.ADVERTISE, "lights"),
        (tree.error("turtle1", "bob"), f"{p}/turtle1/to/bob/error", Kind.TO, "turtle1", "bob", Verb.ERROR, ""),
        (tree.access("turtle1", "bob"), f"{p}/turtle1/to/bob/access", Kind.TO, "turtle1", "bob", Verb.ACCESS, ""),
        (tree.notice("turtle1", "bob"), f"{p}/turtle1/to/bob/notice", Kind.TO, "turtle1", "bob", Verb.NOTICE, ""),
        # a generic rule's input has no verb: its whole leaf is the rule's name
        (tree.from_user("turtle1", "alice", "lights"), f"{p}/turtle1/from/alice/lights", Kind.FROM, "turtle1",
         "alice", None, "lights"),
    ]
    for built, expected, kind, robot, user, verb, name in cases:
        assert built == expected
        parsed = tree.parse(built)
        assert (parsed.kind, parsed.robot, parsed.user, parsed.verb, parsed.name) == (kind, robot, user, verb, name)
        if kind in (Kind.FROM, Kind.TO):
            assert tree.user_topic(robot, user, verb, name) == built if verb is not None else True
            assert built.endswith("/" + parsed.leaf)
    op = tree.operator("alice", "laptop-1")
    assert op == f"{p}/operators/alice/laptop-1"
    parsed = tree.parse(op)
    assert (parsed.kind, parsed.user, parsed.client_id) == (Kind.OPERATOR, "alice", "laptop-1")
    assert op.startswith(tree.operators_prefix())


def test_every_verb_is_declared_once_with_what_a_refusal_of_it_says() -> None:
    """A verb added to the enum without its declaration fails here, not at the first refusal."""
    for verb in Verb:
        assert verb.meaning, verb
        if verb.sent_by_user:
            assert verb.refused("reset", "turtle1") and "{" not in verb.refused("reset", "turtle1"), verb
    assert Verb.CALL.refused("reset", "turtle1") == "call 'reset'"
    assert Verb.CONTROL.refused("take_over", "turtle1") == "take over control of turtle1"
    assert {v for v in Verb if v.open_to_viewers} == {Verb.CALL, Verb.GOAL, Verb.CANCEL, Verb.PARAM, Verb.SNAPSHOT,
                                                     Verb.WATCH}


def test_verbs_belong_to_one_direction() -> None:
    assert USER_VERBS | ROBOT_VERBS == set(Verb) and not USER_VERBS & ROBOT_VERBS
    assert {v for v in Verb if not v.named} == {Verb.ERROR, Verb.NOTICE, Verb.ACCESS}
    assert {v for v in USER_VERBS if v.retained_by_sender} == {Verb.PROVIDE, Verb.ADVERTISE, Verb.PROVIDE_ACTION,
                                                              Verb.DECLARE}
    # a robot's verb under from/ (or a user's under to/) is no verb: "reply" would be a generic rule's name
    assert split_leaf("reply/reset") == (None, "reply/reset")
    assert split_leaf("cmd/twist", sent_by_user=False) == (None, "cmd/twist")
    assert split_leaf("error", sent_by_user=False) == (Verb.ERROR, "")
    # a verb missing its name, or with a name it must not have, reads as a plain name (the robot: "no mapping")
    assert split_leaf("call") == (None, "call")
    assert split_leaf("error/x", sent_by_user=False) == (None, "error/x")
    for verb in Verb:
        name = "" if not verb.named else "a/b"
        assert split_leaf(join_leaf(verb, name), sent_by_user=verb.sent_by_user) == (verb, name)
    with pytest.raises(TopicError):
        join_leaf(Verb.ERROR, "x")
    with pytest.raises(TopicError):
        join_leaf(Verb.CALL, "")
    # every user verb but cmd is reserved as a rule's first level, and so is state
    assert set(RESERVED_RULE_LEVELS) == {v.value for v in USER_VERBS} - {"cmd"} | {"state"}


def test_filters(tree: TopicTree) -> None:
    p = tree.prefix
    assert tree.from_user_filter("turtle1") == f"{p}/turtle1/from/+/#"
    assert tree.from_user_filter("turtle1", "alice") == f"{p}/turtle1/from/alice/#"
    assert tree.to_user_filter("turtle1", "alice") == f"{p}/turtle1/to/alice/#"
    assert tree.to_user_filter("turtle1", ANY) == f"{p}/turtle1/to/+/#"
    assert tree.operators_filter("alice") == f"{p}/operators/alice/+"
    assert tree.operators_filter("alice", deep=True) == f"{p}/operators/alice/#"
    assert tree.heartbeat_filter() == f"{p}/+/heartbeat"
    assert tree.state_filter() == f"{p}/+/state/#"
    assert tree.state_filter("turtle1", "nav/+") == f"{p}/turtle1/state/nav/+"
    assert tree.verb_filter("turtle1", "alice", Verb.REPLY) == f"{p}/turtle1/to/alice/reply/#"
    assert tree.verb_filter("turtle1", ANY, Verb.ERROR) == f"{p}/turtle1/to/+/error"
    assert tree.verb_filter("turtle1", "alice", Verb.CMD) == f"{p}/turtle1/from/alice/cmd/#"
    with pytest.raises(TopicError):
        tree.state_filter("turtle1", "a#")
    with pytest.raises(TopicError):
        tree.state_filter("turtle1", "#/x")
    with pytest.raises(TopicError):
        tree.from_user_filter("tur+tle1")


def test_state_names_and_filter_paths() -> None:
    assert state_name("state/global_motion") == "global_motion"
    assert state_name("/global_motion/") == "global_motion"
    assert state_name("nav/pose") == "nav/pose"
    assert check_filter_path("nav/+") is True and check_filter_path("#") is True
    assert check_filter_path("nav/pose") is False
    for bad in ("", "a+", "#/a", "x/$y", "a//b"):
        with pytest.raises(TopicError):
            check_filter_path(bad)


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
