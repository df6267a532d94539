"""Failsafe decisions and operator presence as pure logic (the fault-injection tests prove the timing)."""

from __future__ import annotations

from roslink_mqtt.bridge.core.failsafe import Failsafe
from roslink_mqtt.presence import OperatorTracker, is_commanding, operator_heartbeat


def test_dead_man_only_while_streaming() -> None:
    f = Failsafe(command_timeout=1.0, link_up=True)
    assert f.tick(0.0, {"alice"}) is None  # nothing moving
    f.velocity_command("alice", 0.0)
    assert f.tick(0.9, {"alice"}) is None
    assert "dead-man" in f.tick(1.1, {"alice"})
    f.stopped()
    assert f.tick(5.0, {"alice"}) is None  # stopped once, not again and again


def test_a_stream_that_ends_on_a_standstill_is_a_stop_not_a_failsafe() -> None:
    """A released drive pad sends one zero twist: the robot is stopped, the dead-man has nothing left to do."""
    f = Failsafe(command_timeout=1.0, link_up=True)
    f.velocity_command("alice", 0.0)
    f.velocity_command("alice", 0.5, standstill=True)
    assert f.tick(5.0, {"alice"}) is None and f.operator_gone("alice") is None
    f.velocity_command("alice", 6.0)  # moving again: armed again
    assert "dead-man" in f.tick(7.1, {"alice"})
    f.stopped()
    f.goal_command("carol")  # a goal under way stays guarded whatever twists say
    f.velocity_command("carol", 8.0, standstill=True)
    assert f.tick(20.0, {"carol"}) is None  # no dead-man for a goal
    assert f.operator_gone("carol") == "operator carol went away"


def test_operator_gone_and_link_lost() -> None:
    f = Failsafe(command_timeout=1.0, link_up=True)
    f.velocity_command("alice", 0.0)
    assert f.operator_gone("bob") is None
    assert f.operator_gone("alice") == "operator alice went away"
    assert f.tick(0.1, set()) == "operator alice went away"
    assert f.link_lost() == "lost the broker"
    f.stopped()
    assert f.link_lost() is None


def test_goal_has_no_dead_man_but_stops_when_operator_leaves() -> None:
    f = Failsafe(command_timeout=1.0, link_up=True)
    f.goal_command("carol")
    assert f.tick(100.0, {"carol"}) is None
    assert f.tick(100.0, set()) == "operator carol went away"


def test_operator_tracker() -> None:
    t = OperatorTracker(timeout=1.5)
    watcher = operator_heartbeat("alice", "phone", commanding=False)
    assert t.heartbeat("alice", "laptop", b"x", 0.0)  # a plain payload counts as a commanding client
    assert t.heartbeat("alice", "phone", watcher, 0.5)
    assert not t.heartbeat("bob", "pc", b"", 0.5)  # a clear for an unknown client: bob has nobody left
    assert t.expire(1.4) == []
    assert t.expire(1.6) == ["alice"]  # the commanding laptop went silent: the phone does not cover for it
    assert t.is_live("alice") and t.is_live("alice", "phone") and not t.is_live("alice", "laptop")
    assert t.expire(2.1) == ["alice"]  # and now nobody is left
    assert not t.is_live("alice")
    t.heartbeat("carol", "c1", b"x", 3.0)
    assert not t.heartbeat("carol", "c1", b"", 3.1)  # last-will
    assert t.live_users() == set()


def test_a_watcher_leaving_does_not_cost_its_user_command_presence() -> None:
    t = OperatorTracker(timeout=1.5)
    t.heartbeat("alice", "laptop", operator_heartbeat("alice", "laptop"), 0.0)
    t.heartbeat("alice", "phone", operator_heartbeat("alice", "phone", commanding=False), 0.0)
    assert t.heartbeat("alice", "phone", b"", 0.2)  # the watcher's last-will: alice still drives
    t.heartbeat("alice", "phone", operator_heartbeat("alice", "phone", commanding=False), 0.3)
    t.heartbeat("alice", "laptop", operator_heartbeat("alice", "laptop"), 1.0)
    assert t.expire(1.9) == []  # the watcher expired, the driver did not
    assert not t.heartbeat("alice", "laptop", b"", 2.0)  # the driver's last-will: stop


def test_commanding_is_read_from_the_heartbeat() -> None:
    assert is_commanding(operator_heartbeat("a", "c")) and not is_commanding(operator_heartbeat("a", "c",
                                                                                                 commanding=False))
    assert is_commanding(b"1") and is_commanding(b'{"message_id": 0, "payload": {}}')  # unsure: commanding


def test_operator_heartbeat_payload_is_a_roslink_heartbeat() -> None:
    from roslink_mqtt.protocol import MessageId, decode
    env = decode(operator_heartbeat("alice", "laptop-1", 3), MessageId.HEARTBEAT)
    assert env.payload["owner_id"] == "alice" and env.payload["name"] == "laptop-1"
