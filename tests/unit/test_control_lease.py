"""The control lease: one driver at a time, as pure decisions (bridge/core/lease.py) and through the command endpoint
in-process (the harness of tests/unit/test_bridge_endpoint.py). Real processes race in
tests/integration/test_one_driver.py."""

from __future__ import annotations

import dataclasses
import time

from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.bridge.core.lease import CONTROL_EXPLICIT, ControlLease, Outcome
from roslink_mqtt.presence import operator_signoff
from roslink_mqtt.protocol.lease import ControlOp, ControlState
from tests.unit.test_bridge_endpoint import FLEET, ROBOT, ROUTES, Harness, T


def test_lease_claims_take_overs_supervisors_and_ends() -> None:
    lease = ControlLease("turtle1", supervisors=frozenset({"admin"}))
    assert lease.gate("alice", live=True, now=100.0) is None and lease.holder == "alice"  # auto: first command
    why = lease.gate("carol", live=True, now=101.0)
    assert why is not None and "turtle1 is driven by alice since" in why and "control take-over turtle1" in why
    refused = lease.request("carol", ControlOp.CLAIM, live=True, now=102.0)
    assert refused.outcome is Outcome.REFUSED and "driven by alice" in refused.reason
    taken = lease.request("carol", ControlOp.TAKE_OVER, live=True, now=103.0)
    assert taken.outcome is Outcome.TAKEN and taken.displaced == "alice" and lease.holder == "carol"
    # a supervisor's claim takes over; nobody but a supervisor takes it back
    sup = lease.request("admin", ControlOp.CLAIM, live=True, now=104.0)
    assert sup.outcome is Outcome.TAKEN and sup.displaced == "carol" and lease.state("viewers").supervisor
    back = lease.request("carol", ControlOp.TAKE_OVER, live=True, now=105.0)
    assert back.outcome is Outcome.REFUSED and "only another supervisor" in back.reason
    assert lease.request("carol", ControlOp.RELEASE, live=True, now=106.0).outcome is Outcome.REFUSED
    assert lease.request("admin", ControlOp.RELEASE, live=True, now=107.0).outcome is Outcome.RELEASED
    assert lease.holder is None and lease.driven_by() == "free"
    # without presence nothing could end a lease: a command may still run, but claims nothing
    assert lease.gate("alice", live=False, now=108.0) is None and lease.holder is None
    assert lease.request("alice", ControlOp.CLAIM, live=False, now=109.0).outcome is Outcome.REFUSED
    lease.gate("alice", live=True, now=110.0)
    assert not lease.ended("carol", "last-will", 111.0) and lease.ended("alice", "last-will", 111.0)
    assert "alice's lease ended: last-will" in lease.event


def test_explicit_mode_needs_a_claim() -> None:
    lease = ControlLease("turtle1", CONTROL_EXPLICIT)
    why = lease.gate("alice", live=True, now=1.0)
    assert why is not None and "claim it first" in why and lease.holder is None
    assert lease.request("alice", ControlOp.CLAIM, live=True, now=2.0).outcome is Outcome.GRANTED
    assert lease.gate("alice", live=True, now=3.0) is None


def test_control_state_round_trips_and_reads_leniently() -> None:
    state = ControlState("alice", 1764158585.25, False, "auto", ("admin",), "viewers", "claimed by alice")
    assert ControlState.from_json(state.to_json()) == state
    assert ControlState.from_json(b'{"holder": null, "since": null, "extra": 1}').summary() == "free"
    assert state.summary().startswith("driven by alice since ")


def _harness(**robot_changes) -> Harness:
    h = Harness()
    if robot_changes:
        robot = dataclasses.replace(ROBOT, **robot_changes)
        fleet = dataclasses.replace(FLEET, robots={**FLEET.robots, "turtle1": robot})
        h.endpoint = CommandEndpoint(fleet, robot, h.link, h.ros, ROUTES)
        h.endpoint.link_up()
    return h


def _control(h: Harness) -> list[ControlState]:
    return [ControlState.from_json(p.payload) for p in h.link.sent if p.topic == T.state("turtle1", "control")]


def test_two_operators_only_the_holders_twists_reach_ros_and_the_other_learns_who() -> None:
    h = _harness()
    h.present("alice")
    h.present("admin", "tablet")
    h.command("twist", {"lx": 0.1})
    h.command("twist", {"lx": 0.4}, user="admin")
    h.command("twist", {"lx": 0.2})
    assert h.twists() == [(0.1, 0.0), (0.2, 0.0)]
    [why] = [e.error for e in h.link.errors("admin")]
    assert "turtle1 is driven by alice since" in why
    assert _control(h)[-1].holder == "alice"
    assert h.endpoint.heartbeat(4) and b'"owner_id":"alice"' in h.endpoint.heartbeat(4)


