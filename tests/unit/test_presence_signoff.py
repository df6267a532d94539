"""A clean sign-off is told apart from a last-will (both end in the same empty retained message)."""

from __future__ import annotations

from roslink_mqtt.presence import OperatorTracker, Presence, classify_presence, operator_heartbeat, operator_signoff


def test_signoff_is_classified_apart_from_heartbeats_and_the_will() -> None:
    assert classify_presence(operator_signoff("alice", "c1")) is Presence.SIGNED_OFF
    assert classify_presence(b"") is Presence.GONE
    assert classify_presence(operator_heartbeat("alice", "c1")) is Presence.COMMANDING
    assert classify_presence(operator_heartbeat("alice", "c1", commanding=False)) is Presence.WATCHING
    assert classify_presence(b"1") is Presence.COMMANDING  # when unsure, losing the client stops the robot


def test_signoff_ends_presence_like_the_will_does() -> None:
    t = OperatorTracker(timeout=1.5)
    assert t.record("alice", "c1", Presence.COMMANDING, 0.0)
    assert not t.record("alice", "c1", Presence.SIGNED_OFF, 0.5)  # the driver left: the robot must stop
    assert not t.is_live("alice")
    assert not t.record("alice", "c1", Presence.GONE, 0.6)  # the clear that follows changes nothing more
    assert t.record("bob", "w", Presence.WATCHING, 0.0) and t.record("bob", "d", Presence.COMMANDING, 0.0)
    assert t.record("bob", "w", Presence.SIGNED_OFF, 0.1)  # a watcher leaving while the driver stays
