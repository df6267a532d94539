"""Every operation is built the same way from the ports the ROS side implements (bridge/core/capabilities/
registry.py): each registered operation builds from the demo robot's wiring, and every verb a user sends is served
by exactly one operation (``cmd/*`` and ``control/*`` are the endpoint's own: the motion path and the lease)."""

from __future__ import annotations

from collections import Counter
from types import SimpleNamespace
from typing import Any

from roslink_mqtt.bridge.core.budget import RequestBudget
from roslink_mqtt.bridge.core.capabilities import Advertise, Snapshots, Watch
from roslink_mqtt.bridge.core.capabilities.registry import OPERATIONS, Ports, Wiring, build_all
from roslink_mqtt.config import load_fleet
from roslink_mqtt.topics import USER_VERBS, Verb
from tests.support.procs import CONFIG

FLEET = load_fleet(CONFIG)


def _wiring(robot: str = "turtle1") -> Wiring:
    port: Any = SimpleNamespace()  # building touches no port: they are used when a request runs
    ports = Ports(services=port, parameters=port, actions=port, rosout=port, advertise=port, provider=port,
                  action_provider=port, sdk_parameters=port, video=port)
    rule = SimpleNamespace(ros_type="std_msgs/msg/Bool", on_demand=True)
    routes: dict[str, Any] = {"lights": SimpleNamespace(rule=rule), "cmd/twist": SimpleNamespace(
        rule=SimpleNamespace(ros_type="geometry_msgs/msg/Twist", on_demand=False))}
    return Wiring(FLEET.robots[robot], FLEET.topics, routes, ports, lambda *a, **k: None, lambda t, p: None,
                  lambda t, p, q: None, RequestBudget(8))


def test_every_user_verb_is_served_by_exactly_one_operation() -> None:
    verbs = Counter(capability.verb for capability in build_all(_wiring()))
    assert all(count == 1 for count in verbs.values()), verbs
    assert set(verbs) | {Verb.CMD, Verb.CONTROL} == USER_VERBS
    assert len(OPERATIONS) == len(verbs)


def test_each_operation_builds_from_the_wiring_alone() -> None:
    built = {type(capability): capability for capability in build_all(_wiring())}
    advertise = built[Advertise]
    assert isinstance(advertise, Advertise)
    assert advertise.on_demand == {"lights": "std_msgs/msg/Bool"} and advertise.always_there == {"cmd/twist"}
    watch = built[Watch]
    assert isinstance(watch, Watch) and watch.streams == tuple(v.name for v in FLEET.robots["turtle1"].video)
    snapshots = built[Snapshots]
    assert isinstance(snapshots, Snapshots) and snapshots.port is None  # the test wiring keeps no ring buffer