def test_take_over_stops_the_robot_and_tells_the_old_holder() -> None:
    h = _harness()
    h.present("alice")
    h.present("admin", "tablet")
    h.command("twist", {"lx": 0.3})
    zeros = h.ros.zeros
    h.raw("control/take_over", b"", user="admin")
    assert h.endpoint.lease.holder == "admin" and h.ros.zeros > zeros
    assert any("taken over by admin from alice" in e.error for e in h.link.errors("alice"))
    h.command("twist", {"lx": 0.3})  # alice: refused now
    assert "driven by admin" in h.link.errors("alice")[-1].error
    h.command("twist", {"lx": 0.2}, user="admin")
    assert h.twists()[-1] == (0.2, 0.0)


def test_lease_ends_with_presence_and_an_estop_needs_none() -> None:
    h = _harness()
    h.present("alice")
    h.command("twist", {"lx": 0.3})
    h.endpoint.on_mqtt(T.operator("alice", "laptop"), operator_signoff("alice", "laptop"))
    assert h.endpoint.lease.holder is None and "signed off" in _control(h)[-1].event
    # a viewer stops the robot (no lease, no presence) but cannot resume it
    h.command("emergency_stop", {}, user="bob")
    assert h.endpoint.motion_blocked and "emergency stop by bob" in h.endpoint.motion_blocked
    assert any(a["command"] == 108 and "emergency stop by bob" in a["text"] for a in h.link.acks())
    h.present("bob", "phone")
    h.command("arm", {}, user="bob")
    assert h.endpoint.motion_blocked and "not an operator" in h.link.errors("bob")[-1].error


def test_estop_operators_keeps_viewers_out() -> None:
    h = _harness(estop="operators")
    h.command("emergency_stop", {}, user="bob")
    assert not h.endpoint.motion_blocked and "not an operator" in h.link.errors("bob")[-1].error


def test_a_viewer_cannot_claim_and_an_unknown_request_is_refused() -> None:
    h = _harness()
    h.present("bob", "phone")
    h.raw("control/claim", b"", user="bob")
    assert h.endpoint.lease.holder is None and "may not claim control of turtle1" in h.link.errors("bob")[-1].error
    h.present("alice")
    h.raw("control/grab", b"", user="alice")
    assert "unknown request" in h.link.errors("alice")[-1].error
    h.raw("control/claim", b"[1]", user="alice")
    assert h.endpoint.lease.holder is None


def test_a_refused_command_claims_nothing() -> None:
    h = _harness()
    h.present("alice")
    h.command("twist", {"lx": 0.1}, sequence=50)
    h.raw("control/release", b"")
    assert h.endpoint.lease.holder is None
    h.command("twist", {"lx": 0.1}, sequence=49)  # stale: dropped, and it does not take the robot
    assert h.endpoint.lease.holder is None and "stale" in h.link.errors("alice")[-1].error
    h.command("twist", {"lx": 0.1}, sequence=51)
    assert h.endpoint.lease.holder == "alice"


def test_between_supervisors_a_take_over_is_explicit() -> None:
    lease = ControlLease("turtle1", supervisors=frozenset({"admin", "chief"}))
    assert lease.request("admin", ControlOp.CLAIM, live=True, now=1.0).outcome is Outcome.GRANTED
    refused = lease.request("chief", ControlOp.CLAIM, live=True, now=2.0)
    assert refused.outcome is Outcome.REFUSED and "control take-over turtle1" in refused.reason
    assert lease.request("chief", ControlOp.TAKE_OVER, live=True, now=3.0).displaced == "admin"


def test_a_flood_of_stops_is_obeyed_but_acknowledged_at_most_twice_a_second_per_user() -> None:
    h = _harness()
    for _ in range(20):  # bob, a viewer, floods stops
        h.command("emergency_stop", {}, user="bob")
    h.command("emergency_stop", {}, user="alice")
    acks = [a for a in h.link.acks() if a["command"] == 108]
    assert [a["text"] for a in acks] == ["emergency stop by bob", "emergency stop by alice"]
    assert h.ros.zeros >= 21  # every stop zeroed the velocity


def test_the_lease_ends_when_its_holder_goes_silent() -> None:
    """No sign-off, no last-will: the holder's presence heartbeats just stop (a frozen laptop, a cut link). After
    operator_timeout the lease is free, the robot stops, and the event says why."""
    h = _harness()
    h.present("alice")
    h.command("twist", {"lx": 0.3})
    assert h.endpoint.lease.holder == "alice"
    h.endpoint.supervise(time.monotonic() + h.endpoint.operators.timeout / 2)
    assert h.endpoint.lease.holder == "alice"  # not yet
    zeros = h.ros.zeros
    h.endpoint.supervise(time.monotonic() + h.endpoint.operators.timeout + 0.1)
    assert h.endpoint.lease.holder is None and h.ros.zeros > zeros
    assert "no heartbeat for" in _control(h)[-1].event
    h.present("admin", "tablet")
    h.command("twist", {"lx": 0.2}, user="admin")  # free: the next operator drives at once
    assert h.endpoint.lease.holder == "admin"
