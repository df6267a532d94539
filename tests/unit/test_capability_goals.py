"""The goal and cancel capabilities (bridge/core/capabilities/goals.py) through the command endpoint, with a recording
ActionPort. A goal needs presence, unblocked motion and (unless viewers may send it) the control lease; a cancel
needs only the grant; every refusal names the goal and its sender. Real actions: tests/integration/test_actions.py.
"""

from __future__ import annotations

from typing import Any

import orjson
import pytest

from roslink_mqtt.bridge.core.capabilities import CancelGoal, SendGoal
from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.config import ActionRule
from roslink_mqtt.protocol.goals import GoalRequest
from tests.unit.test_bridge_endpoint import FLEET, ROBOT, ROUTES, Harness, T


class RecordingActions:
    def __init__(self) -> None:
        self.goals: list[tuple[str, str, str]] = []
        self.cancels: list[tuple[str, str, str]] = []
        self.lock: Any = None  # the endpoint's motion lock: a goal is handed over holding it
        self.locked: list[bool] = []

    def send_goal(self, user: str, rule: ActionRule, request: GoalRequest) -> str | None:
        self.locked.append(self.lock is not None and self.lock._is_owned())
        if (user, rule.name, request.id) in self.goals:
            return f"goal id '{request.id}' is already in use on '{rule.name}'"
        self.goals.append((user, rule.name, request.id))
        return None

    def cancel_goal(self, user: str, action: str, goal_id: str) -> str | None:
        if (user, action, goal_id) not in self.goals:
            return f"no goal '{goal_id}' of yours on '{action}' is in flight"
        self.cancels.append((user, action, goal_id))
        return None


@pytest.fixture
def h() -> Harness:
    harness = Harness()
    harness.actions = RecordingActions()
    caps = [SendGoal(ROBOT, T, harness.actions, harness.endpoint.refuse),
            CancelGoal(ROBOT, T, harness.actions, harness.endpoint.refuse)]
    harness.endpoint = CommandEndpoint(FLEET, ROBOT, harness.link, harness.ros, ROUTES,
                                       capabilities=caps)
    harness.endpoint.link_up()
    harness.actions.lock = harness.endpoint.lock
    return harness


def goal(h: Harness, body: Any, user: str = "alice", action: str = "fibonacci") -> None:
    h.endpoint.on_mqtt(T.goal("turtle1", user, action), body if isinstance(body, bytes) else orjson.dumps(body))


def cancel(h: Harness, goal_id: str, user: str = "alice") -> None:
    h.endpoint.on_mqtt(T.cancel("turtle1", user, "fibonacci"), orjson.dumps({"id": goal_id}))


def test_a_goal_needs_presence_and_unblocked_motion_a_cancel_does_not(h: Harness) -> None:
    goal(h, {"id": "g1", "goal": {"order": 5}, "client_id": "laptop"})
    (report,) = h.link.errors("alice")
    assert report.error.startswith("no live operator heartbeat") and (report.id, report.client_id) == ("g1", "laptop")
    h.present()
    h.command("emergency_stop")
    goal(h, {"id": "g1", "goal": {"order": 5}})
    assert h.link.errors("alice")[-1].error == "emergency stop by alice: send cmd/arm to resume"
    h.command("arm")
    goal(h, {"id": "g1", "goal": {"order": 5}})
    assert h.actions.goals == [("alice", "fibonacci", "g1")]
    assert h.actions.locked == [True]  # an emergency stop cannot come between the gate and the hand-over
    h.endpoint.on_mqtt(T.operator("alice", "laptop"), b"")  # presence ended: a cancel still goes through
    cancel(h, "g1")
    assert h.actions.cancels == [("alice", "fibonacci", "g1")]


def test_a_goal_that_moves_the_robot_needs_the_control_lease(h: Harness) -> None:
    h.present("alice")
    h.present("admin", "console")
    goal(h, {"id": "a", "goal": {"order": 1}})
    goal(h, {"id": "b", "goal": {"order": 1}}, user="admin")
    assert h.endpoint.lease.holder == "alice" and h.actions.goals == [("alice", "fibonacci", "a")]
    assert "control" in h.link.errors("admin")[0].error and h.link.errors("admin")[0].id == "b"


def test_refusals_name_the_goal_and_nothing_malformed_reaches_ros(h: Harness) -> None:
    h.present()
    h.present("bob", "phone")
    goal(h, {"id": "x", "goal": {"order": 1}}, action="warp")
    goal(h, {"id": "y", "goal": [1], "client_id": "laptop"})  # named, then malformed
    goal(h, b"[1, 2]")
    goal(h, {"id": "z", "goal": {"order": 1}}, user="bob")  # a viewer: fibonacci is operators only
    goal(h, {"id": "a", "goal": {"order": 1}})
    goal(h, {"id": "a", "goal": {"order": 1}})  # the port refuses a second goal with the same id
    cancel(h, "nope")
    alice = h.link.errors("alice")
    assert [(e.id, e.client_id) for e in alice] == [("x", None), ("y", "laptop"), (None, None), ("a", None),
                                                     ("nope", None)]
    assert "unknown action 'warp'" in alice[0].error and "goal: expected object" in alice[1].error
    assert "already in use" in alice[3].error and "no goal 'nope'" in alice[4].error
    assert "operator" in h.link.errors("bob")[0].error
    assert h.actions.goals == [("alice", "fibonacci", "a")] and h.endpoint.lease.holder == "alice"
