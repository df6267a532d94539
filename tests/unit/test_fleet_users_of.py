"""Who may use each robot, asked per robot by the broker and ``fleet apply``: worked out once per fleet.

A fleet of 1,000 robots and 1,000 users cost the embedded broker 15 s of CPU at start when every robot's users
were found by scanning every user's grants, and each grant's robot by scanning every robot (a profile of
bench/fleet.py at 1,000 robots): the answers must stay the same, and the work must be once per user."""

from __future__ import annotations

import dataclasses
import random

from roslink_mqtt.config import Role, load_fleet
from roslink_mqtt.config.model import Fleet, Grant, User
from tests.unit.test_config import ROOT


def _naive_users_of(fleet: Fleet, robot: str) -> dict[str, Role]:
    """The definition: each user's strongest role on ``robot``, robots found by key in file order."""
    out: dict[str, Role] = {}
    for name, user in fleet.users.items():
        if user.admin:
            out[name] = Role.OPERATOR
            continue
        role = None
        for grant in user.grants:
            target = next((r for r in fleet.robots.values() if r.key == grant.key), None)
            if target is not None and target.name == robot and role is not Role.OPERATOR:
                role = grant.role
        if role is not None:
            out[name] = role
    return out


def _big_fleet(robots: int, users: int, seed: int = 7) -> Fleet:
    demo = load_fleet(ROOT / "config" / "robots.yaml")
    template = next(iter(demo.robots.values()))
    rng = random.Random(seed)
    fleet_robots = {f"r{i:04d}": dataclasses.replace(template, name=f"r{i:04d}", system_id=i + 1,
                                                     key=f"key-{i % (robots - 3)}")  # a few keys shared
                    for i in range(robots)}
    fleet_users = {f"u{j:04d}": User(f"u{j:04d}", "", tuple(
        Grant(f"key-{rng.randrange(robots + 5)}", rng.choice([Role.VIEWER, Role.OPERATOR]))  # some name no robot
        for _ in range(rng.randrange(4))), admin=j % 97 == 0) for j in range(users)}
    return dataclasses.replace(demo, robots=fleet_robots, users=fleet_users)


def test_every_robots_users_are_what_the_grants_say() -> None:
    fleet = _big_fleet(60, 80)
    for robot in fleet.robots:
        assert fleet.users_of(robot) == _naive_users_of(fleet, robot), robot
        assert list(fleet.users_of(robot)) == list(_naive_users_of(fleet, robot))  # the file's order
    assert fleet.users_of("no-such-robot") == {}


def test_a_thousand_robots_cost_one_look_at_each_user(monkeypatch) -> None:
    fleet = _big_fleet(1000, 1000)
    looked: list[str] = []
    roles_of = Fleet.roles_of
    monkeypatch.setattr(Fleet, "roles_of", lambda self, user: looked.append(user) or roles_of(self, user))
    for robot in fleet.robots:
        fleet.users_of(robot)
    assert len(looked) == len(fleet.users)


def test_a_caller_changing_its_answer_changes_nobody_elses() -> None:
    fleet = _big_fleet(5, 10)
    robot = next(iter(fleet.robots))
    fleet.users_of(robot)["intruder"] = Role.OPERATOR
    assert "intruder" not in fleet.users_of(robot)
