"""Issue 12 (5) as pure logic: late motion is dropped, stops never are; oversized presence is not a heartbeat."""

from __future__ import annotations

from roslink_mqtt.bridge.core.failsafe import late_motion
from roslink_mqtt.presence import (
    MAX_PRESENCE_BYTES,
    OperatorTracker,
    Presence,
    classify_presence,
    operator_heartbeat,
)


def test_motion_that_waited_longer_than_command_timeout_is_dropped() -> None:
    assert late_motion(10.0, 10.0, 1.0, stop=False) is None
    assert late_motion(10.0, 11.0, 1.0, stop=False) is None  # exactly command_timeout: still on time
    why = late_motion(10.0, 11.25, 1.0, stop=False)
    assert why is not None and "waited 1.25 s inside the bridge" in why and "command_timeout 1 s" in why


def test_a_stop_is_never_late() -> None:
    assert late_motion(0.0, 100.0, 1.0, stop=True) is None


def test_a_command_not_from_mqtt_has_no_arrival_and_is_never_late() -> None:
    assert late_motion(None, 100.0, 1.0, stop=False) is None


def test_standstill_is_a_stop_whatever_the_message_type() -> None:
    """Twist and TwistStamped shapes (the real messages are checked in tests/integration/test_safety_ros.py)."""
    from types import SimpleNamespace as Msg

    from roslink_mqtt.bridge.core.safety import is_standstill

    def twist(**set_: float) -> Msg:
        lin = Msg(x=0.0, y=0.0, z=0.0)
        ang = Msg(x=0.0, y=0.0, z=0.0)
        for key, value in set_.items():
            setattr(lin if key.startswith("l") else ang, key[-1], value)
        return Msg(linear=lin, angular=ang)

    assert is_standstill(twist()) and is_standstill(Msg(twist=twist()))
    assert not is_standstill(twist(ay=1e-9))
    assert not is_standstill(Msg(twist=twist(lz=-0.1)))


def test_presence_size_is_checked_before_parsing() -> None:
    assert classify_presence(b"") is Presence.GONE
    assert classify_presence(operator_heartbeat("alice", "laptop")) is Presence.COMMANDING
    assert classify_presence(operator_heartbeat("alice", "phone", commanding=False)) is Presence.WATCHING
    assert classify_presence(b"1" * MAX_PRESENCE_BYTES) is Presence.COMMANDING  # at the limit: parsed
    assert classify_presence(b"1" * (MAX_PRESENCE_BYTES + 1)) is Presence.OVERSIZED
    assert classify_presence(b"[" * (4 * 1024 * 1024)) is Presence.OVERSIZED  # never parsed


def test_oversized_presence_is_not_a_heartbeat() -> None:
    t = OperatorTracker(timeout=1.5)
    big = b" " * (MAX_PRESENCE_BYTES + 1)
    assert t.heartbeat("bob", "pc", big, 0.0)  # nothing lost, nothing gained
    assert not t.is_live("bob")
    t.heartbeat("alice", "laptop", operator_heartbeat("alice", "laptop"), 0.0)
    assert t.heartbeat("alice", "laptop", big, 1.0)  # does not refresh alice's client either
    assert t.expire(1.6) == ["alice"]
